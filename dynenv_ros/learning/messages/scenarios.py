"""What the experience assembler (``learning.messages.assembly``) needs to know of a scenario, so one assembler serves soccer
robots and driving cars — and a third scenario is one more class here, not a fork of the assembler. ROS-free.

A scenario says: its agents' names (and the pattern the trainer node discovers them by), the padded layout a period
of their frames is packed into (``envs.padded_layout``), what an Action must hold to be used, how an Action becomes
the action the learner scores (its ``agent.distributions``) and the previous action the next observation shows,
which steps the agent could act in, and whether an agent's episode can end before its game's (driving: a car that
crashed, or is home with its team's bonus decided; ``StepFeedback.terminated`` says so per car).

- ``SoccerExperience``: robots ``team_a_0`` …; actions [walk, turn, kick, head index] (a head turn in rad taken to
  the nearest of the discrete head's steps); a fallen or penalized robot's step is not an action of its own.
- ``DrivingExperience``: cars ``car_0`` …; actions as the driving agent's heads hold them — discrete, the indices
  [acceleration, steering] of the nearest of the nine commands the simulator's discrete mode accepts; continuous,
  the normalised command [throttle, brake, steering / limit] as float32, clipped to its bounds (a command the
  simulator accepts may lie ``BOUND_TOLERANCE`` beyond one). A policy's action on a bound comes back exactly on it
  (a float32 field divided by the limit is within half a float32 step of ±1), so the learner scores it, as the
  policy did, with the clipped Gaussian's mass beyond the bound rather than a density; the previous action is the
  command [throttle, brake, steering] (BRAKE after a reset, as the policy node's).
"""
from __future__ import annotations

import math
from typing import Any, Callable, Protocol

import numpy as np

from dynenv_ros.driving.agent_actions import BOUND_TOLERANCE, BRAKE_COMMAND, check_action_mode, command_problem
from dynenv_ros.envs.padded_layout import PaddedLayout
from dynenv_ros.learning.algo.policy import can_act
from dynenv_ros.scenarios import DRIVING, SOCCER, get_scenario
from dynenv_ros.soccer.agent_actions import head_index

WALKS, TURNS, KICKS = 5, 3, 3     # Action.msg's soccer choices
STAND_STILL = (0.0, 0.0, 0.0, 0.0)
SOCCER_AGENT = r"team_[ab]_[0-9]+"
DRIVING_AGENT = r"car_[0-9]+"


class ExperienceScenario(Protocol):
    """The scenario side of ``ExperienceAssembler`` (module docstring). One that ``supports_targets`` also has
    ``players`` (per team), the targets' layout."""
    scenario: str                 # TrainConfig.scenario's name: 'robocup', 'driving'
    agent_pattern: str            # a regular expression matching every agent name (topic discovery, bags)
    names: list[str]
    frames: int
    layout: PaddedLayout
    idle: tuple[float, ...]       # the previous action an episode's first observation shows
    action_width: int
    action_dtype: Any
    per_agent_ends: bool          # an agent's episode may end before its game's
    supports_targets: bool        # the self-supervised targets can be built from its ground truth
    probability_actions: bool     # log_prob is a log-probability (≤ 0), not a log-density (continuous heads)

    def action_problem(self, msg: Any) -> str: ...

    def off_grid(self, msg: Any) -> bool: ...

    def action_row(self, msg: Any) -> tuple: ...

    def previous_row(self, msg: Any) -> tuple: ...

    def can_act(self, proprioception: np.ndarray) -> np.ndarray: ...


class SoccerExperience:
    """Soccer robots of two teams of ``players_per_team``; ``head_max``, ``head_units``: the discrete head's bound
    (rad per period) and steps each way."""
    scenario = "robocup"
    agent_pattern = SOCCER_AGENT
    idle = STAND_STILL
    action_width, action_dtype = 4, np.int64
    per_agent_ends = False
    supports_targets = True
    probability_actions = True        # the trainer learns the discrete head only

    def __init__(self, players_per_team: int, frames: int, head_max: float, head_units: int) -> None:
        self.players, self.frames = players_per_team, frames
        self.names = [f"team_{t}_{i}" for t in "ab" for i in range(players_per_team)]
        self.layout = PaddedLayout.for_players(players_per_team, frames)
        self.head_step, self.head_units = head_max / head_units, head_units
        self.head_bound = head_max + 1e-6

    def action_problem(self, msg: Any) -> str:
        if not (0 <= msg.walk < WALKS and 0 <= msg.turn < TURNS and 0 <= msg.kick < KICKS):
            return "choice out of range"
        if not math.isfinite(msg.head_yaw_delta) or abs(msg.head_yaw_delta) > self.head_bound:
            return "head turn out of range"
        return ""

    def off_grid(self, msg: Any) -> bool:
        steps = msg.head_yaw_delta / self.head_step
        return abs(steps - round(steps)) * self.head_step > 1e-5

    def action_row(self, msg: Any) -> tuple:
        """[walk, turn, kick, head index]."""
        index = int(head_index(msg.head_yaw_delta, self.head_units, self.head_step))   # (finite: checked first)
        return (int(msg.walk), int(msg.turn), int(msg.kick), index)

    def previous_row(self, msg: Any) -> tuple:
        """[walk, turn, kick, head turn rad]: what the padded layout's previous action holds."""
        return (float(msg.walk), float(msg.turn), float(msg.kick), float(msg.head_yaw_delta))

    def can_act(self, proprioception: np.ndarray) -> np.ndarray:
        return can_act(proprioception)


class DrivingExperience:
    """The ``n_cars`` cars of a driving game (``config``: its ``DrivingConfig``; ``frames``: the vision frames per
    period when they differ from the config's rates, e.g. a recording's)."""
    scenario = "driving"
    agent_pattern = DRIVING_AGENT
    per_agent_ends = True
    supports_targets = False

    def __init__(self, config: Any, frames: int | None = None) -> None:
        from dynenv_ros.driving.cars import discrete_action, normalised_commands
        from dynenv_ros.envs.driving_observations import driving_layout
        self.action_mode = check_action_mode(config.action_mode)
        self.names = list(config.car_names)
        layout = driving_layout(config)
        self.frames = layout.frames if frames is None else int(frames)
        self.layout = PaddedLayout(self.frames, layout.max_landmarks, layout.max_objects, layout.spec)
        self.limit = float(config.cars.max_yaw_rate)
        self.idle = tuple(float(v) for v in BRAKE_COMMAND)
        discrete = self.action_mode == "discrete"
        self.action_width, self.action_dtype = (2, np.int64) if discrete else (3, np.float32)
        # the clipped Gaussian's log-density exceeds 0 where its spread is below ≈ 0.4 (the brake starts at 0.2)
        self.probability_actions = discrete
        # the nine commands, normalised [throttle, brake, steering / limit], index = 3 * acceleration + steering
        self._normalise = normalised_commands           # driving.cars, imported with the driving scenario only
        self._nine = normalised_commands([(c.throttle, c.brake, c.steering) for c in
                                          (discrete_action(a, s, self.limit) for a in range(3) for s in range(3))],
                                         self.limit)

    def _normalised(self, msg: Any) -> np.ndarray:
        return self._normalise((float(msg.throttle), float(msg.brake), float(msg.steering)), self.limit)

    def action_problem(self, msg: Any) -> str:
        """Within the bounds (the policy node's own check); off the discrete grid is ``off_grid``'s, not a fault."""
        return command_problem((msg.throttle, msg.brake, msg.steering), "continuous", self.limit)

    def _nearest(self, msg: Any) -> tuple[int, float]:
        distances = np.abs(self._nine - self._normalised(msg)).max(axis=1)
        index = int(distances.argmin())
        return index, float(distances[index])

    def off_grid(self, msg: Any) -> bool:
        return self.action_mode == "discrete" and self._nearest(msg)[1] > BOUND_TOLERANCE

    def action_row(self, msg: Any) -> tuple:
        """Discrete: [acceleration, steering] of the nearest of the nine commands; continuous: the normalised
        command within its bounds (module docstring)."""
        if self.action_mode == "discrete":
            index = self._nearest(msg)[0]
            return (index // 3, index % 3)
        return tuple(np.clip(self._normalised(msg), (-1.0, 0.0, -1.0), 1.0).astype(np.float32).tolist())

    def previous_row(self, msg: Any) -> tuple:
        """[throttle, brake, steering rad/s]: the command as sent (the padded layout's previous action)."""
        return (float(msg.throttle), float(msg.brake), float(msg.steering))

    def can_act(self, proprioception: np.ndarray) -> np.ndarray:
        """Every step the assembler emits is a car still driving (its episode's end cuts the stream)."""
        return np.ones(proprioception.shape[:-2], bool)


def experience_scenario(scenario: str, agents: int, frames: int | None = None, action_mode: str = "discrete"
                        ) -> SoccerExperience | DrivingExperience:
    """The scenario's side of the assembler with its defaults: ``agents`` robots per team (robocup) or cars
    (driving); ``frames`` per period (default: the scenario's rates). ValueError for an unknown scenario."""
    return _EXPERIENCES[get_scenario(scenario).name](agents, frames, action_mode)


def _soccer_experience(agents: int, frames: int | None, action_mode: str) -> SoccerExperience:
    from dynenv_ros.soccer.config import SoccerConfig
    soccer = SoccerConfig.from_mapping({"players_per_team": agents})
    return SoccerExperience(agents, soccer.rates.frames_per_period if frames is None else frames,
                            soccer.motion.head_max_delta, soccer.motion.head_units)


def _driving_experience(agents: int, frames: int | None, action_mode: str) -> DrivingExperience:
    from dynenv_ros.driving.config import DrivingConfig
    return DrivingExperience(DrivingConfig(n_cars=agents, action_mode=action_mode), frames)


# Each scenario's experience adapter, by its name: the adapters live here, above the registry (docs/decisions.md,
# "A scenario registry").
_EXPERIENCES: dict[str, Callable[[int, int | None, str], SoccerExperience | DrivingExperience]] = {
    SOCCER.name: _soccer_experience, DRIVING.name: _driving_experience}
