"""The robot's own state in the frames the reverse vision adapter makes (docs/deploy.md, "The robot's own state"):
what a real robot publishes besides its camera, put into DetectionArray's proprioception and GameController
fields. ROS-free: messages are read by attribute, times are integer nanoseconds.

- **Head yaw**: the position of joint ``head_yaw_joint`` (``HeadYaw`` on the NAO) in ``sensor_msgs/JointState``,
  the sample stamped nearest the frame's stamp; none within ``head_yaw_max_age`` of it is stale. The head moves up
  to 37.5° per period, so the sample must be the frame's own moment, not the newest.
- **Fallen, penalized**: ``std_msgs/Bool``, the newest value; one older than ``state_max_age`` on arrival (the
  node's clock) is stale. Publishers send them periodically (a fall detector every cycle, a GameController bridge
  at its 2 Hz), so an old value means the publisher stopped, not that nothing changed.
- **GameController state**: ``std_msgs/Float32MultiArray`` with exactly the three ``GAME_COLUMNS`` values —
  ball owner relative to the robot's team (+1 own, −1 opponents, 0 free), the seconds left of that ownership, the
  seconds left in the half — aged like the flags. Anything else (another length, a non-finite value, an owner
  outside −1, 0, +1) is refused with the reason (``state_malformed``).

Missing (never received) or stale values fall back to ``DEFAULTS`` — what the adapter gave before it read these
topics: head straight, standing, playing, free ball, no seconds left — and every value used, stale or missing is
counted per frame (``<value>_used``, ``<value>_stale``, ``<value>_missing``).
"""
from __future__ import annotations

import bisect
import math
from collections import Counter
from typing import Any

from dynenv_ros.envs.padded_layout import GAME_COLUMNS

HEAD_YAW, FALLEN, PENALIZED, GAME_STATE = "head_yaw", "fallen", "penalized", "game_state"
VALUES = (HEAD_YAW, FALLEN, PENALIZED, GAME_STATE)
DEFAULTS: dict[str, Any] = {HEAD_YAW: 0.0, FALLEN: False, PENALIZED: False, GAME_STATE: (0, 0.0, 0.0)}
HEAD_YAW_HISTORY = 256           # joint samples kept: 2.5 s of a 100 Hz joint_states


def stamp_of(msg: Any) -> int:
    """A message's header stamp in ns (0 if it has none)."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    return 0 if stamp is None else int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def joint_position(msg: Any, joint: str) -> float | None:
    """Joint ``joint``'s position in a JointState, None if it is not named or has no finite position."""
    names = list(msg.name)
    if joint not in names:
        return None
    k = names.index(joint)
    if k >= len(msg.position) or not math.isfinite(msg.position[k]):
        return None
    return float(msg.position[k])


def game_problem(values: Any) -> str:
    """Why a Float32MultiArray's data cannot be the GameController state ('' if it can)."""
    values = list(values)
    if len(values) != len(GAME_COLUMNS):
        return f"game_state has {len(values)} values, expected {len(GAME_COLUMNS)} ({', '.join(GAME_COLUMNS)})"
    if not all(math.isfinite(v) for v in values):
        return "game_state has a non-finite value"
    if values[0] not in (-1.0, 0.0, 1.0):
        return f"game_state ball_owner {values[0]:g} is not -1, 0 or +1"
    if values[1] < 0 or values[2] < 0:
        return "game_state has negative seconds"
    return ""


class RobotState:
    """One robot's latest state values and how they fill its frames (module docstring)."""

    def __init__(self, head_yaw_joint: str = "HeadYaw", head_yaw_max_age_s: float = 0.1,
                 state_max_age_s: float = 1.0, counts: Counter[str] | None = None) -> None:
        self.joint = head_yaw_joint
        self.head_yaw_max_age_ns = round(head_yaw_max_age_s * 1e9)
        self.state_max_age_ns = round(state_max_age_s * 1e9)
        self.counts: Counter[str] = Counter() if counts is None else counts
        self.head_stamps: list[int] = []            # sorted; head_yaws in the same order
        self.head_yaws: list[float] = []
        self.latest: dict[str, tuple[int, Any]] = {}      # value -> (arrival ns, value)
        self.refusal = ""

    # -- messages in -------------------------------------------------------------------------------------------
    def joint_state(self, msg: Any, arrival_ns: int) -> None:
        """File a JointState; one without the head joint is ignored (a robot may split its joint topics)."""
        yaw = joint_position(msg, self.joint)
        if yaw is None:
            return
        stamp = stamp_of(msg) or arrival_ns
        if self.head_stamps and stamp < self.head_stamps[0] - self.head_yaw_max_age_ns:
            self.head_stamps, self.head_yaws = [], []          # the clock went back: start again
        k = bisect.bisect_right(self.head_stamps, stamp)
        self.head_stamps.insert(k, stamp)
        self.head_yaws.insert(k, yaw)
        if len(self.head_stamps) > HEAD_YAW_HISTORY:
            del self.head_stamps[0], self.head_yaws[0]

    def flag(self, which: str, msg: Any, arrival_ns: int) -> None:
        """File a std_msgs/Bool of ``FALLEN`` or ``PENALIZED``."""
        self.latest[which] = (arrival_ns, bool(msg.data))

    def game_state(self, msg: Any, arrival_ns: int) -> str:
        """File a GameController state, or refuse it: returns the reason ('' if filed)."""
        problem = game_problem(msg.data)
        if problem:
            self.counts["state_malformed"] += 1
            self.refusal = problem
            return problem
        owner, owner_seconds, remaining = (float(v) for v in msg.data)
        self.latest[GAME_STATE] = (arrival_ns, (int(owner), owner_seconds, remaining))
        return ""

    # -- values out --------------------------------------------------------------------------------------------
    def head_yaw(self, frame_stamp_ns: int) -> float:
        """The head yaw sampled nearest the frame's stamp, else the default (counted)."""
        if not self.head_stamps:
            self.counts["head_yaw_missing"] += 1
            return DEFAULTS[HEAD_YAW]
        k = bisect.bisect_left(self.head_stamps, frame_stamp_ns)
        near = min((j for j in (k - 1, k) if 0 <= j < len(self.head_stamps)),
                   key=lambda j: abs(self.head_stamps[j] - frame_stamp_ns))
        if abs(self.head_stamps[near] - frame_stamp_ns) > self.head_yaw_max_age_ns:
            self.counts["head_yaw_stale"] += 1
            return DEFAULTS[HEAD_YAW]
        self.counts["head_yaw_used"] += 1
        return self.head_yaws[near]

    def value(self, which: str, now_ns: int) -> Any:
        """The newest ``FALLEN``, ``PENALIZED`` or ``GAME_STATE`` value, else the default (counted)."""
        entry = self.latest.get(which)
        if entry is None:
            self.counts[f"{which}_missing"] += 1
            return DEFAULTS[which]
        if now_ns - entry[0] > self.state_max_age_ns:
            self.counts[f"{which}_stale"] += 1
            return DEFAULTS[which]
        self.counts[f"{which}_used"] += 1
        return entry[1]

    def fill(self, frame: Any, frame_stamp_ns: int, now_ns: int) -> None:
        """Set a DetectionArray's proprioception and GameController fields."""
        frame.head_yaw = self.head_yaw(frame_stamp_ns)
        frame.self_fallen = self.value(FALLEN, now_ns)
        frame.self_penalized = self.value(PENALIZED, now_ns)
        frame.ball_owner, frame.ball_owner_seconds, frame.game_seconds_remaining = self.value(GAME_STATE, now_ns)


__all__ = ["DEFAULTS", "FALLEN", "GAME_STATE", "HEAD_YAW", "PENALIZED", "VALUES", "RobotState", "game_problem",
           "joint_position", "stamp_of"]
