"""Authenticated frames in the train graph (issue 43 item 4): the simulator tags each ``DetectionArray`` and
``WorldState`` it publishes, and the policy node and the trainer use only frames whose tag verifies.

Why: a frame decides what a policy does and, in the train graph, what the trainer learns; DDS without SROS2 does
not say who published it. The frames' messages have no ``mac`` field (a real robot's vision stack publishes the same
type and signs nothing), so the tag travels on a **companion topic**, ``<topic>_mac`` (``std_msgs/UInt8MultiArray``,
``data`` = the 16-byte tag), published right after the frame (docs/decisions.md, issue 43):

- **The secret**: ``frames.secret`` (32 bytes, mode 0600, ``action_auth.load_secret``), held by the simulator, the
  trainer and the train graph's policy nodes; not ``simulator.secret`` (a policy node holding it could forge the
  feedback the trainer learns from) and not a team secret (a robot could forge its team-mates' frames).
- **Canonical bytes** (``detection_array_bytes``, ``world_state_bytes``): a domain label, the topic (length-
  prefixed: a genuine frame replayed onto another robot's topic does not verify), the header and every field in
  message order, little-endian at the message's widths, NaN written as one canonical NaN, arrays length-prefixed.
  The simulator computes a frame's bytes from its numpy records (``detection_rows_bytes``), a receiver from the
  message: a test checks they agree.
- **Pairing** (``FrameGate``): a receiver computes the tag it expects for each frame and waits for it on the
  companion topic, at most ``wait_s`` (2 s) and ``capacity`` frames; tags that came first wait for their frame
  likewise. A frame or tag that arrives is matched before the others expire, and a receiver takes every tag already
  queued before it expires anything (``ros/frame_tags.py``), so a node busier than ``wait_s`` does not refuse
  frames whose tags had come. A frame is used once its tag came; a forged, altered or untagged frame never gets one (a companion tag
  cannot tell the three apart) and is refused as ``frame_mac_missing`` when its wait ends; a genuine frame received
  again after it was used is ``frame_replayed``; a tag of another length is ``tag_malformed``; a tag no frame
  claimed within the wait is ``tag_unmatched``.

Standard library and numpy only; messages are read by attribute.
"""
from __future__ import annotations

import hmac
import math
import struct
from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dynenv_ros.security.action_auth import TAG_BYTES, tag

FRAMES = "frames"                          # frames.secret in secrets_dir
TAG_SUFFIX = "_mac"                        # the companion topic: <frame topic>_mac
DETECTIONS_DOMAIN = b"dynenv_msgs/DetectionArray/v1\n"
WORLD_STATE_DOMAIN = b"dynenv_msgs/WorldState/v1\n"
WAIT_S = 2.0                               # how long a frame waits for its tag (and a tag for its frame)
CAPACITY = 1024                            # frames (and tags) waiting per gate; the oldest is refused first
REPLAY_MEMORY = 4096                       # tags of frames used, to refuse a replay
# Refusal reasons, as counted (frames_refused_<reason> in the nodes' diagnostics).
REASONS = ("frame_mac_missing", "frame_replayed", "tag_malformed", "tag_unmatched")
_NAN32 = struct.unpack("<f", struct.pack("<f", math.nan))[0]
_LENGTH = struct.Struct("<I")
# DetectionArray after the header: robot_id u16, episode_id u32, motion_period u32, frame_index u8,
# frames_per_period u8, head_yaw f32, self_fallen, self_penalized, self_kicking bool, ball_owner i8,
# ball_owner_seconds f32, game_seconds_remaining f32.
_DETECTION_ARRAY = struct.Struct("<HIIBBf???bff")
# Detection: class_id u8, position xyz f64, yaw, size_x, size_y, confidence f32, team i8, subtype u8, fallen,
# penalized bool, line_start xyz f64, line_end xyz f64, sighting u8 (packed, no padding).
_DETECTION = struct.Struct("<BdddffffbB??ddddddB")
_DETECTION_DTYPE = np.dtype([("class_id", "u1"), ("px", "<f8"), ("py", "<f8"), ("pz", "<f8"), ("yaw", "<f4"),
                             ("size_x", "<f4"), ("size_y", "<f4"), ("confidence", "<f4"), ("team", "i1"),
                             ("subtype", "u1"), ("fallen", "u1"), ("penalized", "u1"), ("lsx", "<f8"),
                             ("lsy", "<f8"), ("lsz", "<f8"), ("lex", "<f8"), ("ley", "<f8"), ("lez", "<f8"),
                             ("sighting", "u1")])
assert _DETECTION_DTYPE.itemsize == _DETECTION.size
# WorldState after the header: scenario u8, episode_id u32, tick u64, tick_period, game_time, time_remaining f64,
# phase u8, ball_owner_team i8, ball_owner_remaining f32, score_team_a, score_team_b u16.
_WORLD_STATE = struct.Struct("<BIQdddBbfHH")
# ObjectState: id u32, class_id u8, team i8, x, y, yaw, vx, vy, yaw_rate, head_yaw f64, size_x, size_y f32,
# status u8, penalty_remaining f32, goal_x, goal_y f64.
_OBJECT = struct.Struct("<IBbdddddddffBfdd")


def _text(value: str) -> bytes:
    data = value.encode("utf-8")
    return _LENGTH.pack(len(data)) + data


def _header(msg: Any) -> bytes:
    header = msg.header
    return struct.pack("<iI", int(header.stamp.sec), int(header.stamp.nanosec)) + _text(str(header.frame_id))


def _f(value: float) -> float:
    """One NaN for every NaN: the payload of a NaN is not part of what a frame says."""
    value = float(value)
    return _NAN32 if value != value else value


def _pack(layout: struct.Struct, *values: Any) -> bytes:
    try:
        return layout.pack(*values)
    except (struct.error, OverflowError, TypeError) as error:
        raise ValueError(f"a frame field is out of its type's range ({error})") from None


def detection_array_bytes(msg: Any, topic: str) -> bytes:
    """The canonical bytes of a DetectionArray published on ``topic`` (module docstring). ValueError for values no
    DetectionArray can hold."""
    head = _pack(_DETECTION_ARRAY, int(msg.robot_id), int(msg.episode_id), int(msg.motion_period),
                 int(msg.frame_index), int(msg.frames_per_period), _f(msg.head_yaw), bool(msg.self_fallen),
                 bool(msg.self_penalized), bool(msg.self_kicking), int(msg.ball_owner), _f(msg.ball_owner_seconds),
                 _f(msg.game_seconds_remaining))
    rows = [_pack(_DETECTION, int(d.class_id), _f(d.position.x), _f(d.position.y), _f(d.position.z), _f(d.yaw),
                  _f(d.size_x), _f(d.size_y), _f(d.confidence), int(d.team), int(d.subtype), bool(d.fallen),
                  bool(d.penalized), _f(d.line_start.x), _f(d.line_start.y), _f(d.line_start.z), _f(d.line_end.x),
                  _f(d.line_end.y), _f(d.line_end.z), int(d.sighting)) for d in msg.detections]
    return (DETECTIONS_DOMAIN + _text(topic) + _header(msg) + head + _LENGTH.pack(len(rows)) + b"".join(rows))


def detection_rows_bytes(rows: np.ndarray, topic: str, *, stamp_sec: int, stamp_nanosec: int, frame_id: str,
                         robot_id: int, episode_id: int, motion_period: int, frame_index: int,
                         frames_per_period: int, head_yaw: float, fallen: bool, penalized: bool, kicking: bool,
                         ball_owner: int, ball_owner_seconds: float, game_seconds_remaining: float) -> bytes:
    """``detection_array_bytes`` of the message the simulator publishes for ``rows`` (DETECTION_DTYPE records,
    ``ros/cdr.py``'s arguments), without building it: the simulator's side."""
    header = struct.pack("<iI", stamp_sec, stamp_nanosec) + _text(frame_id)
    head = _pack(_DETECTION_ARRAY, robot_id, episode_id, motion_period, frame_index, frames_per_period,
                 _f(np.float32(head_yaw)), bool(fallen), bool(penalized), bool(kicking), ball_owner,
                 _f(np.float32(ball_owner_seconds)), _f(np.float32(game_seconds_remaining)))
    block = np.zeros(len(rows), _DETECTION_DTYPE)
    for target, column in (("class_id", "class_id"), ("px", "x"), ("py", "y"), ("yaw", "yaw"),
                           ("size_x", "size_x"), ("size_y", "size_y"), ("confidence", "confidence"),
                           ("team", "team"), ("subtype", "subtype"), ("fallen", "fallen"),
                           ("penalized", "penalized"), ("lsx", "line_start_x"), ("lsy", "line_start_y"),
                           ("lex", "line_end_x"), ("ley", "line_end_y"), ("sighting", "sighting")):
        values = rows[column]
        if values.dtype.kind == "f":
            values = np.where(np.isnan(values), np.float32(_NAN32), values)
        block[target] = values
    return (DETECTIONS_DOMAIN + _text(topic) + header + head + _LENGTH.pack(len(rows)) + block.tobytes())


def world_state_bytes(msg: Any, topic: str) -> bytes:
    """The canonical bytes of a WorldState published on ``topic``."""
    head = _pack(_WORLD_STATE, int(msg.scenario), int(msg.episode_id), int(msg.tick), _f(msg.tick_period),
                 _f(msg.game_time), _f(msg.time_remaining), int(msg.phase), int(msg.ball_owner_team),
                 _f(msg.ball_owner_remaining), int(msg.score_team_a), int(msg.score_team_b))
    touches = [int(i) for i in msg.last_touch_robot_ids]
    objects = [_pack(_OBJECT, int(o.id), int(o.class_id), int(o.team), _f(o.x), _f(o.y), _f(o.yaw), _f(o.vx),
                     _f(o.vy), _f(o.yaw_rate), _f(o.head_yaw), _f(o.size_x), _f(o.size_y), int(o.status),
                     _f(o.penalty_remaining), _f(o.goal_x), _f(o.goal_y)) for o in msg.objects]
    return (WORLD_STATE_DOMAIN + _text(topic) + _header(msg) + head + _LENGTH.pack(len(touches))
            + _pack(struct.Struct(f"<{len(touches)}I"), *touches) + _LENGTH.pack(len(objects)) + b"".join(objects))


def tag_frame(secret: bytes, data: bytes) -> bytes:
    """The tag the simulator publishes on ``<topic>_mac`` for a frame of canonical bytes ``data``."""
    return tag(secret, data)


@dataclass
class _Waiting:
    since_ns: int
    item: Any = None


@dataclass
class FrameGate:
    """A receiver's pairing of frames with their tags (module docstring), for every topic it reads (a tag covers
    its topic). ``frame`` and ``tag`` return the frames now verified, in arrival order; refusals are counted in
    ``counts`` by reason, the last one described in ``last_refusal``."""
    secret: bytes
    wait_s: float = WAIT_S
    capacity: int = CAPACITY
    counts: dict[str, int] = field(default_factory=dict)
    last_refusal: str = ""

    def __post_init__(self) -> None:
        if len(self.secret) < 16 or not self.wait_s > 0 or self.capacity < 1:
            raise ValueError(f"a frame gate needs a secret of >= 16 bytes, wait_s > 0 and capacity >= 1 (got "
                             f"{len(self.secret)} bytes, {self.wait_s}, {self.capacity})")
        self._frames: OrderedDict[bytes, _Waiting] = OrderedDict()     # expected tag -> frame waiting for it
        self._tags: OrderedDict[bytes, _Waiting] = OrderedDict()       # tag -> when it came, waiting for its frame
        self._used: OrderedDict[bytes, None] = OrderedDict()
        for reason in REASONS + ("frames_verified",):
            self.counts.setdefault(reason, 0)

    @property
    def waiting(self) -> int:
        return len(self._frames)

    def frame(self, item: Any, data: bytes, now_ns: int, what: Hashable = "") -> list[Any]:
        """A frame of canonical bytes ``data`` arrived (``item``: what to hand on once verified; ``what``: a name
        for the log)."""
        expected = tag_frame(self.secret, data)
        if expected in self._used:
            self.refuse("frame_replayed", f"{what}: a frame already used arrived again")
            return []
        if self._tags.pop(expected, None) is not None:       # before the others expire: late is not forged
            self.expire(now_ns)
            return [self._use(expected, item)]
        self.expire(now_ns)
        if expected in self._frames:          # the same bytes twice before the tag: the first one waits
            self.refuse("frame_replayed", f"{what}: a frame arrived twice before its tag")
            return []
        self._frames[expected] = _Waiting(now_ns, (item, what))
        while len(self._frames) > self.capacity:
            _, waiting = self._frames.popitem(last=False)
            self.refuse("frame_mac_missing", f"{waiting.item[1]}: no tag came while {self.capacity} newer frames "
                                              "waited (forged, altered or untagged)")
        return []

    def tag(self, mac: Any, now_ns: int, expire: bool = True) -> list[Any]:
        """A tag arrived on a companion topic. It is matched before the frames waiting expire: a tag that came
        after the wait (a node too busy to read it in time) still verifies its frame. ``expire`` false: nothing
        expires (a receiver taking a batch of queued tags expires once, after the batch)."""
        mac = bytes(mac)
        if len(mac) != TAG_BYTES:
            if expire:
                self.expire(now_ns)
            self.refuse("tag_malformed", f"a tag of {len(mac)} bytes (want {TAG_BYTES})")
            return []
        for expected, waiting in self._frames.items():
            if hmac.compare_digest(expected, mac):
                del self._frames[expected]
                if expire:
                    self.expire(now_ns)
                return [self._use(expected, waiting.item[0])]
        if expire:
            self.expire(now_ns)
        if mac not in self._used:
            self._tags[mac] = _Waiting(now_ns)
            while len(self._tags) > self.capacity:
                self._tags.popitem(last=False)
                self.refuse("tag_unmatched", f"no frame claimed a tag while {self.capacity} newer tags waited")
        return []

    def expire(self, now_ns: int) -> None:
        """Refuse the frames (and drop the tags) that waited longer than ``wait_s``."""
        limit = now_ns - round(self.wait_s * 1e9)
        while self._frames:
            expected, waiting = next(iter(self._frames.items()))
            if waiting.since_ns > limit:
                break
            del self._frames[expected]
            self.refuse("frame_mac_missing", f"{waiting.item[1]}: no tag for this frame within {self.wait_s:g} s "
                                              "(forged, altered or untagged)")
        while self._tags:
            mac, waiting = next(iter(self._tags.items()))
            if waiting.since_ns > limit:
                break
            del self._tags[mac]
            self.refuse("tag_unmatched", f"no frame claimed a tag within {self.wait_s:g} s")

    def _use(self, expected: bytes, item: Any) -> Any:
        self._used[expected] = None
        while len(self._used) > REPLAY_MEMORY:
            self._used.popitem(last=False)
        self.counts["frames_verified"] += 1
        return item

    def refuse(self, reason: str, text: str) -> None:
        self.counts[reason] += 1
        self.last_refusal = f"{reason}: {text}"


__all__ = ["FRAMES", "TAG_SUFFIX", "REASONS", "WAIT_S", "CAPACITY", "FrameGate", "detection_array_bytes",
           "detection_rows_bytes", "world_state_bytes", "tag_frame"]
