"""Checking a bag's MCAP file, and rebuilding the index of one a crash or damage left unreadable (``dynenv-bag
reindex``), like ``ros2 bag reindex``: from whatever complete chunks the file holds, with a count of what was kept.

Only single-file, uncompressed-file MCAP bags are checked and repaired (what the recorder writes); other bags
(sqlite3, split or zstd-file-compressed) are handed to rosbags as they are. No ROS imports.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import yaml

from dynenv_ros.bags.mcap import (ChunkInfo, Damage, McapFormatError, McapScan, Schema, index_tail,
                                  message_index_records, scan)

METADATA = "metadata.yaml"


class RecoveryError(Exception):
    """A bag that cannot be checked or reindexed; the message says why in one line."""


def bag_mcap(bag: Path) -> Path | None:
    """The one MCAP file of a bag directory that this module can check, or None (not MCAP, several files,
    file-compressed). Without metadata.yaml (an unfinished recording) the directory's only .mcap file."""
    meta = bag / METADATA
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
            files = list(info["relative_file_paths"])
            storage, mode = info.get("storage_identifier"), (info.get("compression_mode") or "").lower()
        except (OSError, yaml.YAMLError, KeyError, TypeError) as error:
            raise RecoveryError(f"{meta}: unreadable ({type(error).__name__}: {error})") from None
        if storage != "mcap" or mode == "file" or len(files) != 1:
            return None
        return bag / Path(files[0]).name
    found = sorted(bag.glob("*.mcap"))
    return found[0] if len(found) == 1 else None


def check(mcap: Path) -> McapScan:
    """``mcap.scan`` with its failures as RecoveryError."""
    try:
        return scan(mcap)
    except (OSError, McapFormatError) as error:
        raise RecoveryError(f"cannot read {str(mcap)!r}: {error}") from None


def definition_hash(schema: Schema, msgtype: str) -> str:
    """RIHS01 hash of an embedded definition (bags of older writers do not store it with the channel), '' if the
    definition does not parse."""
    from rosbags.typesys import Stores, get_typestore, get_types_from_idl, get_types_from_msg

    try:
        text = schema.data.decode()
        store = get_typestore(Stores.EMPTY)
        if schema.encoding == "ros2msg":
            store.register(get_types_from_msg(text, msgtype))
        else:
            separator = "=" * 80 + "\n"
            for part in (text.split(separator)[1:] if text.startswith(separator + "IDL: ") else [text]):
                store.register(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
        return store.hash_rihs01(msgtype)
    except Exception:   # any defect of a stranger's definition: no hash, the readers then skip or fall back
        return ""


def metadata(result: McapScan, mcap_name: str) -> dict[str, Any]:
    """metadata.yaml (rosbag2 version 9) describing what ``result`` found."""
    counts = result.channel_counts()
    starts = [c.message_start for c in result.chunks if c.message_count]
    ends = [c.message_end for c in result.chunks if c.message_count]
    start, end = (min(starts), max(ends)) if starts else (0, 0)
    topics = []
    for channel_id, channel in sorted(result.channels.items()):
        schema = result.schemas.get(channel.schema_id)
        msgtype = schema.name if schema else ""
        try:
            qos = yaml.safe_load(channel.metadata.get("offered_qos_profiles", "")) or []
        except yaml.YAMLError:
            qos = []
        digest = channel.metadata.get("topic_type_hash") or (definition_hash(schema, msgtype) if schema else "")
        topics.append({"topic_metadata": {"name": channel.topic, "type": msgtype,
                                          "serialization_format": channel.message_encoding,
                                          "offered_qos_profiles": qos, "type_description_hash": digest},
                       "message_count": counts.get(channel_id, 0)})
    count = sum(counts.values())
    return {"rosbag2_bagfile_information": {
        "version": 9, "storage_identifier": "mcap", "relative_file_paths": [mcap_name],
        "duration": {"nanoseconds": end - start}, "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count, "topics_with_message_count": topics, "compression_format": "",
        "compression_mode": "", "files": [{"path": mcap_name, "starting_time": {"nanoseconds_since_epoch": start},
                                           "duration": {"nanoseconds": end - start}, "message_count": count}],
        "custom_data": None, "ros_distro": "rosbags"}}


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _tail_metadata(info: dict[str, Any]) -> dict[str, dict[str, str]]:
    """The MCAP Metadata record rosbag2 embeds: its metadata.yaml without the top-level key."""
    return {"rosbag2": {"serialized_metadata": yaml.safe_dump(info["rosbag2_bagfile_information"]).strip()}}


def _channels_and_schemas(result: McapScan) -> tuple[list[Schema], list[Any]]:
    return [result.schemas[k] for k in sorted(result.schemas)], [result.channels[k] for k in sorted(result.channels)]


def rewrite(result: McapScan, target: BinaryIO) -> list[ChunkInfo]:
    """Write a clean copy of ``result``'s file to ``target``: header, schemas, channels, every valid chunk (bytes
    as they are) with fresh MessageIndex records, and an index. Returns the chunks as written."""
    schemas, channels = _channels_and_schemas(result)
    info = metadata(result, result.path.name)
    with open(result.path, "rb") as source:
        position = target.write(source.read(result.header_end))
        for record in [s.to_record() for s in schemas] + [c.to_record() for c in channels]:
            position += target.write(record)
        written = []
        for chunk in result.chunks:
            source.seek(chunk.start)
            data = source.read(chunk.length)
            copy = ChunkInfo(position, chunk.length, chunk.message_start, chunk.message_end, chunk.compression,
                             chunk.compressed_size, chunk.uncompressed_size, chunk.index)
            indexes, copy.index_offsets = message_index_records(copy, position + len(data))
            copy.index_length = len(indexes)
            position += target.write(data + indexes)
            written.append(copy)
    target.write(index_tail(position, schemas, channels, written, _tail_metadata(info)))
    return written


def repaired_copy(result: McapScan, directory: Path) -> Path:
    """A readable bag in ``directory`` (created) holding the valid chunks of ``result``: how damaged bags are read
    with --ignore-damage without touching them."""
    directory.mkdir(parents=True)
    with open(directory / result.path.name, "wb") as target:
        rewrite(result, target)
    _write_atomically(directory / METADATA, yaml.safe_dump(metadata(result, result.path.name), sort_keys=False))
    return directory


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'s' * (n != 1)}"


@dataclass
class Reindexed:
    """What ``reindex`` did."""

    bag: Path
    messages: int
    topics: dict[str, int]
    chunks: int
    start_ns: int
    end_ns: int
    damage: list[Damage] = field(default_factory=list)
    tail: Damage | None = None
    rewritten: bool = False          # a new file (chunk indexes were damaged) rather than an index appended
    already_finished: bool = False   # nothing to do

    def describe(self) -> str:
        span = f", {(self.end_ns - self.start_ns) / 1e9:.3f} s" if self.messages else ""
        if self.already_finished:
            return (f"{self.bag}: already complete ({_count(self.messages, 'message')} on "
                    f"{_count(len(self.topics), 'topic')}{span})")
        parts = [f"reindexed {self.bag}: recovered {_count(self.messages, 'message')} on "
                 f"{_count(len(self.topics), 'topic')} in {_count(self.chunks, 'chunk')}{span}"]
        if self.tail is not None:
            parts.append(f"dropped an unfinished end, {self.tail.describe()}")
        parts += [f"skipped damaged {d.describe()}" for d in self.damage]
        return "; ".join(parts)


def reindex(bag: str | os.PathLike[str], *, ignore_damage: bool = False) -> Reindexed:
    """Make an unfinished or damaged bag readable again: cut off an incomplete last record, index every chunk that
    checks out, and write metadata.yaml. Chunks in the middle of the file that fail their checks are left where
    they are, unindexed, and only with ``ignore_damage`` (otherwise RecoveryError names them).

    Normally the index is appended in place after the last valid record (the file is truncated there first, which
    also frees the space a disk-full crash left half-used); if a chunk before the last lost its MessageIndex
    records, a repaired copy replaces the file instead (needs its size in free space).
    """
    bag = Path(bag)
    if not bag.is_dir():
        raise RecoveryError(f"no bag directory at {str(bag)!r}")
    mcap = bag_mcap(bag)
    if mcap is None or not mcap.is_file():
        raise RecoveryError(f"{str(bag)!r} holds no single MCAP file to reindex")
    result = check(mcap)
    topics = {}
    for channel_id, count in result.channel_counts().items():
        if channel_id in result.channels:
            topic = result.channels[channel_id].topic
            topics[topic] = topics.get(topic, 0) + count
    starts = [c.message_start for c in result.chunks if c.message_count]
    ends = [c.message_end for c in result.chunks if c.message_count]
    report = Reindexed(bag, result.message_count, topics, len(result.chunks), min(starts, default=0),
                       max(ends, default=0), result.lost, result.tail)
    if result.healthy and (bag / METADATA).is_file():
        report.already_finished = True
        return report
    if result.lost and not ignore_damage:
        raise RecoveryError(f"{bag} is damaged: " + "; ".join(d.describe() for d in result.lost)
                            + f"; pass --ignore-damage to index the {result.message_count} messages that check out "
                            "without them")
    info = metadata(result, mcap.name)
    schemas, channels = _channels_and_schemas(result)
    if all(c.index_offsets for c in result.chunks[:-1]):
        with open(mcap, "r+b") as stream:
            at = result.data_end
            extra = b""
            last = result.chunks[-1] if result.chunks else None
            if last is not None and not last.index_offsets:   # crashed between the chunk and its index
                at = last.end
                extra, last.index_offsets = message_index_records(last, at)
                last.index_length = len(extra)
            stream.truncate(at)
            stream.seek(at)
            stream.write(extra + index_tail(at + len(extra), schemas, channels, result.chunks,
                                            _tail_metadata(info)))
            stream.flush()
            os.fsync(stream.fileno())
    else:
        tmp = mcap.with_name(mcap.name + ".reindex.tmp")
        try:
            with open(tmp, "wb") as target:
                rewrite(result, target)
                target.flush()
                os.fsync(target.fileno())
            os.replace(tmp, mcap)
        finally:
            tmp.unlink(missing_ok=True)
        report.rewritten = True
    _write_atomically(bag / METADATA, yaml.safe_dump(info, sort_keys=False))
    return report
