"""High-level robot commands, one per motion period, and their strict validation.

Values follow dynenv_msgs/Action: walk NONE/FORWARD/BACKWARD/LEFT/RIGHT, turn NONE/LEFT/RIGHT (left = counter-
clockwise, REP 103), kick NONE/LEFT_FOOT/RIGHT_FOOT, and a head turn in rad per period.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from dynenv_ros.soccer.agent_actions import head_radians


class Walk(IntEnum):
    NONE = 0
    FORWARD = 1
    BACKWARD = 2
    LEFT = 3
    RIGHT = 4


class Turn(IntEnum):
    NONE = 0
    LEFT = 1
    RIGHT = 2


class Kick(IntEnum):
    NONE = 0
    LEFT_FOOT = 1
    RIGHT_FOOT = 2


@dataclass(frozen=True)
class SoccerAction:
    walk: Walk = Walk.NONE
    turn: Turn = Turn.NONE
    kick: Kick = Kick.NONE
    head_yaw_delta: float = 0.0   # rad over the period; the world clamps the head to its limit

    @property
    def moves(self) -> bool:
        return self.walk != Walk.NONE or self.turn != Turn.NONE


IDLE = SoccerAction()


# Each command enum's members by value (values 0, 1, …): a lookup costs a fraction of ``kind(value)``.
_MEMBERS: dict[type[IntEnum], tuple[IntEnum, ...]] = {kind: tuple(kind) for kind in (Walk, Turn, Kick)}
assert all(member.value == i for members in _MEMBERS.values() for i, member in enumerate(members))


def _choice(robot: str, name: str, value: Any, kind: type[IntEnum]) -> IntEnum:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) and not (
            isinstance(value, (float, np.floating)) and float(value).is_integer()):
        raise ValueError(f"{robot}: action field '{name}' must be an integer {kind.__name__} value "
                         f"({', '.join(f'{m.value}={m.name}' for m in kind)}), got {value!r}")
    members, index = _MEMBERS[kind], int(value)
    if 0 <= index < len(members):
        return members[index]
    raise ValueError(f"{robot}: action field '{name}'={index} is out of range "
                     f"({', '.join(f'{m.value}={m.name}' for m in kind)})")


def parse_action(robot: str, raw: Any, *, head_mode: str, head_step: float, head_units: int) -> SoccerAction:
    """Turn what a caller passed for one robot into a SoccerAction, or raise ValueError naming robot and field.

    Accepted forms: a SoccerAction; discrete mode — 4 integers [walk, turn, kick, head] with head an index in
    0..2·units (units steps of ``head_step`` each, centred); continuous mode — a mapping
    {"motion": [walk, turn, kick], "head": [rad]} or 4 numbers [walk, turn, kick, head_rad].
    """
    max_delta = head_step * head_units
    if isinstance(raw, SoccerAction):
        motion: Any = (raw.walk, raw.turn, raw.kick)
        head: Any = raw.head_yaw_delta
        head_is_index = False
    elif isinstance(raw, dict):
        if set(raw) != {"motion", "head"}:
            raise ValueError(f"{robot}: action mapping needs exactly the keys 'motion' and 'head', got {sorted(raw)}")
        motion = np.asarray(raw["motion"]).ravel()
        head_arr = np.asarray(raw["head"]).ravel()
        if motion.shape != (3,) or head_arr.shape != (1,):
            raise ValueError(f"{robot}: action 'motion' must hold 3 values and 'head' 1, got shapes "
                             f"{np.shape(raw['motion'])} and {np.shape(raw['head'])}")
        head, head_is_index = head_arr[0], False
    else:
        arr = np.asarray(raw)
        if arr.shape != (4,):
            raise ValueError(f"{robot}: action must have shape (4,) [walk, turn, kick, head], got shape {arr.shape}")
        if arr.dtype.kind not in "iuf":
            raise ValueError(f"{robot}: action must be numeric, got dtype {arr.dtype}")
        motion, head = arr[:3], arr[3]
        head_is_index = head_mode == "discrete"
    walk = _choice(robot, "walk", motion[0], Walk)
    turn = _choice(robot, "turn", motion[1], Turn)
    kick = _choice(robot, "kick", motion[2], Kick)
    if head_is_index:
        if isinstance(head, (float, np.floating)) and not float(head).is_integer() or isinstance(head, bool):
            raise ValueError(f"{robot}: action field 'head' must be an integer index in 0..{2 * head_units}, "
                             f"got {head!r}")
        if not 0 <= int(head) <= 2 * head_units:
            raise ValueError(f"{robot}: action field 'head'={int(head)} is out of range 0..{2 * head_units}")
        delta = head_radians(int(head), head_units, head_step)
    else:
        delta = float(head)
        if not math.isfinite(delta):
            raise ValueError(f"{robot}: action field 'head' must be finite, got {delta}")
        if abs(delta) > max_delta + 1e-9:
            raise ValueError(f"{robot}: action field 'head'={delta:.4f} rad is beyond ±{max_delta:.4f} rad per period")
    return SoccerAction(walk, turn, kick, delta)
