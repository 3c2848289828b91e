"""Every number of the soccer world in one validated place: motions, kicks, falls, penalties, ball, rewards.

Defaults reproduce the motions and rules measured in the original DynEnv (docs/original.md §2, §6),
converted to SI units; docs/differences.md lists where we depart from it on purpose.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from dataclasses import field as _default
from typing import Any, Mapping

from dynenv_ros.core.settings import build_settings, check_numbers
from dynenv_ros.sim.timing import Rates
from dynenv_ros.soccer.field import FieldGeometry

MAX_PLAYERS_PER_TEAM = 5
SCENARIO_SOCCER = 0                        # WorldState.SCENARIO_SOCCER
START_KINDS = ("kickoff", "attack")        # StartConfig.kind
DEFENDERS = ("present", "absent")          # StartConfig.defenders
START_MARGIN = 0.3                         # m: an attack start's ball stays this far inside every line
MIN_BALL_DISTANCE = 0.5                    # m: the least StartConfig.ball_distance_min (clear of the keeper's spot)
MIN_ATTACKER_DISTANCE = 0.75               # m: the least StartConfig.attacker_distance (room for 5 robots)


def is_soccer_world(code: int) -> bool:
    """Whether a WorldState's (a snapshot's) ``scenario`` code is soccer's: what reads only soccer's ground truth
    (the GameController's view of the game) refuses another world's."""
    return code == SCENARIO_SOCCER


def robot_names(players_per_team: int) -> list[str]:
    """Robot names, also PettingZoo agent names and ROS namespaces: team A's slots, then team B's (index = id)."""
    return [f"team_{team}_{slot}" for team in "ab" for slot in range(players_per_team)]


@dataclass(frozen=True)
class MotionConfig:
    """What one motion period of each high-level action achieves for a free robot."""
    forward_step: float = 0.055        # m per period (DynEnv: ≈5.5 cm)
    backward_step: float = 0.036       # m per period (≈3.6 cm)
    side_step: float = 0.036           # m per period (≈3.6 cm)
    turn_step: float = 0.1             # rad per period (≈5.7°)
    head_step: float = math.radians(12.5)   # rad per period for one discrete head unit
    head_units: int = 3                # discrete head command d ∈ {-units..units}
    head_limit: float = math.radians(120.0)  # |head yaw| clamp, rad
    drive_max_force: float = 200.0     # N: how hard a walking robot holds its commanded velocity
    drive_max_torque: float = 20.0     # N·m

    @property
    def head_max_delta(self) -> float:
        """Largest head turn in one period, rad (the continuous mode's bound)."""
        return self.head_step * self.head_units


@dataclass(frozen=True)
class KickConfig:
    """A kick spans two motion periods: wind-up, then the foot strikes forward and returns (DynEnv timing)."""
    strike_speed: float = 1.65         # m/s; a stationary ball leaves at about twice this (≈3.3 m/s)
    strike_seconds: float = 0.1        # forward stroke, then the same time back
    periods: int = 2


@dataclass(frozen=True)
class FallConfig:
    enabled: bool = True
    p_walk: float = 0.001              # per walking action
    p_turn: float = 0.001              # per turning action
    p_kick: float = 0.01               # per kick
    getup_seconds: float = 4.0
    p_fall_again: float = 0.1          # when trying to get up
    falls_to_penalty: int = 3          # consecutive falls without getting up
    contact_base: float = 0.9999       # robot–robot: falls this tick if U > base**contact_ticks
    contact_base_pusher: float = 0.99995
    goalpost_base: float = 0.9998
    push_min_speed: float = 0.01       # m/s commanded speed to count as moving into the other robot
    push_cos: float = 0.4              # cos of the angle between motion and the direction to the other robot
    knock_radius: float = 0.4          # m: a falling robot shoves what is this close
    knock_speed: float = 0.4           # m/s given to each shoved body


@dataclass(frozen=True)
class PenaltyConfig:
    first_seconds: float = 20.0
    increment_seconds: float = 10.0    # each further penalty of the same team lasts this much longer
    sideline_spacing: float = 0.525    # m between sideline spots
    spots_per_side: int = 7
    max_in_own_penalty_area: int = 2   # illegal defender beyond this


@dataclass(frozen=True)
class BallConfig:
    radius: float = 0.05               # SPL ball: 10 cm diameter
    mass: float = 0.045
    elasticity: float = 0.98
    friction: float = 0.5
    deceleration: float = 1.18         # m/s²: a 3.3 m/s kick rolls ≈4.6 m, as in DynEnv
    spin_deceleration: float = 20.0    # rad/s²
    kickoff_ownership_seconds: float = 10.0
    free_kick_ownership_seconds: float = 25.0  # DynEnv: 15 s grace, then 10 s
    sideline_out_shift: float = 0.5    # m toward the goal of the team that touched it last


@dataclass(frozen=True)
class RewardConfig:
    """Weights in SI units. DynEnv's per-pixel weights × 100 px/m give the per-metre defaults."""
    goal: float = 25.0
    ball_progress_per_m: float = 5.0   # DynEnv Δx/20 per px
    team_share: float = 0.1            # of the team's ball reward to every teammate
    chain_decay: float = 0.5           # i-th most recent toucher gets decay**i
    chain_length: int = 4
    bystander_share: float = 0.5       # of a loss, to the closest or nearby robots outside the chain
    bystander_radius: float = 1.5      # m
    approach_per_m: float = 5.0        # DynEnv 0.05 per px, for the closest robot of each team
    fall: float = -2.0
    penalty_per_second: float = -0.5   # -10 for 20 s, -15 for 30 s, ...
    observation_robot: float = 0.0025
    observation_landmark: float = 0.0025
    observation_ball: float = 0.01
    observation_robot_cap: int = 2
    observation_landmark_cap: int = 3
    observation_ball_cap: int = 3


@dataclass(frozen=True)
class StartConfig:
    """How every episode starts (docs/soccer.md, "Start states"). ``kickoff``: the game's own start. ``attack``: a
    scene near one goal, for curricula that start near success (Google Research Football's academy, reverse
    curricula): the ball ``ball_distance_min``..``ball_distance_max`` from the centre of the goal one team attacks,
    at most ``ball_max_angle`` off that goal's axis and ``START_MARGIN`` inside the lines; the attacking team's robots
    behind the ball within ``attacker_distance`` of it, facing the goal; the defenders at their kickoff spots
    (keeper in its goal area) or, ``defenders: absent``, out of play for the whole episode. ``kickoff_share``: the
    share of an attack start's episodes that start from the kickoff instead (drawn per episode with the world's own
    generator), so that a curriculum can keep its attack scenes while the game itself is learnt."""
    kind: str = "kickoff"
    ball_distance_min: float = 1.0         # m from the attacked goal's centre (the middle of its goal line)
    ball_distance_max: float = 3.0         # m
    ball_max_angle: float = math.radians(60.0)   # rad off the goal's axis (the line through both goals' centres)
    attacker_distance: float = 1.0         # m: each attacker at most this far from the ball
    defenders: str = "present"             # or "absent"
    kickoff_share: float = 0.0             # attack only: this share of episodes starts from the kickoff instead

    def check(self, field: FieldGeometry) -> None:
        """ValueError naming the ``start.`` key that cannot work on ``field``."""
        if self.kind not in START_KINDS:
            raise ValueError(f"start.kind must be one of {', '.join(START_KINDS)}, got {self.kind!r}")
        if not 0.0 <= self.kickoff_share <= 1.0:        # False for NaN too
            raise ValueError(f"start.kickoff_share must be in [0, 1] (a share of episodes), got {self.kickoff_share}")
        if self.kickoff_share > 0.0 and self.kind != "attack":
            raise ValueError(f"start.kickoff_share mixes kickoffs into attack starts: it needs start.kind attack, "
                             f"got {self.kind!r}")
        if self.kickoff_share > 0.0 and self.defenders == "absent":
            raise ValueError("start.kickoff_share needs start.defenders present: a kickoff is played by both teams")
        if self.defenders not in DEFENDERS:
            raise ValueError(f"start.defenders must be one of {', '.join(DEFENDERS)}, got {self.defenders!r}")
        low, high = self.ball_distance_min, self.ball_distance_max
        if low > high:
            raise ValueError(f"start.ball_distance_min ({low} m) is beyond start.ball_distance_max ({high} m)")
        farthest = field.length - START_MARGIN     # the ball on the goals' axis, START_MARGIN before the own line
        if low < MIN_BALL_DISTANCE or high > farthest:
            raise ValueError(f"start.ball_distance_min/max must lie in [{MIN_BALL_DISTANCE}, {farthest:g}] m (the "
                             f"ball inside the field, {START_MARGIN} m from its lines), got [{low}, {high}]")
        if not 0.0 <= self.ball_max_angle <= math.pi / 2:
            raise ValueError(f"start.ball_max_angle must be in [0, pi/2] rad (in front of the goal), got "
                             f"{self.ball_max_angle}")
        if self.attacker_distance < MIN_ATTACKER_DISTANCE:
            raise ValueError(f"start.attacker_distance must be at least {MIN_ATTACKER_DISTANCE} m (room behind the "
                             f"ball for a whole team), got {self.attacker_distance}")


@dataclass(frozen=True)
class SoccerConfig:
    players_per_team: int = 2
    episode_seconds: float = 120.0
    rates: Rates = _default(default_factory=Rates)
    field: FieldGeometry = _default(default_factory=FieldGeometry)
    motion: MotionConfig = _default(default_factory=MotionConfig)
    kick: KickConfig = _default(default_factory=KickConfig)
    falls: FallConfig = _default(default_factory=FallConfig)
    penalties: PenaltyConfig = _default(default_factory=PenaltyConfig)
    ball: BallConfig = _default(default_factory=BallConfig)
    rewards: RewardConfig = _default(default_factory=RewardConfig)
    start: StartConfig = _default(default_factory=StartConfig)
    head_mode: str = "discrete"        # or "continuous"
    robot_mass: float = 5.2            # kg (NAO)

    def __post_init__(self) -> None:
        n = self.players_per_team
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_PLAYERS_PER_TEAM:
            raise ValueError(f"players_per_team must be an integer in 1..{MAX_PLAYERS_PER_TEAM}, got {n!r}")
        if self.head_mode not in ("discrete", "continuous"):
            raise ValueError(f"head_mode must be 'discrete' or 'continuous', got {self.head_mode!r}")
        check_numbers(self, negative_ok=("fall", "penalty_per_second"))
        period = self.rates.motion_period_ticks * self.rates.tick_seconds
        if self.episode_seconds < period:
            raise ValueError(f"episode_seconds ({self.episode_seconds}) is shorter than one motion period ({period})")
        if 2 * self.kick.strike_seconds > period:
            raise ValueError("kick.strike_seconds: the stroke forward and back must fit in one motion period")
        for name in ("robot_mass", "ball.mass", "ball.radius", "ball.deceleration", "kick.strike_speed",
                     "kick.strike_seconds", "motion.drive_max_force", "motion.drive_max_torque", "motion.head_step",
                     "motion.head_limit", "penalties.sideline_spacing"):
            owner, _, leaf = name.rpartition(".")
            if not getattr(getattr(self, owner) if owner else self, leaf) > 0:
                raise ValueError(f"{name} must be positive")
        if self.kick.periods < 1 or self.motion.head_units < 1 or self.penalties.spots_per_side < 1:
            raise ValueError("kick.periods, motion.head_units and penalties.spots_per_side must be at least 1")
        for name in ("p_walk", "p_turn", "p_kick", "p_fall_again"):
            if not 0.0 <= getattr(self.falls, name) <= 1.0:
                raise ValueError(f"falls.{name} must be a probability in [0, 1]")
        for name in ("contact_base", "contact_base_pusher", "goalpost_base"):
            if not 0.0 < getattr(self.falls, name) <= 1.0:
                raise ValueError(f"falls.{name} must be in (0, 1]")
        self.start.check(self.field)

    @property
    def robot_names(self) -> list[str]:
        return robot_names(self.players_per_team)

    @property
    def n_robots(self) -> int:
        return 2 * self.players_per_team

    @property
    def period_seconds(self) -> float:
        return self.rates.motion_period_ticks * self.rates.tick_seconds

    @property
    def episode_periods(self) -> int:
        return max(1, round(self.episode_seconds / self.period_seconds))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None = None) -> "SoccerConfig":
        """Build from nested plain values (YAML, keyword arguments); unknown keys are refused by name."""
        return build_settings(cls, dict(values or {}), "soccer")


__all__ = ["robot_names", "SoccerConfig", "MotionConfig", "KickConfig", "FallConfig", "PenaltyConfig", "BallConfig",
           "RewardConfig", "StartConfig", "MAX_PLAYERS_PER_TEAM", "SCENARIO_SOCCER", "START_KINDS", "DEFENDERS",
           "is_soccer_world", "replace"]
