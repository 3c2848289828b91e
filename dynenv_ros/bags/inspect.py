"""``dynenv-bag``: look into rosbag2 bags of the simulator without ROS (rosbags only).

Subcommands:
  info BAG [--json]                                   topics, types, counts, start/end, duration, rate per topic
  echo BAG --topic T [--limit N] [--format yaml|json] decoded messages as plain dicts
  render BAG --out game.gif [--robot NAME] [--fps F] [--pixels-per-metre P] [--stride K]
                                                      /world_state replayed top-down (soccer or driving),
                                                      optionally with one robot's (car's) detections overlaid
  export BAG --out DIR [--format csv|npz]             one table per kind: world_state, detections, feedback, actions
  reindex BAG                                         make an unfinished (killed, disk full) bag readable again

Messages are decoded with the definitions embedded in the bag (so an old bag still decodes after a .msg changed),
falling back to ``dynenv_typestore()`` for topics without them; a topic whose type cannot be decoded that way is
skipped with a notice on stderr (``info`` still counts it). A missing or unreadable bag is reported in one line
with exit status 2, never a traceback.

Before reading, the bag's MCAP file is checked record by record (``dynenv_ros.bags.mcap.scan``: lengths, chunk
CRCs, record framing, the index against the data). A damaged or unfinished bag is refused (exit 2) with what is
wrong and how many messages are affected; with ``--ignore-damage`` the commands read the messages that check out
(from a repaired copy in a temporary directory; the bag is not changed), after a notice naming what is skipped.
``reindex`` repairs the bag itself (``dynenv_ros.bags.recovery``).
"""
from __future__ import annotations

import argparse
import csv
import tempfile
import json
import math
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from dynenv_ros.bags.messages import detection_rows, json_safe, snapshot_from_msg, stamp_ns, to_plain
from dynenv_ros.bags.recovery import RecoveryError, bag_mcap, check, reindex, repaired_copy
from dynenv_ros.bags.typestore import dynenv_typestore

WORLD_STATE_TYPE = "dynenv_msgs/msg/WorldState"
DETECTION_ARRAY_TYPE = "dynenv_msgs/msg/DetectionArray"
STEP_FEEDBACK_TYPE = "dynenv_msgs/msg/StepFeedback"
ACTION_TYPE = "dynenv_msgs/msg/Action"
EXIT_BAG_ERROR = 2

# render's limits. Frames are kept in memory until the GIF is written (RGB, 3 bytes a pixel), so the image and the
# whole replay are bounded, not only the scale: 400 px/m is ~8x the default's detail; 4096 px a side is what GIF
# viewers handle comfortably (the default field at 400 px/m is 4160 px wide, so this limit binds first); 1 GiB of
# frames is ~250 s of a 10 Hz game at the default 40 px/m (longer bags: --stride). GIF delays are whole
# centiseconds (fps 100 is the fastest a GIF can say; most viewers slow down anything above 50) and at most
# 655.35 s (fps 0.01 would already be 100 s a frame; 0.1 is the slowest allowed).
RENDER_PPM_RANGE = (1.0, 400.0)
RENDER_FPS_RANGE = (0.1, 100.0)
RENDER_MAX_SIDE_PX = 4096
RENDER_MAX_FRAME_BYTES = 1 << 30


class BagError(Exception):
    """A bag (or a request about it) that cannot be served; the CLI prints it in one line and exits 2."""


def resolve_bag_path(path: str | os.PathLike[str]) -> Path:
    """The bag directory; a path to the .mcap inside it is accepted too (people tab-complete to the file). A
    directory with one .mcap file and no metadata.yaml is an unfinished recording: accepted here, refused or
    repaired by ``open_bag``."""
    bag = Path(path)
    if not bag.exists():
        raise BagError(f"no bag at {str(bag)!r}")
    if bag.is_file() and bag.suffix == ".mcap":
        return bag.parent
    if bag.is_file() and (bag.parent / "metadata.yaml").is_file():
        return bag.parent
    if not (bag / "metadata.yaml").is_file() and not (bag.is_dir() and len(list(bag.glob("*.mcap"))) == 1):
        raise BagError(f"{str(bag)!r} is not a rosbag2 bag (no metadata.yaml)")
    return bag


def _print_notice(text: str) -> None:
    print(f"dynenv-bag: notice: {text}", file=sys.stderr, flush=True)


class BagReader:
    """A rosbags reader whose failures (corrupt MCAP, bad metadata.yaml, a chunk that does not decode) surface as
    BagError, while errors of the caller's own code pass through unchanged.

    Types are resolved per topic, not for the whole bag (rosbags' AnyReader refuses a bag if one definition does
    not parse or match its hash): ``connections`` are the topics that decode, ``unreadable`` maps the others'
    topics to why, and a notice names each when the bag is opened.
    """

    def __init__(self, reader: Any, path: Path, notice: Callable[[str], None] = _print_notice) -> None:
        from rosbags.typesys import Stores, get_typestore

        self._reader = reader
        self.path = path
        self.typestore = get_typestore(Stores.EMPTY)
        self.all_connections: list[Any] = list(reader.connections)
        self.unreadable: dict[str, str] = {}
        self.connections: list[Any] = []
        decided: dict[tuple[str, str, str], str] = {}   # (type, definition, hash) → why not ("" = fine)
        for connection in self.all_connections:
            key = (connection.msgtype, connection.msgdef.data, connection.digest)
            why = decided[key] if key in decided else decided.setdefault(key, self._register(connection))
            if why:
                if connection.topic not in self.unreadable:
                    notice(f"skipping {connection.topic}: {why}")
                self.unreadable[connection.topic] = why
            else:
                self.connections.append(connection)

    def _register(self, connection: Any) -> str:
        """Add the topic's type to the typestore; returns why it cannot be decoded, or ""."""
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        msgtype, fmt, text = connection.msgtype, connection.msgdef.format, connection.msgdef.data
        try:
            if fmt == MessageDefinitionFormat.NONE or not text:
                installed = dynenv_typestore()
                if msgtype not in installed.types:
                    return f"its type {msgtype} is unknown (the bag has no definition of it and it is not installed)"
                if connection.digest.startswith("RIHS01_") and connection.digest != installed.hash_rihs01(msgtype):
                    return f"the bag has no definition of {msgtype} and the installed one differs from its hash"
                text, _ = installed.generate_msgdef(msgtype, ros_version=2)
                fmt = MessageDefinitionFormat.MSG
            if fmt == MessageDefinitionFormat.MSG:
                types = get_types_from_msg(text, msgtype)
            else:
                separator = "=" * 80 + "\n"
                types = {}
                for part in (text.split(separator)[1:] if text.startswith(separator + "IDL: ") else [text]):
                    types.update(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
            self.typestore.register(types)
            if connection.digest.startswith("RIHS01_") and self.typestore.hash_rihs01(msgtype) != connection.digest:
                return f"the bag's definition of {msgtype} does not match its type hash"
        except Exception as error:   # a stranger's definition: any parse or registration failure skips the topic
            return f"its definition of {msgtype} cannot be used ({type(error).__name__}: {error})"
        return ""

    @property
    def storage(self) -> str:
        """The storage plugin metadata.yaml names (mcap or sqlite3)."""
        import yaml

        try:
            meta = yaml.safe_load((self.path / "metadata.yaml").read_text())
            return str(meta["rosbag2_bagfile_information"]["storage_identifier"])
        except (OSError, yaml.YAMLError, KeyError, TypeError):
            return ""

    def _failed(self, error: Exception) -> BagError:
        return BagError(f"cannot read bag {str(self.path)!r}: {type(error).__name__}: {error}")

    def messages(self, connections: Sequence[Any] = (), *, include_unreadable: bool = False
                 ) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, bag time ns, raw CDR) in time order; ``connections`` filters (empty: every decodable topic,
        or with ``include_unreadable`` every topic)."""
        wanted = list(connections) or (self.all_connections if include_unreadable else self.connections)
        if not wanted:
            return
        iterator = self._reader.messages(connections=wanted)
        while True:
            try:
                item = next(iterator)
            except StopIteration:
                return
            except Exception as error:
                raise self._failed(error) from error
            yield item

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        try:
            return self.typestore.deserialize_cdr(raw, msgtype)
        except Exception as error:
            raise self._failed(error) from error


def damage_report(path: str | os.PathLike[str]) -> tuple[Path, Any]:
    """(bag directory, scan of its MCAP file or None when the bag is not a checkable MCAP bag)."""
    bag = resolve_bag_path(path)
    try:
        mcap = bag_mcap(bag)
        return bag, (check(mcap) if mcap is not None and mcap.is_file() else None)
    except RecoveryError as error:
        raise BagError(str(error)) from None


@contextmanager
def open_bag(path: str | os.PathLike[str], *, ignore_damage: bool = False,
             notice: Callable[[str], None] = _print_notice) -> Iterator[BagReader]:
    """Open a bag for reading with the definitions it embeds, after checking its MCAP file: damage or an
    unfinished recording is a BagError naming what is wrong, unless ``ignore_damage`` (then ``notice`` says what
    is skipped and the messages that check out are read from a repaired temporary copy)."""
    from rosbags.rosbag2 import Reader

    bag, result = damage_report(path)
    with ExitStack() as stack:
        source = bag
        finished = (bag / "metadata.yaml").is_file()
        for note in result.notes() if result is not None else []:
            notice(f"{bag}: {note}")
        if result is not None and not (result.healthy and finished):
            problems = result.problems() or ["no metadata.yaml"]
            what = "; ".join(problems)
            if not ignore_damage:
                if not result.lost and not result.summary_problem:
                    raise BagError(f"bag {str(bag)!r} was not finished (recorder killed, disk full?): {what}; "
                                   f"`dynenv-bag reindex {bag}` recovers its {result.message_count} messages in "
                                   "complete chunks (or pass --ignore-damage to read them without changing it)")
                raise BagError(f"bag {str(bag)!r} is damaged: {what}; {result.message_count} messages check out: "
                               "pass --ignore-damage to read them")
            notice(f"{bag}: {what}; reading the {result.message_count} messages that check out")
            tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="dynenv-bag-")))
            try:
                source = repaired_copy(result, tmp / bag.name)
            except OSError as error:
                raise BagError(f"cannot make a repaired copy of {str(bag)!r} in {tmp}: {error}") from None
        try:
            reader = Reader(source)
            reader.open()
        except Exception as error:   # bad metadata.yaml, unsupported storage, ...: one message, no traceback
            raise BagError(f"cannot read bag {str(bag)!r}: {error}") from error
        stack.callback(_close_quietly, reader)
        yield BagReader(reader, bag, notice)


def _close_quietly(reader: Any) -> None:
    try:
        reader.close()
    except Exception:
        pass


# ---------------------------------------------------------------------------------------------------------------- info
def _utc(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).isoformat(timespec="milliseconds")


def _seconds(ns: int) -> str:
    """Exact seconds.nanoseconds (a float would round epoch times to about 100 ns)."""
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def bag_info(path: str | os.PathLike[str], *, ignore_damage: bool = False,
             notice: Callable[[str], None] = _print_notice) -> dict[str, Any]:
    """Summary of a bag; reads every message (without decoding) so that counts and times are what is really
    there, and a damaged file is found now rather than half way through a replay. Topics whose type cannot be
    decoded are listed and counted too, with ``unreadable`` saying why."""
    with open_bag(path, ignore_damage=ignore_damage, notice=notice) as reader:
        topics: dict[str, dict[str, Any]] = {}
        for connection in reader.all_connections:
            topics.setdefault(connection.topic, {"name": connection.topic, "type": connection.msgtype, "count": 0,
                                                 "first_ns": None, "last_ns": None})
            if connection.topic in reader.unreadable:
                topics[connection.topic]["unreadable"] = reader.unreadable[connection.topic]
        for connection, timestamp, _ in reader.messages(include_unreadable=True):
            entry = topics[connection.topic]
            entry["count"] += 1
            entry["first_ns"] = timestamp if entry["first_ns"] is None else min(entry["first_ns"], timestamp)
            entry["last_ns"] = timestamp if entry["last_ns"] is None else max(entry["last_ns"], timestamp)
        storage = reader.storage
    for entry in topics.values():
        span = (entry["last_ns"] - entry["first_ns"]) if entry["count"] > 1 else 0
        # Mean rate between the first and the last message: n messages span n - 1 intervals.
        entry["rate_hz"] = (entry["count"] - 1) / (span / 1e9) if span > 0 else None
    firsts = [t["first_ns"] for t in topics.values() if t["first_ns"] is not None]
    lasts = [t["last_ns"] for t in topics.values() if t["last_ns"] is not None]
    start, end = (min(firsts), max(lasts)) if firsts else (None, None)
    return {"path": str(resolve_bag_path(path)), "storage": storage,
            "message_count": sum(t["count"] for t in topics.values()),
            "start_ns": start, "end_ns": end, "duration_s": (end - start) / 1e9 if firsts else 0.0,
            "topics": sorted(topics.values(), key=lambda t: t["name"])}


def format_info(info: dict[str, Any]) -> str:
    lines = [f"Bag:       {info['path']}", f"Storage:   {info['storage']}",
             f"Duration:  {info['duration_s']:.3f} s"]
    if info["start_ns"] is not None:
        lines += [f"Start:     {_utc(info['start_ns'])} ({_seconds(info['start_ns'])})",
                  f"End:       {_utc(info['end_ns'])} ({_seconds(info['end_ns'])})"]
    lines += [f"Messages:  {info['message_count']}", f"Topics:    {len(info['topics'])}"]
    width = max((len(t["name"]) for t in info["topics"]), default=0)
    type_width = max((len(t["type"]) for t in info["topics"]), default=0)
    for t in info["topics"]:
        rate = f"{t['rate_hz']:.2f} Hz" if t["rate_hz"] is not None else "-"
        unreadable = "  (cannot be decoded)" if "unreadable" in t else ""
        lines.append(f"  {t['name']:<{width}}  {t['type']:<{type_width}}  {t['count']:>8} msgs  {rate:>12}"
                     f"{unreadable}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------------- echo
def _check_topic(reader: Any, topic: str) -> list[Any]:
    if topic in reader.unreadable:
        raise BagError(f"topic {topic!r} cannot be decoded: {reader.unreadable[topic]}")
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        known = ", ".join(sorted({c.topic for c in reader.all_connections})) or "none"
        raise BagError(f"topic {topic!r} is not in the bag (topics: {known})")
    return connections


def echo(path: str | os.PathLike[str], topic: str, limit: int | None = None, *, ignore_damage: bool = False,
         notice: Callable[[str], None] = _print_notice) -> Iterator[dict[str, Any]]:
    """Decoded messages of one topic in bag order: {"topic", "type", "timestamp_ns", "message": plain dict}."""
    if limit is not None and limit < 0:
        raise BagError(f"--limit must be >= 0, got {limit}")
    with open_bag(path, ignore_damage=ignore_damage, notice=notice) as reader:
        connections = _check_topic(reader, topic)
        if limit == 0:
            return
        count = 0
        for connection, timestamp, raw in reader.messages(connections=connections):
            message = reader.deserialize(raw, connection.msgtype)
            yield {"topic": connection.topic, "type": connection.msgtype, "timestamp_ns": timestamp,
                   "message": to_plain(message)}
            count += 1
            if limit is not None and count >= limit:
                return


def format_record(record: dict[str, Any], fmt: str) -> str:
    """YAML documents separated by '---' (like ``ros2 topic echo``; NaN stays .nan), or JSON Lines (NaN → null)."""
    if fmt == "json":
        return json.dumps(json_safe(record), allow_nan=False)
    import yaml

    return "---\n" + yaml.safe_dump(record, sort_keys=False, default_flow_style=False).rstrip("\n")


# -------------------------------------------------------------------------------------------------------------- render
def _connections_of_type(reader: Any, msgtype: str) -> list[Any]:
    return [c for c in reader.connections if c.msgtype == msgtype]


def _world_code(reader: Any, worlds: list[Any]) -> int | None:
    """The first WorldState's ``scenario`` code (None if there is none)."""
    for connection, _, raw in reader.messages(connections=worlds):
        return int(reader.deserialize(raw, connection.msgtype).scenario)
    return None


def render(path: str | os.PathLike[str], out: str | os.PathLike[str], *, robot: str | None = None,
           fps: float = 10.0, pixels_per_metre: float | None = None, stride: int = 1, ignore_damage: bool = False,
           notice: Callable[[str], None] = _print_notice) -> int:
    """Replay the bag's WorldState messages as a top-down GIF; with ``robot`` (a namespace such as "team_a_0" or
    "car_0"), overlay the detections that robot reported at the same sim time. Returns the number of frames.

    The world is the first WorldState's, drawn by its replay (``render.replay``): soccer on the default
    FieldGeometry, driving with ``render/driving.py`` on the default driving map (a bag carries neither).
    ``pixels_per_metre`` defaults to the replay's, 40 (soccer) or 4 (driving). Frames are kept in memory until the GIF is written; ``stride`` renders every k-th
    world state for long bags. The options are bounded (RENDER_* above): the scale, the image's sides and the
    memory all frames take, checked before anything is drawn.
    """
    if stride < 1:
        raise BagError(f"--stride must be >= 1, got {stride}")
    if not (math.isfinite(fps) and RENDER_FPS_RANGE[0] <= fps <= RENDER_FPS_RANGE[1]):
        raise BagError(f"--fps must be between {RENDER_FPS_RANGE[0]:g} and {RENDER_FPS_RANGE[1]:g} (GIF frame "
                       f"delays are whole centiseconds), got {fps:g}")
    low, high = RENDER_PPM_RANGE
    if pixels_per_metre is not None and not (math.isfinite(pixels_per_metre) and low <= pixels_per_metre <= high):
        raise BagError(f"--pixels-per-metre must be between {low:g} and {high:g}, got {pixels_per_metre:g}")
    with open_bag(path, ignore_damage=ignore_damage, notice=notice) as reader:
        worlds = _connections_of_type(reader, WORLD_STATE_TYPE)
        if not worlds:
            raise BagError(f"the bag has no {WORLD_STATE_TYPE} messages to render")
        from dynenv_ros.render.replay import replay_of
        world = replay_of(_world_code(reader, worlds))
        ppm = world.default_pixels_per_metre if pixels_per_metre is None else pixels_per_metre
        replay = world(ppm)
        width, height = replay.view.size
        if max(width, height) > RENDER_MAX_SIDE_PX:
            raise BagError(f"--pixels-per-metre {ppm:g} makes {width}x{height} px frames; at most "
                           f"{RENDER_MAX_SIDE_PX} px a side (lower --pixels-per-metre)")
        frames = -(-sum(c.msgcount for c in worlds) // stride)
        if frames * width * height * 3 > RENDER_MAX_FRAME_BYTES:
            raise BagError(f"{frames} frames of {width}x{height} px would take "
                           f"{frames * width * height * 3 / 2**30:.1f} GiB of memory (at most "
                           f"{RENDER_MAX_FRAME_BYTES / 2**30:g} GiB): raise --stride or lower --pixels-per-metre")
        wanted = list(worlds)
        if robot is not None:
            topic = f"/{robot.strip('/')}/detections"
            detection_connections = [c for c in _check_topic(reader, topic) if c.msgtype == DETECTION_ARRAY_TYPE]
            if not detection_connections:
                raise BagError(f"topic {topic!r} is not a {DETECTION_ARRAY_TYPE}")
            wanted += detection_connections
        # Detections and world states of one instant share the header stamp but may arrive in either order.
        pending_detections: dict[int, Any] = {}
        world_states: list[tuple[int, Any]] = []
        seen = 0
        for connection, _, raw in reader.messages(connections=wanted):
            message = reader.deserialize(raw, connection.msgtype)
            if connection.msgtype == DETECTION_ARRAY_TYPE:
                pending_detections[stamp_ns(message.header.stamp)] = message
                continue
            if seen % stride == 0:
                world_states.append((stamp_ns(message.header.stamp), snapshot_from_msg(message)))
            seen += 1
    for stamp, snapshot in world_states:
        frame = replay.draw(snapshot)
        detections = pending_detections.get(stamp)
        if robot is not None and detections is not None:
            observer = next((o for o in snapshot.objects if o.id == detections.robot_id
                             and o.class_id == replay.observer_class), None)
            if observer is not None:
                team = -1 if observer.team == -1 else 1
                replay.overlay(frame, observer, detections, detection_rows(detections.detections), team)
        replay.keep(frame)
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    replay.save_gif(target, fps=fps)
    return len(replay)


# -------------------------------------------------------------------------------------------------------------- export
@dataclass(frozen=True)
class Column:
    name: str
    dtype: str                     # numpy dtype of the .npz column
    get: Callable[..., Any]
    optional: bool = False         # a field bags recorded with an older definition lack: the getter gives None there


def _field(name: str) -> Callable[..., Any]:
    """Getter of a message field that older definitions lack (None there)."""
    return lambda t, b, m, i: getattr(m, name, None)


def _robot_of(topic: str) -> str:
    """'/team_a_0/detections' → 'team_a_0' (the namespace is the robot's name)."""
    parts = topic.strip("/").split("/")
    return parts[-2] if len(parts) >= 2 else ""


# Each table: the message type it comes from, its columns, and how one message becomes rows.
# Row getters receive (topic, bag_time_ns, message, item) where item is the per-row element (object, detection)
# or the message itself for one-row-per-message tables.
_COMMON = [Column("bag_time_ns", "i8", lambda t, b, m, i: b),
           Column("stamp_ns", "i8", lambda t, b, m, i: stamp_ns(m.header.stamp))]
_PER_ROBOT = [Column("robot", "U", lambda t, b, m, i: _robot_of(t)),
              Column("robot_id", "u2", lambda t, b, m, i: m.robot_id),
              Column("episode_id", "u4", lambda t, b, m, i: m.episode_id),
              Column("motion_period", "u4", lambda t, b, m, i: m.motion_period)]

TABLES: dict[str, tuple[str, list[Column], Callable[[Any], Sequence[Any]]]] = {
    "world_state": (WORLD_STATE_TYPE, _COMMON + [
        Column("episode_id", "u4", lambda t, b, m, i: m.episode_id),
        Column("tick", "u8", lambda t, b, m, i: m.tick),
        Column("game_time", "f8", lambda t, b, m, i: m.game_time),
        Column("time_remaining", "f8", lambda t, b, m, i: m.time_remaining),
        Column("phase", "u1", lambda t, b, m, i: m.phase),
        Column("score_team_a", "u2", lambda t, b, m, i: m.score_team_a),
        Column("score_team_b", "u2", lambda t, b, m, i: m.score_team_b),
        Column("ball_owner_team", "i1", lambda t, b, m, i: m.ball_owner_team),
        Column("id", "u4", lambda t, b, m, i: i.id),
        Column("class_id", "u1", lambda t, b, m, i: i.class_id),
        Column("team", "i1", lambda t, b, m, i: i.team),
    ] + [Column(f, "f8", (lambda f: lambda t, b, m, i: getattr(i, f))(f))
         for f in ("x", "y", "yaw", "vx", "vy", "yaw_rate", "head_yaw")]
      + [Column(f, "f4", (lambda f: lambda t, b, m, i: getattr(i, f))(f)) for f in ("size_x", "size_y")]
      + [Column("status", "u1", lambda t, b, m, i: i.status),
         Column("penalty_remaining", "f4", lambda t, b, m, i: i.penalty_remaining),
         Column("goal_x", "f8", lambda t, b, m, i: i.goal_x),
         Column("goal_y", "f8", lambda t, b, m, i: i.goal_y)],
        lambda m: m.objects),
    "detections": (DETECTION_ARRAY_TYPE, _COMMON + _PER_ROBOT + [
        Column("frame_index", "u1", lambda t, b, m, i: m.frame_index),
        Column("head_yaw", "f4", lambda t, b, m, i: m.head_yaw),
        Column("self_fallen", "?", lambda t, b, m, i: m.self_fallen),
        Column("self_penalized", "?", lambda t, b, m, i: m.self_penalized),
        Column("self_kicking", "?", _field("self_kicking"), optional=True),
        Column("ball_owner", "i1", _field("ball_owner"), optional=True),
        Column("ball_owner_seconds", "f4", _field("ball_owner_seconds"), optional=True),
        Column("game_seconds_remaining", "f4", _field("game_seconds_remaining"), optional=True),
        Column("class_id", "u1", lambda t, b, m, i: i.class_id),
        Column("x", "f8", lambda t, b, m, i: i.position.x),
        Column("y", "f8", lambda t, b, m, i: i.position.y),
        Column("yaw", "f4", lambda t, b, m, i: i.yaw),
        Column("size_x", "f4", lambda t, b, m, i: i.size_x),
        Column("size_y", "f4", lambda t, b, m, i: i.size_y),
        Column("confidence", "f4", lambda t, b, m, i: i.confidence),
        Column("team", "i1", lambda t, b, m, i: i.team),
        Column("subtype", "u1", lambda t, b, m, i: i.subtype),
        Column("fallen", "?", lambda t, b, m, i: i.fallen),
        Column("penalized", "?", lambda t, b, m, i: i.penalized),
        Column("line_start_x", "f8", lambda t, b, m, i: i.line_start.x),
        Column("line_start_y", "f8", lambda t, b, m, i: i.line_start.y),
        Column("line_end_x", "f8", lambda t, b, m, i: i.line_end.x),
        Column("line_end_y", "f8", lambda t, b, m, i: i.line_end.y),
        Column("sighting", "u1", lambda t, b, m, i: i.sighting),
    ], lambda m: m.detections),
    "feedback": (STEP_FEEDBACK_TYPE, _COMMON + _PER_ROBOT + [
        Column(f, "f4", (lambda f: lambda t, b, m, i: getattr(m, f))(f))
        for f in ("reward_primary", "reward_rule", "reward_auxiliary", "reward_observation", "reward_total")
    ] + [Column("terminated", "?", lambda t, b, m, i: m.terminated),
         Column("truncated", "?", lambda t, b, m, i: m.truncated),
         Column("landmarks_seen", "f4", lambda t, b, m, i: m.landmarks_seen),
         Column("seen_object_ids", "U", lambda t, b, m, i: " ".join(str(int(v)) for v in m.seen_object_ids))],
        lambda m: (m,)),
    "actions": (ACTION_TYPE, _COMMON + _PER_ROBOT + [
        Column(f, "u1", (lambda f: lambda t, b, m, i: getattr(m, f))(f)) for f in ("walk", "turn", "kick")
    ] + [Column(f, "f4", (lambda f: lambda t, b, m, i: getattr(m, f))(f))
         for f in ("head_yaw_delta", "throttle", "brake", "steering")],
        lambda m: (m,)),
}


def _cell(column: Column, topic: str, timestamp: int, message: Any, item: Any) -> Any:
    """A column's value, None when the bag's definition of the type lacks the field (the column is then left out)."""
    try:
        return column.get(topic, timestamp, message, item)
    except AttributeError:
        return None


def export(path: str | os.PathLike[str], out_dir: str | os.PathLike[str], fmt: str = "csv", *,
           ignore_damage: bool = False, notice: Callable[[str], None] = _print_notice) -> dict[str, int]:
    """Write one table per message kind found in the bag (``<kind>.csv`` or ``<kind>.npz`` with one array per
    column) and return {file name: rows}. Other types (clock, diagnostics, markers) are not exported, nor topics
    whose type cannot be decoded (skipped with a notice).

    A DetectionArray with no detections gives no row; feedback's ``seen_object_ids`` is a space-separated string.
    Columns of fields that a bag's (older or foreign) message definitions lack are left out of that table, never
    invented.
    """
    if fmt not in ("csv", "npz"):
        raise BagError(f"--format must be csv or npz, got {fmt!r}")
    by_type = {msgtype: kind for kind, (msgtype, _, _) in TABLES.items()}
    rows: dict[str, dict[str, list[Any]]] = {}
    skipped: set[str] = set()
    with open_bag(path, ignore_damage=ignore_damage, notice=notice) as reader:
        wanted = [c for c in reader.connections if c.msgtype in by_type]
        for connection, timestamp, raw in reader.messages(connections=wanted):
            kind = by_type[connection.msgtype]
            _, columns, items = TABLES[kind]
            table = rows.setdefault(kind, {c.name: [] for c in columns})
            message = reader.deserialize(raw, connection.msgtype)
            try:
                rows_of = items(message)
            except AttributeError as error:   # a foreign definition under our type's name
                if connection.topic not in skipped:
                    skipped.add(connection.topic)
                    notice(f"skipping {connection.topic} in export: its definition of {connection.msgtype} "
                           f"lacks a field the table needs ({error})")
                continue
            for item in rows_of:
                for column in columns:
                    table[column.name].append(_cell(column, connection.topic, timestamp, message, item))
        for connection in wanted:   # a topic with no rows still gets its (empty) table
            kind = by_type[connection.msgtype]
            rows.setdefault(kind, {c.name: [] for c in TABLES[kind][1]})
    target = Path(out_dir)
    target.mkdir(parents=True, exist_ok=True)
    written: dict[str, int] = {}
    for kind, table in rows.items():
        columns = [c for c in TABLES[kind][1] if not any(v is None for v in table[c.name])]
        count = len(table[columns[0].name])
        name = f"{kind}.{fmt}"
        tmp = target / (name + ".tmp")
        if fmt == "csv":
            with open(tmp, "w", newline="") as stream:
                writer = csv.writer(stream)
                writer.writerow([c.name for c in columns])
                # float32 fields in their shortest form (0.2, not 0.20000000298023224)
                cells = [[str(np.float32(v)) for v in table[c.name]] if c.dtype == "f4" else table[c.name]
                         for c in columns]
                writer.writerows(zip(*cells))
        else:
            arrays = {c.name: np.asarray(table[c.name], dtype=c.dtype if c.dtype != "U" else str)
                      for c in columns}
            with open(tmp, "wb") as stream:
                np.savez_compressed(stream, **arrays)
        os.replace(tmp, target / name)   # a crash never leaves a half-written table under the final name
        written[name] = count
    return written


# ----------------------------------------------------------------------------------------------------------------- CLI
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dynenv-bag", description="Inspect rosbag2 bags of the simulator "
                                     "(no ROS needed).")
    sub = parser.add_subparsers(dest="command", required=True)
    damage_help = ("read a damaged or unfinished bag anyway: the messages that check out, after a notice naming what "
                   "is skipped (default: refuse with exit status 2)")
    p = sub.add_parser("info", help="topics, types, counts, duration and rates")
    p.add_argument("bag")
    p.add_argument("--ignore-damage", action="store_true", help=damage_help)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p = sub.add_parser("echo", help="decoded messages of one topic")
    p.add_argument("bag")
    p.add_argument("--topic", required=True)
    p.add_argument("--ignore-damage", action="store_true", help=damage_help)
    p.add_argument("--limit", type=int, default=None, help="at most this many messages")
    p.add_argument("--format", choices=("yaml", "json"), default="yaml",
                   help="yaml documents, or JSON Lines (NaN written as null)")
    p = sub.add_parser("render", help="top-down GIF of /world_state (soccer or driving), optionally with one "
                       "robot's (car's) detections")
    p.add_argument("bag")
    p.add_argument("--out", required=True, help="GIF file to write")
    p.add_argument("--robot", default=None, help="overlay this robot's detections (e.g. team_a_0, car_0)")
    p.add_argument("--fps", type=float, default=10.0,
                   help=f"frames per second, {RENDER_FPS_RANGE[0]:g} to {RENDER_FPS_RANGE[1]:g}")
    p.add_argument("--pixels-per-metre", type=float, default=None,
                   help=f"scale, {RENDER_PPM_RANGE[0]:g} to {RENDER_PPM_RANGE[1]:g} (default 40 for soccer, 4 for "
                        f"driving), frames at most "
                        f"{RENDER_MAX_SIDE_PX} px a side and {RENDER_MAX_FRAME_BYTES >> 30} GiB in all")
    p.add_argument("--stride", type=int, default=1, help="render every k-th world state")
    p.add_argument("--ignore-damage", action="store_true", help=damage_help)
    p = sub.add_parser("export", help="tables of world state, detections, feedback and actions")
    p.add_argument("bag")
    p.add_argument("--out", required=True, help="directory for the tables")
    p.add_argument("--format", choices=("csv", "npz"), default="csv")
    p.add_argument("--ignore-damage", action="store_true", help=damage_help)
    p = sub.add_parser("reindex", help="make an unfinished (killed, disk full) or damaged bag readable again: "
                       "index its complete chunks and rewrite metadata.yaml")
    p.add_argument("bag")
    p.add_argument("--ignore-damage", action="store_true",
                   help="also index a bag with damaged chunks in the middle, leaving them out (default: refuse)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        damage = {"ignore_damage": args.ignore_damage}
        if args.command == "info":
            info = bag_info(args.bag, **damage)
            print(json.dumps(json_safe(info), indent=1) if args.json else format_info(info))
        elif args.command == "echo":
            for record in echo(args.bag, args.topic, args.limit, **damage):
                print(format_record(record, args.format), flush=False)
        elif args.command == "render":
            frames = render(args.bag, args.out, robot=args.robot, fps=args.fps,
                            pixels_per_metre=args.pixels_per_metre, stride=args.stride, **damage)
            print(f"wrote {args.out}: {frames} frames")
        elif args.command == "reindex":
            try:
                print(reindex(resolve_bag_path(args.bag), **damage).describe())
            except RecoveryError as error:
                raise BagError(str(error)) from None
        else:
            for name, count in export(args.bag, args.out, args.format, **damage).items():
                print(f"wrote {os.path.join(args.out, name)}: {count} rows")
    except BrokenPipeError:   # `dynenv-bag echo ... | head`: stop quietly, and keep Python's exit flush quiet too
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (BagError, OSError, ValueError) as error:   # bad bag; output not writable; a value the renderer refused
        print(f"dynenv-bag: error: {error}", file=sys.stderr)
        return EXIT_BAG_ERROR
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
