"""Ground truth of a world at one instant, in the shape of dynenv_msgs/WorldState (field frame, SI units).

Scenarios fill these plain records; the simulator node turns them into messages and the renderer draws them, so
neither needs to know a scenario's internals.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus


@dataclass(frozen=True)
class BodyState:
    """One body: pose and velocity in the field frame (m, rad, m/s, rad/s), as ObjectState.msg."""
    id: int
    class_id: ObjectClass | int   # an int: a class this code base does not know yet (a replayed recording)
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


def _object_class(value: int) -> ObjectClass | int:
    try:
        return ObjectClass(int(value))
    except ValueError:   # a class this code base does not know yet: keep the number rather than fail a replay
        return int(value)


def body_from_msg(o: Any) -> BodyState:
    """ObjectState (rclpy or rosbags: attributes only, no ROS import) → BodyState, field for field."""
    return BodyState(id=int(o.id), class_id=_object_class(o.class_id), team=int(o.team), x=float(o.x),
                     y=float(o.y), yaw=float(o.yaw), vx=float(o.vx), vy=float(o.vy), yaw_rate=float(o.yaw_rate),
                     head_yaw=float(o.head_yaw), size_x=float(o.size_x), size_y=float(o.size_y),
                     status=ObjectStatus(int(o.status)), penalty_remaining=float(o.penalty_remaining),
                     goal_x=float(o.goal_x), goal_y=float(o.goal_y))


def snapshot_from_msg(msg: Any) -> WorldSnapshot:
    """WorldState (rclpy or rosbags) → WorldSnapshot, the inverse of ``ros.conversions.world_state``."""
    return WorldSnapshot(scenario=int(msg.scenario), episode_id=int(msg.episode_id), tick=int(msg.tick),
                         tick_period=float(msg.tick_period), game_time=float(msg.game_time),
                         time_remaining=float(msg.time_remaining), phase=int(msg.phase),
                         ball_owner_team=int(msg.ball_owner_team),
                         ball_owner_remaining=float(msg.ball_owner_remaining),
                         last_touch_robot_ids=tuple(int(i) for i in msg.last_touch_robot_ids),
                         score_team_a=int(msg.score_team_a), score_team_b=int(msg.score_team_b),
                         objects=tuple(body_from_msg(o) for o in msg.objects))
