"""Teacher labels: what a scripted team would do in each robot's place, as the agent's discrete action indices.

Why: learning to play soccer from scratch takes the paper ≈ 20 GPU-hours; a scripted player that reads the ground
truth is a teacher the learner can imitate from its own noisy, partial observations (DAgger: the learner acts, the
teacher labels the states the learner reaches). The labels are made inside each world's process, where the ground
truth lives, and cross the process boundary as four integers per robot.

A teacher row is ``[walk, turn, kick, head]`` in the discrete action encoding (``soccer.actions.parse_action``):
the head index is the scripted head turn rounded to the nearest of the 2·units + 1 discrete steps.

``perceiving`` (``PerceivingTeacher``): the scripted chaser on each robot's *own perception*
(``soccer.perceiving.PerceivingPolicy``): it acts on exactly the robot's padded observation of the period (the
object rows, proprioception and GameController values the learner receives) and its self-localization estimate
(``observations.vision.estimate``; the world runs its localization for it, observed or not), so a learner with the
``pose_estimate`` input sees everything it decides from. It keeps a ball memory per robot, so there is one teacher
per world, reset at each of its episode starts (``reset``) and asked once per period in order. Every slot is a
chaser, as with ``chaser``: one shared network has no slot input to play a keeper in one slot.

Every teacher answers ``reset()`` (an episode of its world starts) and ``label(world, out, observation,
observer)``: the world, the (A, width) rows to fill, the world's padded observation of this instant ({key: (A,
...)}) and its observation builder; the ground-truth teachers read the world only.

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
from dynenv_ros.soccer.agent_actions import head_index
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.perceiving import perceiving_team
from dynenv_ros.soccer.scripted import act_all, team_policies

GROUND_TRUTH_TEACHERS = ("chaser", "eager_chaser", "keeper_and_chasers")
PERCEIVING_TEACHER = "perceiving"    # reads the robot's observation and pose estimate, not the world
TEACHERS = GROUND_TRUTH_TEACHERS + (PERCEIVING_TEACHER,)
PERCEIVED_KEYS = ("objects", "object_mask", "proprioception", "game")   # what PerceivingPolicy reads
DRIVING_TEACHERS = ("scripted",)


def action_indices(action: SoccerAction, head_step: float, head_units: int) -> tuple[int, int, int, int]:
    """A SoccerAction as the discrete action row the agent emits (the head turn rounded to a step index, divided in
    its own type)."""
    head = int(head_index(action.head_yaw_delta, head_units, head_step, dtype=None))
    return int(action.walk), int(action.turn), int(action.kick), head


def _discrete_head(config: SoccerConfig) -> tuple[float, int]:
    if config.head_mode != "discrete":
        raise ValueError("teacher labels need head_mode='discrete' (the agent's head is then an index)")
    return config.motion.head_step, config.motion.head_units


def make_soccer_teacher(config: SoccerConfig, kind: str) -> "Teacher | PerceivingTeacher":
    """The teacher ``kind`` names (``TEACHERS``) for worlds of ``config``."""
    if kind == PERCEIVING_TEACHER:
        return PerceivingTeacher(config)
    return Teacher(config, kind)


class Teacher:
    """Labels every robot of a world (both teams) with the scripted ``kind``'s action for the current state."""

    def __init__(self, config: SoccerConfig, kind: str) -> None:
        if kind not in GROUND_TRUTH_TEACHERS:
            raise ValueError(f"teacher must be one of {GROUND_TRUTH_TEACHERS}, got {kind!r}")
        self.head_step, self.head_units = _discrete_head(config)
        self.policies = team_policies(config.players_per_team, kind, field=config.field,  # type: ignore[arg-type]
                                      head_mode="discrete", motion=config.motion)

    def reset(self) -> None:
        """Stateless: nothing to forget at an episode start."""

    def label(self, world, out: np.ndarray, observation=None, observer=None) -> None:
        """Write the (A, 4) labels of ``world``'s current state into ``out``."""
        for i, action in enumerate(act_all(self.policies, world.snapshot())):
            out[i] = action_indices(action, self.head_step, self.head_units)


class PerceivingTeacher:
    """Labels every robot of one world with the perceiving chaser's action (``soccer.perceiving``) on the robot's
    own padded observation and pose estimate; stateful (a ball memory per robot): ``reset`` at each episode start,
    then one ``label`` per period, in order."""

    def __init__(self, config: SoccerConfig) -> None:
        self.head_step, self.head_units = _discrete_head(config)
        self.policies = perceiving_team(config.players_per_team, config.period_seconds, field=config.field,
                                        motion=config.motion, kind="chaser")

    def reset(self) -> None:
        for policy in self.policies:
            policy.reset()

    def label(self, world, out: np.ndarray, observation, observer) -> None:
        """Write the (A, 4) labels into ``out``: robot i's from row i of ``observation`` (padded, {key: (A, ...)})
        and of ``observer.vision.estimate`` (A, 3), the field-frame pose estimate of the period's last frame."""
        estimate = observer.vision.estimate
        for i, policy in enumerate(self.policies):
            action = policy.act({key: observation[key][i] for key in PERCEIVED_KEYS}, estimate[i])
            out[i] = action_indices(action, self.head_step, self.head_units)


class DrivingTeacher:
    """Labels every car of a driving world with the scripted driver's action for the current state."""

    def __init__(self, config: DrivingConfig, kind: str = "scripted") -> None:
        if kind not in DRIVING_TEACHERS:
            raise ValueError(f"a driving teacher must be one of {DRIVING_TEACHERS}, got {kind!r}")
        self.driver = ScriptedDriver(config)
        self.limit = None if config.action_mode == "discrete" else config.cars.max_yaw_rate

    def reset(self) -> None:
        """Stateless: nothing to forget at an episode start."""

    def label(self, world, out: np.ndarray, observation=None, observer=None) -> None:
        """Write the (n_cars, width) labels of ``world``'s current state into ``out``."""
        actions = self.driver.actions(world)
        out[:] = actions if self.limit is None else normalised_commands(actions, self.limit)
