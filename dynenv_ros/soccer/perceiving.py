"""The scripted team on its robots' own perception: ``keeper_and_chasers`` that knows only what a robot can know.

The ground-truth scripted team (``soccer.scripted``) reads the world; a learning agent sees noisy, partial
detections and (optionally) a pose estimate. This team plays the same goalkeeper and chasers, but each robot acts on
a *believed* snapshot built from its own padded observation of the period (``envs.padded_layout``: the object rows
of its vision frames, its proprioception and the GameController's broadcast) and its self-localization estimate
(``perception.localization``; the true pose where the perception preset is ``none``):

- **Itself:** the pose estimate (field frame, possibly mirrored: a flipped robot plays toward its own goal, as a
  real one does), the head yaw and the fallen / penalized / kicking bits of its last frame.
- **The ball:** the most confident ball detection of the latest frame that shows one, camera frame → body (head
  yaw of that frame) → field (the estimate). A detection can be a false positive or a confusion: the team believes
  it, as a simple real behaviour would. When no frame of the period shows a ball, the last believed position is
  kept for ``memory_seconds`` (it is in field coordinates, so the robot's own motion is accounted for by the
  estimate); after that the ball is lost and the robot searches: it turns on the spot and sweeps its head, and a
  goalkeeper returns to its guard spot.
- **The game:** ball ownership from the GameController (relative → absolute team), as every robot receives it.

Each frame's detections are taken at the frame's instant but placed with the estimate at the period's end (the
robot moved by at most one period's walk in between, ≤ 0.1 m at the default motion): a real stack would use
odometry for that; the error is within the detection noise at a few metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.perception.detections import FEATURE_COLUMNS
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import MotionConfig
from dynenv_ros.soccer.field import FieldGeometry
from dynenv_ros.soccer.observation_columns import GAME_COLUMNS, PROPRIOCEPTION_COLUMNS
from dynenv_ros.soccer.scripted import ChaserPolicy, GoalkeeperPolicy, ScriptedPolicy

MEMORY_SECONDS = 3.0          # how long a ball no frame shows is still believed where it was last seen
_CLASS, _X, _Y, _CONFIDENCE = (FEATURE_COLUMNS.index(c) for c in ("class_id", "x", "y", "confidence"))
_HEAD, _FALLEN, _PENALIZED, _KICKING = (PROPRIOCEPTION_COLUMNS.index(c)
                                        for c in ("head_yaw", "fallen", "penalized", "kicking"))
_OWNER = GAME_COLUMNS.index("ball_owner")


@dataclass(frozen=True)
class BallSighting:
    """Where a robot believes the ball is (field frame, m) and how old that belief is (s)."""
    x: float
    y: float
    age: float


def ball_in_view(objects: np.ndarray, mask: np.ndarray, head_yaw: np.ndarray) -> tuple[int, float, float] | None:
    """(frame, body-frame x, body-frame y) of the most confident ball detection in the latest frame showing one.

    ``objects`` (F, O, 19) feature rows in the camera frame, ``mask`` (F, O), ``head_yaw`` (F,) rad."""
    is_ball = (mask > 0) & (np.rint(objects[..., _CLASS]) == int(ObjectClass.BALL))
    frames = is_ball.any(axis=1).nonzero()[0]
    if not len(frames):
        return None
    frame = int(frames[-1])
    rows = objects[frame][is_ball[frame]]
    best = rows[int(np.argmax(rows[:, _CONFIDENCE]))]
    c, s = math.cos(float(head_yaw[frame])), math.sin(float(head_yaw[frame]))
    cx, cy = float(best[_X]), float(best[_Y])
    return frame, c * cx - s * cy, s * cx + c * cy


def to_field(pose: Sequence[float], bx: float, by: float) -> tuple[float, float]:
    """A body-frame point seen from ``pose`` (x, y, yaw) → field frame."""
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    return x + c * bx - s * by, y + s * bx + c * by


class PerceivingPolicy:
    """One robot's scripted play (a chaser's or a goalkeeper's) on its own observation and pose estimate.

    Stateful only through the ball memory; ``reset`` at each episode start."""

    def __init__(self, inner: ScriptedPolicy, robot_id: int, team: int, period_seconds: float,
                 memory_seconds: float = MEMORY_SECONDS, motion: MotionConfig | None = None) -> None:
        if team not in (1, -1):
            raise ValueError(f"team must be +1 (A) or -1 (B), got {team!r}")
        if not (period_seconds > 0 and math.isfinite(period_seconds)):
            raise ValueError(f"period_seconds must be positive, got {period_seconds!r}")
        if not (memory_seconds >= 0 and math.isfinite(memory_seconds)):
            raise ValueError(f"memory_seconds must be ≥ 0, got {memory_seconds!r}")
        self.inner, self.robot_id, self.team = inner, int(robot_id), int(team)
        self.period_seconds, self.memory_seconds = float(period_seconds), float(memory_seconds)
        motion = motion or MotionConfig()
        self.head_max_delta, self.head_limit = float(motion.head_max_delta), float(motion.head_limit)
        self.ball: BallSighting | None = None
        self._sweep = 1.0

    def reset(self) -> None:
        self.ball = None
        self._sweep = 1.0

    def believe(self, observation: Mapping[str, np.ndarray], pose: Sequence[float]) -> WorldSnapshot:
        """The snapshot this robot believes in after the period: itself at ``pose``, the ball where it saw it last
        (absent when lost), ownership from the GameController."""
        proprioception = np.asarray(observation["proprioception"], np.float32)
        head = proprioception[:, _HEAD]
        seen = ball_in_view(np.asarray(observation["objects"], np.float32),
                            np.asarray(observation["object_mask"], np.float32), head)
        frames = len(proprioception)
        if seen is not None:
            frame, bx, by = seen
            x, y = to_field(pose, bx, by)
            # the frame's age within the period: the last frame is the period's end
            self.ball = BallSighting(x, y, (frames - 1 - frame) * self.period_seconds / frames)
        elif self.ball is not None:
            age = self.ball.age + self.period_seconds
            self.ball = BallSighting(self.ball.x, self.ball.y, age) if age <= self.memory_seconds else None
        last = proprioception[-1]
        status = ObjectStatus.NONE
        for column, bit in ((_FALLEN, ObjectStatus.FALLEN), (_PENALIZED, ObjectStatus.PENALIZED),
                            (_KICKING, ObjectStatus.KICKING)):
            if last[column] > 0.5:
                status |= bit
        me = BodyState(id=self.robot_id, class_id=ObjectClass.ROBOT, team=self.team, x=float(pose[0]),
                       y=float(pose[1]), yaw=float(pose[2]), head_yaw=float(last[_HEAD]), status=status)
        objects: tuple[BodyState, ...] = (me,)
        if self.ball is not None:
            objects += (BodyState(id=-1, class_id=ObjectClass.BALL, x=self.ball.x, y=self.ball.y),)
        owner = int(round(float(np.asarray(observation["game"])[_OWNER]))) * self.team
        return WorldSnapshot(scenario=0, episode_id=0, tick=0, tick_period=0.0, game_time=0.0, time_remaining=0.0,
                             phase=0, ball_owner_team=owner, objects=objects)

    def act(self, observation: Mapping[str, np.ndarray], pose: Sequence[float]) -> SoccerAction:
        snapshot = self.believe(observation, pose)
        if self.ball is not None:
            return self.inner.act(snapshot, self.robot_id)
        return self._search(snapshot.objects[0])

    def _search(self, me: BodyState) -> SoccerAction:
        """No ball believed: sweep the head end to end and turn on the spot (a keeper walks back to its spot)."""
        if abs(me.head_yaw) >= self.head_limit - self.head_max_delta:
            self._sweep = -math.copysign(1.0, me.head_yaw)
        head = self._sweep * self.head_max_delta
        if me.status & (ObjectStatus.FALLEN | ObjectStatus.PENALIZED | ObjectStatus.KICKING):
            return SoccerAction(head_yaw_delta=head)
        if isinstance(self.inner, GoalkeeperPolicy):
            # guard spot in front of the own goal, believed from the estimate: the inner keeper with a ball
            # imagined at the centre spot takes it there, facing the field
            centre = BodyState(id=-1, class_id=ObjectClass.BALL, x=0.0, y=0.0)
            snapshot = WorldSnapshot(scenario=0, episode_id=0, tick=0, tick_period=0.0, game_time=0.0,
                                     time_remaining=0.0, phase=0, objects=(me, centre))
            action = self.inner.act(snapshot, self.robot_id)
            return SoccerAction(action.walk, action.turn, Kick.NONE, head)
        return SoccerAction(Walk.NONE, Turn.LEFT, Kick.NONE, head)


PERCEIVING_KINDS = ("keeper_and_chasers", "chaser")


def perceiving_team(players_per_team: int, period_seconds: float, field: FieldGeometry | None = None,
                    motion: MotionConfig | None = None, memory_seconds: float = MEMORY_SECONDS,
                    kind: str = "keeper_and_chasers") -> list[PerceivingPolicy]:
    """Both teams' robots (A's slots, then B's), ``keeper_and_chasers`` as in ``scripted.team_policies``: a
    goalkeeper in slot 0 of each team of two or more, chasers elsewhere; ``kind="chaser"``: chasers in every slot
    (the imitation teacher ``perceiving``, ``envs.teacher``)."""
    if isinstance(players_per_team, bool) or not isinstance(players_per_team, int) or players_per_team < 1:
        raise ValueError(f"players_per_team must be a positive integer, got {players_per_team!r}")
    if kind not in PERCEIVING_KINDS:
        raise ValueError(f"kind must be one of {PERCEIVING_KINDS}, got {kind!r}")
    m = motion or MotionConfig()
    out = []
    for i in range(2 * players_per_team):
        keeper = kind == "keeper_and_chasers" and i % players_per_team == 0 and players_per_team > 1
        inner = GoalkeeperPolicy(field, m.head_max_delta) if keeper else ChaserPolicy(field, m.head_max_delta)
        out.append(PerceivingPolicy(inner, i, 1 if i < players_per_team else -1, period_seconds, memory_seconds, m))
    return out


__all__ = ["PerceivingPolicy", "BallSighting", "perceiving_team", "PERCEIVING_KINDS", "ball_in_view", "to_field",
           "MEMORY_SECONDS"]
