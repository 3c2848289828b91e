"""Teacher labels: what a scripted team would do in each robot's place, as the agent's discrete action indices.

Why: learning to play soccer from scratch takes the paper ≈ 20 GPU-hours; a scripted player that reads the ground
truth is a teacher the learner can imitate from its own noisy, partial observations (DAgger: the learner acts, the
teacher labels the states the learner reaches). The labels are made inside each world's process, where the ground
truth lives, and cross the process boundary as four integers per robot.

A teacher row is ``[walk, turn, kick, head]`` in the discrete action encoding (``soccer.actions.parse_action``):
the head index is the scripted head turn rounded to the nearest of the 2·units + 1 discrete steps.

Driving (``DrivingTeacher``, kind ``"scripted"``): the scripted driver (``driving.scripted.ScriptedDriver``: lane
keeping along a route to the car's destination, yielding) labels every car, as the agent's action row: discrete
``[acceleration, steering]`` indices, or continuous ``[throttle, brake, steering / max_yaw_rate]`` — the
normalised units the learner stores its own continuous actions in.
"""
from __future__ import annotations

import numpy as np

from dynenv_ros.driving.cars import normalised_commands
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.scripted import ScriptedDriver
from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.scripted import act_all, team_policies

TEACHERS = ("chaser", "eager_chaser", "keeper_and_chasers")
DRIVING_TEACHERS = ("scripted",)


def action_indices(action: SoccerAction, head_step: float, head_units: int) -> tuple[int, int, int, int]:
    """A SoccerAction as the discrete action row the agent emits (the head turn rounded to a step index)."""
    head = int(np.clip(np.rint(action.head_yaw_delta / head_step), -head_units, head_units)) + head_units
    return int(action.walk), int(action.turn), int(action.kick), head


class Teacher:
    """Labels every robot of a world (both teams) with the scripted ``kind``'s action for the current state."""

    def __init__(self, config: SoccerConfig, kind: str) -> None:
        if kind not in TEACHERS:
            raise ValueError(f"teacher must be one of {TEACHERS}, got {kind!r}")
        if config.head_mode != "discrete":
            raise ValueError("teacher labels need head_mode='discrete' (the agent's head is then an index)")
        self.policies = team_policies(config.players_per_team, kind, field=config.field,  # type: ignore[arg-type]
                                      head_mode="discrete", motion=config.motion)
        self.head_step, self.head_units = config.motion.head_step, config.motion.head_units

    def label(self, world, out: np.ndarray) -> None:
        """Write the (A, 4) labels of ``world``'s current state into ``out``."""
        for i, action in enumerate(act_all(self.policies, world.snapshot())):
            out[i] = action_indices(action, self.head_step, self.head_units)


class DrivingTeacher:
    """Labels every car of a driving world with the scripted driver's action for the current state."""

    def __init__(self, config: DrivingConfig, kind: str = "scripted") -> None:
        if kind not in DRIVING_TEACHERS:
            raise ValueError(f"a driving teacher must be one of {DRIVING_TEACHERS}, got {kind!r}")
        self.driver = ScriptedDriver(config)
        self.limit = None if config.action_mode == "discrete" else config.cars.max_yaw_rate

    def label(self, world, out: np.ndarray) -> None:
        """Write the (n_cars, width) labels of ``world``'s current state into ``out``."""
        actions = self.driver.actions(world)
        out[:] = actions if self.limit is None else normalised_commands(actions, self.limit)
