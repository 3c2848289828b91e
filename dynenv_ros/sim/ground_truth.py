"""Ground truth of a world at one instant, in the shape of dynenv_msgs/WorldState (field frame, SI units).

Scenarios fill these plain records; the simulator node turns them into messages and the renderer draws them, so
neither needs to know a scenario's internals.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus


@dataclass(frozen=True)
class BodyState:
    """One body: pose and velocity in the field frame (m, rad, m/s, rad/s), as ObjectState.msg."""
    id: int
    class_id: ObjectClass
    team: int = 0                 # +1 team A, -1 team B, 0 none (TEAM_* of the messages use the same numbers)
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    yaw_rate: float = 0.0
    head_yaw: float = 0.0         # relative to the body
    size_x: float = 0.0
    size_y: float = 0.0
    status: ObjectStatus = ObjectStatus.NONE
    penalty_remaining: float = 0.0
    goal_x: float = float("nan")
    goal_y: float = float("nan")


@dataclass(frozen=True)
class WorldSnapshot:
    """The whole world, as WorldState.msg: clock, game phase, ball ownership, touch chain, score and bodies."""
    scenario: int
    episode_id: int
    tick: int
    tick_period: float
    game_time: float
    time_remaining: float
    phase: int
    ball_owner_team: int = 0
    ball_owner_remaining: float = 0.0
    last_touch_robot_ids: tuple[int, ...] = ()
    score_team_a: int = 0
    score_team_b: int = 0
    objects: tuple[BodyState, ...] = field(default_factory=tuple)

    def of_class(self, class_id: ObjectClass) -> tuple[BodyState, ...]:
        return tuple(o for o in self.objects if o.class_id == class_id)
