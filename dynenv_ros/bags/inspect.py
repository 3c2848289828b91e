"""``dynenv-bag``: look into rosbag2 bags of the simulator without ROS (rosbags only).

Subcommands:
  info BAG [--json]                                   topics, types, counts, start/end, duration, rate per topic
  echo BAG --topic T [--limit N] [--format yaml|json] decoded messages as plain dicts
  render BAG --out game.gif [--robot NAME] [--fps F] [--pixels-per-metre P] [--stride K]
                                                      /world_state replayed top-down, optionally with one robot's
                                                      detections overlaid
  export BAG --out DIR [--format csv|npz]             one table per kind: world_state, detections, feedback, actions

Messages are decoded with the definitions embedded in the bag (so an old bag still decodes after a .msg changed),
falling back to ``dynenv_typestore()`` for bags without them. A missing, unreadable or truncated bag is reported in
one line with exit status 2, never a traceback.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from dynenv_ros.bags.messages import detection_rows, json_safe, snapshot_from_msg, stamp_ns, to_plain
from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.core.object_classes import ObjectClass

WORLD_STATE_TYPE = "dynenv_msgs/msg/WorldState"
DETECTION_ARRAY_TYPE = "dynenv_msgs/msg/DetectionArray"
STEP_FEEDBACK_TYPE = "dynenv_msgs/msg/StepFeedback"
ACTION_TYPE = "dynenv_msgs/msg/Action"
EXIT_BAG_ERROR = 2


class BagError(Exception):
    """A bag (or a request about it) that cannot be served; the CLI prints it in one line and exits 2."""


def resolve_bag_path(path: str | os.PathLike[str]) -> Path:
    """The bag directory; a path to the .mcap inside it is accepted too (people tab-complete to the file)."""
    bag = Path(path)
    if not bag.exists():
        raise BagError(f"no bag at {str(bag)!r}")
    if bag.is_file() and (bag.parent / "metadata.yaml").is_file():
        return bag.parent
    if not (bag / "metadata.yaml").is_file():
        raise BagError(f"{str(bag)!r} is not a rosbag2 bag (no metadata.yaml): was the recording finished?")
    return bag


class BagReader:
    """A rosbags AnyReader whose failures (corrupt MCAP, bad metadata.yaml, hash mismatch, a chunk that does not
    decode) surface as BagError, while errors of the caller's own code pass through unchanged."""

    def __init__(self, reader: Any, path: Path) -> None:
        self._reader = reader
        self.path = path
        self.connections: list[Any] = list(reader.connections)

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

    def messages(self, connections: Sequence[Any] = ()) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, bag time ns, raw CDR) in time order; ``connections`` filters (empty: all)."""
        iterator = self._reader.messages(connections=connections)
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
            return self._reader.deserialize(raw, msgtype)
        except Exception as error:
            raise self._failed(error) from error


@contextmanager
def open_bag(path: str | os.PathLike[str]) -> Iterator[BagReader]:
    """Open a bag for reading with the definitions it embeds (``dynenv_typestore()`` for bags without them)."""
    from rosbags.highlevel import AnyReader

    bag = resolve_bag_path(path)
    try:
        reader = AnyReader([bag], default_typestore=dynenv_typestore())
        reader.open()
    except Exception as error:   # truncated MCAP (no footer), bad metadata.yaml, ...: one message, no traceback
        raise BagError(f"cannot read bag {str(bag)!r}: {error}") from error
    try:
        yield BagReader(reader, bag)
    finally:
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


def bag_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Summary of a bag; reads every message (without decoding) so that counts and times are what is really
    there, and a damaged file is found now rather than half way through a replay."""
    with open_bag(path) as reader:
        topics: dict[str, dict[str, Any]] = {}
        for connection in reader.connections:
            topics.setdefault(connection.topic, {"name": connection.topic, "type": connection.msgtype, "count": 0,
                                                 "first_ns": None, "last_ns": None})
        for connection, timestamp, _ in reader.messages():
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
        lines.append(f"  {t['name']:<{width}}  {t['type']:<{type_width}}  {t['count']:>8} msgs  {rate:>12}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------------------- echo
def _check_topic(reader: Any, topic: str) -> list[Any]:
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        known = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
        raise BagError(f"topic {topic!r} is not in the bag (topics: {known})")
    return connections


def echo(path: str | os.PathLike[str], topic: str, limit: int | None = None) -> Iterator[dict[str, Any]]:
    """Decoded messages of one topic in bag order: {"topic", "type", "timestamp_ns", "message": plain dict}."""
    if limit is not None and limit < 0:
        raise BagError(f"--limit must be >= 0, got {limit}")
    with open_bag(path) as reader:
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


def render(path: str | os.PathLike[str], out: str | os.PathLike[str], *, robot: str | None = None,
           fps: float = 10.0, pixels_per_metre: float = 40.0, stride: int = 1) -> int:
    """Replay the bag's WorldState messages as a top-down GIF; with ``robot`` (a namespace such as "team_a_0"),
    overlay the detections that robot reported at the same sim time. Returns the number of frames rendered.

    Frames are kept in memory until the GIF is written; ``stride`` renders every k-th world state for long bags.
    The field geometry is the default FieldGeometry (a bag does not carry it).
    """
    from dynenv_ros.render.detections import field_view, overlay_detections
    from dynenv_ros.render.topdown import EpisodeRecorder
    from dynenv_ros.soccer.field import FieldGeometry

    if stride < 1:
        raise BagError(f"--stride must be >= 1, got {stride}")
    if not (math.isfinite(fps) and fps > 0):
        raise BagError(f"--fps must be a positive number, got {fps}")
    if not (math.isfinite(pixels_per_metre) and pixels_per_metre > 0):
        raise BagError(f"--pixels-per-metre must be a positive number, got {pixels_per_metre}")
    geometry = FieldGeometry()
    recorder = EpisodeRecorder(geometry, pixels_per_metre=pixels_per_metre)
    view = field_view(geometry, pixels_per_metre)
    with open_bag(path) as reader:
        worlds = _connections_of_type(reader, WORLD_STATE_TYPE)
        if not worlds:
            raise BagError(f"the bag has no {WORLD_STATE_TYPE} messages to render")
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
        balls = snapshot.of_class(ObjectClass.BALL)
        ball_radius = balls[0].size_x / 2 if balls and balls[0].size_x > 0 else 0.05
        recorder.ball_radius = ball_radius
        frame = recorder.add(snapshot)
        detections = pending_detections.get(stamp)
        if robot is not None and detections is not None:
            observer = next((o for o in snapshot.objects if o.id == detections.robot_id
                             and o.class_id == ObjectClass.ROBOT), None)
            if observer is not None:
                pose = (observer.x, observer.y, observer.yaw + float(detections.head_yaw))
                overlay_detections(frame, view, pose, detection_rows(detections.detections),
                                   observer_team=-1 if observer.team == -1 else 1)
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    recorder.save_gif(target, fps=fps)
    return len(recorder)


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


def export(path: str | os.PathLike[str], out_dir: str | os.PathLike[str], fmt: str = "csv") -> dict[str, int]:
    """Write one table per message kind found in the bag (``<kind>.csv`` or ``<kind>.npz`` with one array per
    column) and return {file name: rows}. Other types (clock, diagnostics, markers) are not exported.

    A DetectionArray with no detections gives no row; feedback's ``seen_object_ids`` is a space-separated string.
    Columns of fields that a bag's (older) message definitions lack are left out of that table, never invented.
    """
    if fmt not in ("csv", "npz"):
        raise BagError(f"--format must be csv or npz, got {fmt!r}")
    by_type = {msgtype: kind for kind, (msgtype, _, _) in TABLES.items()}
    rows: dict[str, dict[str, list[Any]]] = {}
    with open_bag(path) as reader:
        wanted = [c for c in reader.connections if c.msgtype in by_type]
        for connection, timestamp, raw in reader.messages(connections=wanted):
            kind = by_type[connection.msgtype]
            _, columns, items = TABLES[kind]
            table = rows.setdefault(kind, {c.name: [] for c in columns})
            message = reader.deserialize(raw, connection.msgtype)
            for item in items(message):
                for column in columns:
                    table[column.name].append(column.get(connection.topic, timestamp, message, item))
        for connection in wanted:   # a topic with no rows still gets its (empty) table
            kind = by_type[connection.msgtype]
            rows.setdefault(kind, {c.name: [] for c in TABLES[kind][1]})
    target = Path(out_dir)
    target.mkdir(parents=True, exist_ok=True)
    written: dict[str, int] = {}
    for kind, table in rows.items():
        columns = [c for c in TABLES[kind][1] if not (c.optional and any(v is None for v in table[c.name]))]
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
    p = sub.add_parser("info", help="topics, types, counts, duration and rates")
    p.add_argument("bag")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p = sub.add_parser("echo", help="decoded messages of one topic")
    p.add_argument("bag")
    p.add_argument("--topic", required=True)
    p.add_argument("--limit", type=int, default=None, help="at most this many messages")
    p.add_argument("--format", choices=("yaml", "json"), default="yaml",
                   help="yaml documents, or JSON Lines (NaN written as null)")
    p = sub.add_parser("render", help="top-down GIF of /world_state, optionally with one robot's detections")
    p.add_argument("bag")
    p.add_argument("--out", required=True, help="GIF file to write")
    p.add_argument("--robot", default=None, help="overlay this robot's detections (e.g. team_a_0)")
    p.add_argument("--fps", type=float, default=10.0)
    p.add_argument("--pixels-per-metre", type=float, default=40.0)
    p.add_argument("--stride", type=int, default=1, help="render every k-th world state")
    p = sub.add_parser("export", help="tables of world state, detections, feedback and actions")
    p.add_argument("bag")
    p.add_argument("--out", required=True, help="directory for the tables")
    p.add_argument("--format", choices=("csv", "npz"), default="csv")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "info":
            info = bag_info(args.bag)
            print(json.dumps(json_safe(info), indent=1) if args.json else format_info(info))
        elif args.command == "echo":
            for record in echo(args.bag, args.topic, args.limit):
                print(format_record(record, args.format), flush=False)
        elif args.command == "render":
            frames = render(args.bag, args.out, robot=args.robot, fps=args.fps,
                            pixels_per_metre=args.pixels_per_metre, stride=args.stride)
            print(f"wrote {args.out}: {frames} frames")
        else:
            for name, count in export(args.bag, args.out, args.format).items():
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
