"""Core records ↔ dynenv_msgs messages. Field-for-field copies: the core already speaks SI units and REP 103."""
from __future__ import annotations

from typing import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from dynenv_msgs.msg import Action, Detection, DetectionArray, ObjectState, StepFeedback, WorldState
from geometry_msgs.msg import Point

from dynenv_ros.sim.frames import WORLD_FRAME, camera_frame  # noqa: F401  (re-exported)
from dynenv_ros.sim.ground_truth import WorldSnapshot, snapshot_from_msg  # noqa: F401  (re-exported)
from dynenv_ros.soccer.actions import SoccerAction



def sim_time(tick: int, tick_seconds: float) -> Time:
    ns = round(tick * tick_seconds * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def detections_to_msgs(rows: np.ndarray) -> list[Detection]:
    """Structured DETECTION_DTYPE rows → Detection messages (simulator-only columns dropped)."""
    out = []
    for r in rows.tolist():   # tuples in dtype order: fast attribute-free access
        (class_id, x, y, yaw, sx, sy, conf, team, subtype, fallen, penalized, lsx, lsy, lex, ley, sighting,
         _true_id, _true_class) = r
        out.append(Detection(class_id=class_id, position=Point(x=x, y=y, z=0.0), yaw=yaw, size_x=sx, size_y=sy,
                             confidence=conf, team=team, subtype=subtype, fallen=fallen, penalized=penalized,
                             line_start=Point(x=lsx, y=lsy, z=0.0), line_end=Point(x=lex, y=ley, z=0.0),
                             sighting=sighting))
    return out


def detection_array(rows: np.ndarray, *, robot_id: int, robot_name: str, episode_id: int, motion_period: int,
                    frame_index: int, frames_per_period: int, head_yaw: float, fallen: bool, penalized: bool,
                    kicking: bool, ball_owner: int, ball_owner_seconds: float, game_seconds_remaining: float,
                    stamp: Time) -> DetectionArray:
    """``ball_owner`` is relative to the observer's team (+1 own, -1 opponents, 0 free), as the message says."""
    msg = DetectionArray(robot_id=robot_id, episode_id=episode_id, motion_period=motion_period,
                         frame_index=frame_index, frames_per_period=frames_per_period, head_yaw=head_yaw,
                         self_fallen=fallen, self_penalized=penalized, self_kicking=kicking, ball_owner=ball_owner,
                         ball_owner_seconds=ball_owner_seconds, game_seconds_remaining=game_seconds_remaining,
                         detections=detections_to_msgs(rows))
    msg.header.stamp = stamp
    msg.header.frame_id = camera_frame(robot_name)
    return msg


def world_state(snapshot: WorldSnapshot, stamp: Time) -> WorldState:
    msg = WorldState(scenario=snapshot.scenario, episode_id=snapshot.episode_id, tick=snapshot.tick,
                     tick_period=snapshot.tick_period, game_time=snapshot.game_time,
                     time_remaining=snapshot.time_remaining, phase=snapshot.phase,
                     ball_owner_team=snapshot.ball_owner_team, ball_owner_remaining=snapshot.ball_owner_remaining,
                     last_touch_robot_ids=list(snapshot.last_touch_robot_ids), score_team_a=snapshot.score_team_a,
                     score_team_b=snapshot.score_team_b,
                     objects=[ObjectState(id=o.id, class_id=int(o.class_id), team=o.team, x=o.x, y=o.y, yaw=o.yaw,
                                          vx=o.vx, vy=o.vy, yaw_rate=o.yaw_rate, head_yaw=o.head_yaw,
                                          size_x=o.size_x, size_y=o.size_y, status=int(o.status),
                                          penalty_remaining=o.penalty_remaining, goal_x=o.goal_x, goal_y=o.goal_y)
                              for o in snapshot.objects])
    msg.header.stamp = stamp
    msg.header.frame_id = WORLD_FRAME
    return msg


def step_feedback(*, robot_id: int, episode_id: int, motion_period: int, rewards: dict[str, float],
                  terminated: bool, truncated: bool, seen_object_ids: Sequence[int], landmarks_seen: float,
                  stamp: Time, action_digest: bytes = b"") -> StepFeedback:
    """``action_digest``: which Action the period ran for this robot (``security.action_auth``); empty when it
    acted by default."""
    msg = StepFeedback(robot_id=robot_id, episode_id=episode_id, motion_period=motion_period,
                       reward_primary=rewards["primary"], reward_rule=rewards["rule"],
                       reward_auxiliary=rewards["auxiliary"], reward_observation=rewards["observation"],
                       reward_total=sum(rewards.values()), terminated=terminated, truncated=truncated,
                       seen_object_ids=[i for i in seen_object_ids if i >= 0], landmarks_seen=landmarks_seen,
                       action_digest=action_digest)
    msg.header.stamp = stamp
    return msg


def action_msg(action: SoccerAction, *, robot_id: int, episode_id: int, motion_period: int, stamp: Time) -> Action:
    msg = Action(robot_id=robot_id, episode_id=episode_id, motion_period=motion_period, walk=int(action.walk),
                 turn=int(action.turn), kick=int(action.kick), head_yaw_delta=float(action.head_yaw_delta),
                 throttle=0.0, brake=0.0, steering=0.0)
    msg.header.stamp = stamp
    return msg
