"""MCAP, the container of rosbag2 bags, written so that a crash loses at most a second and read back record by
record so that damage is found, named and skipped rather than silently dropping messages.

Written from the MCAP specification (https://mcap.dev/spec): magic, Header, then the data section (Schema and
Channel records, Chunk records each followed by one MessageIndex record per channel, DataEnd), the summary section
(Schema, Channel, ChunkIndex, MetadataIndex, Statistics, SummaryOffset) and the Footer, then the magic again.

Why not rosbags' own MCAP writer: it keeps a chunk in memory until it passes 1 MiB and writes the index only at
close, so a killed recorder leaves a file no reader opens and loses up to 1 MiB; and it writes no chunk CRC, so
flipped bytes cannot be told from data. ``CrashSafeMcapStorage`` plugs into rosbags' ``Writer`` in its place:

* a chunk is closed when it holds ``CHUNK_MAX_BYTES`` or is ``CHUNK_MAX_AGE_S`` old (``flush()`` is called on a
  timer for quiet periods) and handed to the OS in one unbuffered write, so a killed process loses at most the
  open chunk;
* every chunk carries the CRC32 of its records;
* schemas and channels are written in the data section as soon as they are added, and each channel's metadata
  carries its RIHS01 type hash (``topic_type_hash``, as Jazzy's rosbag2 writes), so ``scan`` can rebuild
  metadata.yaml from the file alone.

``scan`` walks the data section without trusting the summary: every chunk's lengths, decompressed size, CRC (when
the writer gave one) and record framing are checked; a bad region is skipped by searching for the next chunk that
checks out. ``index_tail`` writes DataEnd, summary and footer after whatever valid data there is, which is how a
crashed or damaged file is made readable again (see ``dynenv_ros.bags.recovery``). No ROS imports.
"""
from __future__ import annotations

import errno
import mmap
import os
import struct
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = 0x01, 0x02, 0x03, 0x04, 0x05, \
    0x06, 0x07
OP_CHUNK_INDEX, OP_ATTACHMENT, OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = \
    0x08, 0x09, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F
FOOTER_SIZE = 1 + 8 + 20          # opcode, length, summary_start u64, summary_offset_start u64, summary_crc u32

# Chunking limits of the recorder's bags (rosbag2's own MCAP writer uses 768 KiB chunks and no time limit; ours
# are smaller because a killed recorder loses exactly the chunk still in memory): at most 256 KiB (about 2 s of a
# 2v2 game at real time, so the age limit is what usually closes a chunk) and at most 0.5 s of messages, which with
# a flush timer of FLUSH_PERIOD_S bounds the loss to ~0.75 s. Each chunk costs ~100 bytes of record headers and
# index, negligible next to the data.
CHUNK_MAX_BYTES = 256 * 1024
CHUNK_MAX_AGE_S = 0.5
FLUSH_PERIOD_S = 0.25
COMPRESSIONS = ("", "zstd", "lz4")


class McapFormatError(ValueError):
    """Bytes that do not form the record they claim to be."""


# -------------------------------------------------------------------------------------------------------- records
def _u16(v: int) -> bytes:
    return struct.pack("<H", v)


def _u32(v: int) -> bytes:
    return struct.pack("<I", v)


def _u64(v: int) -> bytes:
    return struct.pack("<Q", v)


def _string(text: str | bytes) -> bytes:
    data = text.encode() if isinstance(text, str) else text
    return _u32(len(data)) + data


def _string_map(pairs: dict[str, str]) -> bytes:
    body = b"".join(_string(k) + _string(v) for k, v in pairs.items())
    return _u32(len(body)) + body


def record(op: int, body: bytes) -> bytes:
    """One MCAP record: opcode, u64 body length, body."""
    return bytes((op,)) + _u64(len(body)) + body


@dataclass(frozen=True)
class Schema:
    id: int
    name: str
    encoding: str
    data: bytes

    def to_record(self) -> bytes:
        return record(OP_SCHEMA, _u16(self.id) + _string(self.name) + _string(self.encoding) + _string(self.data))


@dataclass(frozen=True)
class Channel:
    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]

    def to_record(self) -> bytes:
        return record(OP_CHANNEL, _u16(self.id) + _u16(self.schema_id) + _string(self.topic)
                      + _string(self.message_encoding) + _string_map(self.metadata))


@dataclass
class ChunkInfo:
    """A chunk that checked out: where its record is, its time range, and its messages' (log time, offset within
    the uncompressed records) per channel — what its MessageIndex records and its ChunkIndex say."""

    start: int                      # file offset of the Chunk record's opcode
    length: int                     # the whole record: opcode + length + body
    message_start: int
    message_end: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    index: dict[int, list[tuple[int, int]]]
    index_offsets: dict[int, int] = field(default_factory=dict)   # MessageIndex record per channel, if intact
    index_length: int = 0
    counts: dict[int, int] = field(default_factory=dict)   # messages per channel once ``index`` was let go

    @property
    def end(self) -> int:
        return self.start + self.length

    def channel_counts(self) -> dict[int, int]:
        return {k: len(v) for k, v in self.index.items()} if self.index else dict(self.counts)

    def forget_messages(self) -> None:
        """Keep only the counts: a writer must not hold every message's index entry until the bag is closed (a
        10-minute recording grew the recorder by 40 MiB that way)."""
        self.counts, self.index = self.channel_counts(), {}

    @property
    def message_count(self) -> int:
        return sum(self.channel_counts().values())


def message_index_records(chunk: ChunkInfo, at: int) -> tuple[bytes, dict[int, int]]:
    """The MessageIndex records of ``chunk`` written at file offset ``at``, and their offsets per channel."""
    out = bytearray()
    offsets: dict[int, int] = {}
    for channel_id in sorted(chunk.index):
        entries = sorted(chunk.index[channel_id])
        offsets[channel_id] = at + len(out)
        out += record(OP_MESSAGE_INDEX, _u16(channel_id) + _u32(16 * len(entries))
                      + b"".join(struct.pack("<QQ", t, o) for t, o in entries))
    return bytes(out), offsets


def chunk_record(records: bytes, start: int, end: int) -> bytes:
    """An uncompressed Chunk record around ``records`` with their CRC32."""
    return record(OP_CHUNK, struct.pack("<QQQI", start, end, len(records), zlib.crc32(records))
                  + _string("") + _u64(len(records)) + records)


def index_tail(at: int, schemas: list[Schema], channels: list[Channel], chunks: list[ChunkInfo],
               metadata: dict[str, dict[str, str]]) -> bytes:
    """Everything after the last data record, to be written at file offset ``at``: DataEnd, the Metadata records,
    the summary (schemas, channels, chunk indexes, metadata indexes, statistics), summary offsets, the Footer with
    the summary's CRC, and the closing magic. ``chunks`` must have ``index_offsets``/``index_length`` set."""
    out = bytearray(record(OP_DATA_END, _u32(0)))      # 0: no data-section CRC (each chunk has its own)
    metadata_at: list[tuple[int, int, str]] = []
    for name, pairs in metadata.items():
        rec = record(OP_METADATA, _string(name) + _string_map(pairs))
        metadata_at.append((at + len(out), len(rec), name))
        out += rec
    summary_start = at + len(out)
    groups: list[tuple[int, int, int]] = []

    def group(op: int, records: list[bytes]) -> None:
        if records:
            groups.append((op, at + len(out), sum(len(r) for r in records)))
            out.extend(b"".join(records))

    group(OP_SCHEMA, [s.to_record() for s in schemas])
    group(OP_CHANNEL, [c.to_record() for c in channels])
    group(OP_CHUNK_INDEX, [record(OP_CHUNK_INDEX, struct.pack("<QQQQ", c.message_start, c.message_end, c.start,
                                                                   c.length)
                                  + _u32(10 * len(c.index_offsets))
                                  + b"".join(struct.pack("<HQ", k, v) for k, v in sorted(c.index_offsets.items()))
                                  + _u64(c.index_length) + _string(c.compression)
                                  + _u64(c.compressed_size) + _u64(c.uncompressed_size)) for c in chunks])
    group(OP_METADATA_INDEX, [record(OP_METADATA_INDEX, _u64(o) + _u64(n) + _string(name))
                              for o, n, name in metadata_at])
    counts: dict[int, int] = {c.id: 0 for c in channels}
    for chunk in chunks:
        for channel_id, count in chunk.channel_counts().items():
            counts[channel_id] = counts.get(channel_id, 0) + count
    total = sum(counts.values())
    starts = [c.message_start for c in chunks if c.message_count]
    ends = [c.message_end for c in chunks if c.message_count]
    group(OP_STATISTICS, [record(OP_STATISTICS, struct.pack("<QHIIIIQQ", total, len(schemas), len(channels), 0,
                                                            len(metadata), len(chunks), min(starts, default=0),
                                                            max(ends, default=0))
                                 + _u32(10 * len(counts))
                                 + b"".join(struct.pack("<HQ", k, v) for k, v in sorted(counts.items())))])
    summary_offset_start = at + len(out)
    for op, start, length in list(groups):
        out += record(OP_SUMMARY_OFFSET, struct.pack("<BQQ", op, start, length))
    footer_fields = _u64(summary_start) + _u64(summary_offset_start)
    out += bytes((OP_FOOTER,)) + _u64(20) + footer_fields
    summary_crc = zlib.crc32(bytes(out[summary_start - at:]))
    out += _u32(summary_crc) + MAGIC
    return bytes(out)


# --------------------------------------------------------------------------------------------------------- writer
class CrashSafeMcapStorage:
    """rosbags' MCAP storage protocol (``__init__(path, compression)``, ``add_msgtype``, ``add_connection``,
    ``write``, ``close``, ``abort``) with bounded buffering, chunk CRCs and ``flush``; see the module docstring.

    A failed write (disk full, I/O error) leaves ``failed`` set and makes every later write raise: the file then
    ends in a partial record, which ``dynenv_ros.bags.recovery.reindex`` cuts off.
    """

    def __init__(self, path: Path, compression: Any) -> None:
        if getattr(compression, "name", "NONE") != "NONE":
            raise ValueError("CrashSafeMcapStorage writes uncompressed chunks only")
        self.path = Path(path) / f"{Path(path).name}.mcap"
        self._file = open(self.path, "xb", buffering=0)   # unbuffered: each chunk goes to the OS in one write
        self._position = 0
        self.failed: OSError | None = None
        self.schemas: list[Schema] = []
        self.channels: list[Channel] = []
        self.chunks: list[ChunkInfo] = []
        self.flushed_messages = 0                       # messages in chunks handed to the OS
        self._new_chunk()
        try:
            self._write_out(MAGIC + record(OP_HEADER, _string("ros2") + _string("dynenv_ros")))
        except OSError:
            self._file.close()
            raise

    def _new_chunk(self) -> None:
        self._records = bytearray()
        self._index: dict[int, list[tuple[int, int]]] = {}
        self._chunk_start = 2**63 - 1
        self._chunk_end = 0
        self._opened = time.monotonic()

    def _write_out(self, data: bytes) -> None:
        """All of ``data`` to the file, or OSError with ``failed`` set (a raw write may be short: loop)."""
        if self.failed is not None:
            raise OSError(self.failed.errno, f"bag writing already failed: {self.failed.strerror or self.failed}")
        view = memoryview(data)
        try:
            while view:
                written = self._file.write(view)
                if not written:
                    raise OSError(errno.ENOSPC, "no space left on device (short write)")
                self._position += written
                view = view[written:]
        except OSError as error:
            self.failed = error
            raise

    def add_msgtype(self, connection: Any) -> None:
        encoding = "ros2msg" if getattr(connection.msgdef.format, "name", "MSG") == "MSG" else "ros2idl"
        schema = Schema(len(self.schemas) + 1, connection.msgtype, encoding, connection.msgdef.data.encode())
        self._write_out(schema.to_record())
        self.schemas.append(schema)

    def add_connection(self, connection: Any, offered_qos_profiles: str) -> None:
        schema_id = next(s.id for s in self.schemas if s.name == connection.msgtype)
        channel = Channel(connection.id, schema_id, connection.topic, connection.ext.serialization_format,
                          {"offered_qos_profiles": offered_qos_profiles, "topic_type_hash": connection.digest or ""})
        self._write_out(channel.to_record())
        self.channels.append(channel)

    def write(self, connection: Any, timestamp: int, data: bytes | memoryview) -> None:
        if self.failed is not None:
            self._write_out(b"")   # raises
        if not self._records:
            self._opened = time.monotonic()
        self._index.setdefault(connection.id, []).append((timestamp, len(self._records)))
        self._records += record(OP_MESSAGE, struct.pack("<HIQQ", connection.id, 0, timestamp, timestamp)
                                + bytes(data))
        self._chunk_start = min(self._chunk_start, timestamp)
        self._chunk_end = max(self._chunk_end, timestamp)
        if len(self._records) >= CHUNK_MAX_BYTES or time.monotonic() - self._opened >= CHUNK_MAX_AGE_S:
            self.flush()

    @property
    def pending_messages(self) -> int:
        return sum(len(v) for v in self._index.values())

    def flush(self, max_age_s: float | None = None) -> None:
        """Close the open chunk (if it holds messages and, with ``max_age_s``, is at least that old) and hand it
        with its MessageIndex records to the OS in one write."""
        if not self._records or (max_age_s is not None and time.monotonic() - self._opened < max_age_s):
            return
        records = bytes(self._records)
        chunk = ChunkInfo(self._position, 0, self._chunk_start, self._chunk_end, "", len(records), len(records),
                          self._index)
        data = chunk_record(records, self._chunk_start, self._chunk_end)
        chunk.length = len(data)
        indexes, chunk.index_offsets = message_index_records(chunk, chunk.end)
        chunk.index_length = len(indexes)
        count = chunk.message_count
        self._new_chunk()   # the messages are gone from memory either way: a failed write is not retried
        self._write_out(data + indexes)
        chunk.forget_messages()
        self.chunks.append(chunk)
        self.flushed_messages += count

    def close(self, version: int, metadata: str) -> None:
        """Flush, write the index (summary, footer), sync to disk and close."""
        try:
            self.flush()
            self._write_out(index_tail(self._position, self.schemas, self.channels, self.chunks,
                                       {"rosbag2": {"serialized_metadata": metadata}}))
            os.fsync(self._file.fileno())
        finally:
            self._file.close()

    def abort(self) -> None:
        """Close without an index (the file stays recoverable up to its last whole chunk)."""
        if not self._file.closed:
            self._file.close()


# ------------------------------------------------------------------------------------------------------- scanning
class _Cursor:
    """Bounds-checked little-endian reads from a buffer; any overrun raises McapFormatError."""

    def __init__(self, buf: Any, pos: int, end: int) -> None:
        self.buf, self.pos, self.end = buf, pos, end

    def take(self, n: int) -> bytes:
        if n < 0 or self.pos + n > self.end:
            raise McapFormatError(f"field of {n} bytes overruns its record")
        data = bytes(self.buf[self.pos:self.pos + n])
        self.pos += n
        return data

    def unpack(self, fmt: str) -> tuple[int, ...]:
        return struct.unpack(fmt, self.take(struct.calcsize(fmt)))

    def string(self) -> str:
        try:
            return self.take(self.unpack("<I")[0]).decode()
        except UnicodeDecodeError as error:
            raise McapFormatError(f"string is not UTF-8: {error}") from None

    def blob(self) -> bytes:
        return self.take(self.unpack("<I")[0])

    def string_map(self) -> dict[str, str]:
        (length,) = self.unpack("<I")
        end = self.pos + length
        if end > self.end:
            raise McapFormatError("map overruns its record")
        inner = _Cursor(self.buf, self.pos, end)
        pairs: dict[str, str] = {}
        while inner.pos < end:
            key = inner.string()
            pairs[key] = inner.string()
        self.pos = end
        return pairs


def parse_schema(body: Any, start: int, end: int) -> Schema:
    c = _Cursor(body, start, end)
    return Schema(c.unpack("<H")[0], c.string(), c.string(), c.blob())


def parse_channel(body: Any, start: int, end: int) -> Channel:
    c = _Cursor(body, start, end)
    channel_id, schema_id = c.unpack("<HH")
    return Channel(channel_id, schema_id, c.string(), c.string(), c.string_map())


@dataclass
class Damage:
    """A byte range of the file that could not be used, why, and how many messages it held (None: unknown)."""

    start: int
    end: int
    reason: str
    messages: int | None = None
    topics: tuple[str, ...] = ()
    indexed: bool = True     # False: a trusted index already leaves the region out (e.g. after reindex), so
    #                          readers lose nothing they were promised

    def describe(self) -> str:
        held = ("an unknown number of messages" if self.messages is None
                else f"{self.messages} message{'s' * (self.messages != 1)}")
        names = list(self.topics[:4]) + ([f"{len(self.topics) - 4} more topics"] if len(self.topics) > 4 else [])
        on = f" on {', '.join(names)}" if names else ""
        return f"bytes {self.start}-{self.end} ({self.end - self.start} B, {self.reason}): {held}{on}"


@dataclass
class McapScan:
    """What ``scan`` found in one MCAP file."""

    path: Path
    size: int
    header_end: int = 0
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[ChunkInfo] = field(default_factory=list)
    damage: list[Damage] = field(default_factory=list)     # regions between valid records, in file order
    tail: Damage | None = None                              # an unfinished end: incomplete record, no index
    data_end: int = 0                                       # end of the last valid data record (or its index)
    finished: bool = False                                  # a DataEnd, a summary and a footer that check out
    summary_problem: str = ""                               # why a present summary was not trusted
    loose_messages: int = 0                                 # Message records outside chunks (not indexed)
    orphans: int = 0                                        # messages whose channel record is nowhere

    @property
    def message_count(self) -> int:
        return sum(c.message_count for c in self.chunks)

    def channel_counts(self) -> dict[int, int]:
        counts = {channel_id: 0 for channel_id in self.channels}
        for chunk in self.chunks:
            for channel_id, entries in chunk.index.items():
                counts[channel_id] = counts.get(channel_id, 0) + len(entries)
        return counts

    @property
    def lost(self) -> list[Damage]:
        """Damaged regions that held messages the index promises (or with no trusted index: any)."""
        return [d for d in self.damage if d.indexed]

    @property
    def healthy(self) -> bool:
        """Finished, the summary agrees with the data, nothing it indexes is damaged: readers see every message
        the bag says it has."""
        return self.finished and not self.lost and not self.summary_problem and not self.loose_messages \
            and not self.orphans

    def notes(self) -> list[str]:
        """Damage outside a trusted index (harmless to readers, e.g. what an earlier reindex left out)."""
        return [f"damaged {d.describe()}, outside the index" for d in self.damage if not d.indexed]

    def problems(self) -> list[str]:
        """One phrase per thing wrong, for messages to users."""
        out = [f"damaged {d.describe()}" for d in self.lost]
        if self.tail is not None:
            out.append(f"unfinished: {self.tail.describe()}")
        elif not self.finished:
            out.append("unfinished: no readable index (summary and footer) at the end")
        if self.summary_problem:
            out.append(f"index not trusted: {self.summary_problem}")
        if self.loose_messages:
            out.append(f"{self.loose_messages} messages outside chunks (not indexed, skipped)")
        if self.orphans:
            out.append(f"{self.orphans} messages of channels whose definition is lost (skipped)")
        return out


def _check_chunk(buf: Any, pos: int, limit: int) -> tuple[ChunkInfo, list[Schema], list[Channel]]:
    """Validate the Chunk record at ``pos`` (lengths, compression, size, CRC, record framing) or raise."""
    if pos + 9 > limit or buf[pos] != OP_CHUNK:
        raise McapFormatError("not a chunk record")
    (length,) = struct.unpack_from("<Q", buf, pos + 1)
    end = pos + 9 + length
    if length < 40 or end > limit:
        raise McapFormatError(f"chunk length {length} runs past the end of the data")
    c = _Cursor(buf, pos + 9, end)
    start_time, end_time, uncompressed_size, crc = c.unpack("<QQQI")
    compression = c.string()
    (compressed_size,) = c.unpack("<Q")
    if compression not in COMPRESSIONS:
        raise McapFormatError(f"unknown chunk compression {compression[:16]!r}")
    if c.pos + compressed_size != end:
        raise McapFormatError("chunk data size disagrees with the record length")
    if start_time > end_time:
        raise McapFormatError("chunk start time after its end time")
    data = bytes(buf[c.pos:end])
    if compression == "zstd":
        try:
            from backports import zstd   # what rosbags reads zstd with (a rosbags dependency)
            data = zstd.decompress(data)
        except Exception as error:
            raise McapFormatError(f"zstd data does not decompress: {error}") from None
    elif compression == "lz4":
        try:
            from lz4.frame import decompress
            data = decompress(data)
        except Exception as error:
            raise McapFormatError(f"lz4 data does not decompress: {error}") from None
    if len(data) != uncompressed_size:
        raise McapFormatError(f"chunk holds {len(data)} bytes, its header says {uncompressed_size}")
    if crc and zlib.crc32(data) != crc:
        raise McapFormatError("chunk CRC mismatch")
    index: dict[int, list[tuple[int, int]]] = {}
    schemas: list[Schema] = []
    channels: list[Channel] = []
    p = 0
    while p < len(data):
        if p + 9 > len(data):
            raise McapFormatError("record header overruns the chunk")
        op = data[p]
        (size,) = struct.unpack_from("<Q", data, p + 1)
        body, next_p = p + 9, p + 9 + size
        if next_p > len(data) or op == 0 or op > OP_DATA_END:
            raise McapFormatError(f"record at chunk offset {p} is malformed")
        if op == OP_MESSAGE:
            if size < 22:
                raise McapFormatError("message record too short")
            channel_id, _, log_time = struct.unpack_from("<HIQ", data, body)
            if not start_time <= log_time <= end_time:
                raise McapFormatError("message time outside the chunk's time range")
            index.setdefault(channel_id, []).append((log_time, p))
        elif op == OP_SCHEMA:
            schemas.append(parse_schema(data, body, next_p))
        elif op == OP_CHANNEL:
            channels.append(parse_channel(data, body, next_p))
        p = next_p
    return (ChunkInfo(pos, end - pos, start_time, end_time, compression, compressed_size, uncompressed_size,
                      index), schemas, channels)


def _read_indexes(buf: Any, chunk: ChunkInfo, limit: int) -> int:
    """Check the MessageIndex records right after ``chunk`` against its contents; when they match, set
    ``index_offsets``/``index_length``. Returns where they end (the chunk's end when they are not intact)."""
    pos, offsets = chunk.end, {}
    found: dict[int, list[tuple[int, int]]] = {}
    while pos + 9 <= limit and buf[pos] == OP_MESSAGE_INDEX:
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        if pos + 9 + length > limit or length < 6:
            break
        channel_id, array_length = struct.unpack_from("<HI", buf, pos + 9)
        if array_length != length - 6 or array_length % 16:
            break
        found[channel_id] = sorted(struct.iter_unpack("<QQ", bytes(buf[pos + 15:pos + 9 + length])))
        offsets[channel_id] = pos
        pos += 9 + length
    if found == {k: sorted(v) for k, v in chunk.index.items()}:
        chunk.index_offsets, chunk.index_length = offsets, pos - chunk.end
        return pos
    return chunk.end


def _counts_from_index(buf: Any, pos: int, limit: int) -> dict[int, int]:
    """{channel: messages} listed by MessageIndex records starting at ``pos`` (for reporting a damaged chunk)."""
    counts: dict[int, int] = {}
    while pos + 15 <= limit and buf[pos] == OP_MESSAGE_INDEX:
        (length,) = struct.unpack_from("<Q", buf, pos + 1)
        channel_id, array_length = struct.unpack_from("<HI", buf, pos + 9)
        if length < 6 or array_length != length - 6 or array_length % 16 or pos + 9 + length > limit:
            break
        counts[channel_id] = counts.get(channel_id, 0) + array_length // 16
        pos += 9 + length
    return counts


def _resync(buf: Any, pos: int, limit: int, data_end_at: int | None) -> int:
    """The next offset after ``pos`` where a chunk that checks out (or the known DataEnd) starts; ``limit`` if
    none. Candidates are filtered by opcode and by the chunk length fields agreeing before anything is decoded."""
    candidate = pos
    while True:
        candidate = buf.find(bytes((OP_CHUNK,)), candidate + 1, limit)
        if candidate < 0:
            return data_end_at if data_end_at is not None and data_end_at > pos else limit
        if data_end_at is not None and candidate >= data_end_at:
            return data_end_at
        try:
            _check_chunk(buf, candidate, limit)
            return candidate
        except (McapFormatError, struct.error):
            continue


def scan(path: str | os.PathLike[str]) -> McapScan:
    """Read an MCAP file record by record (see the module docstring); never raises for bad content, only for an
    unreadable file (OSError) or one that is not MCAP at all (McapFormatError)."""
    path = Path(path)
    with open(path, "rb") as stream:
        size = os.fstat(stream.fileno()).st_size
        result = McapScan(path, size)
        if size < len(MAGIC) + 9:
            raise McapFormatError(f"{path.name} is too short to be an MCAP file ({size} bytes)")
        with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            _scan(buf, result)
    return result


def _summary(buf: Any, result: McapScan) -> tuple[int | None, dict[int, dict[int, int]] | None, int | None]:
    """(summary start, {chunk offset: {channel: messages}}, statistics message count) from a footer that
    checks out, else (None, None, None) with ``summary_problem`` set when there was a footer but it is bad."""
    size = result.size
    if size < len(MAGIC) * 2 + FOOTER_SIZE or bytes(buf[size - 8:]) != MAGIC:
        return None, None, None
    footer = size - 8 - FOOTER_SIZE
    if buf[footer] != OP_FOOTER or struct.unpack_from("<Q", buf, footer + 1)[0] != 20:
        result.summary_problem = "the footer is malformed"
        return None, None, None
    summary_start, _, summary_crc = struct.unpack_from("<QQI", buf, footer + 9)
    if not result.header_end <= summary_start <= footer:
        result.summary_problem = "the footer points outside the file"
        return None, None, None
    if summary_crc and zlib.crc32(bytes(buf[summary_start:footer + 25])) != summary_crc:
        result.summary_problem = "summary CRC mismatch"
        return summary_start, None, None
    chunk_counts: dict[int, dict[int, int]] = {}
    statistics: int | None = None
    pos = summary_start
    try:
        while pos < footer:
            op = buf[pos]
            (length,) = struct.unpack_from("<Q", buf, pos + 1)
            if pos + 9 + length > footer:
                raise McapFormatError("summary record overruns the footer")
            if op == OP_CHUNK_INDEX:
                c = _Cursor(buf, pos + 9, pos + 9 + length)
                _, _, chunk_start, chunk_length = c.unpack("<QQQQ")
                offsets = sorted((o, k) for k, o in struct.iter_unpack("<HQ", c.blob()))
                (index_length,) = c.unpack("<Q")
                bounds = [o for o, _ in offsets] + [chunk_start + chunk_length + index_length]
                # MessageIndex records follow the chunk back to back: 15 bytes of header, 16 per message
                chunk_counts[chunk_start] = {k: (b - o - 15) // 16 for (o, k), b in zip(offsets, bounds[1:])}
            elif op == OP_STATISTICS:
                (statistics,) = struct.unpack_from("<Q", buf, pos + 9)
            pos += 9 + length
    except (McapFormatError, struct.error) as error:
        result.summary_problem = f"summary unreadable ({error})"
        return summary_start, None, None
    return summary_start, chunk_counts, statistics


def _scan(buf: Any, result: McapScan) -> None:
    size = result.size
    if bytes(buf[:8]) != MAGIC:
        raise McapFormatError(f"{result.path.name} is not an MCAP file (bad magic)")
    if buf[8] != OP_HEADER:
        raise McapFormatError(f"{result.path.name} has no MCAP header record")
    (header_length,) = struct.unpack_from("<Q", buf, 9)
    result.header_end = pos = 17 + header_length
    if pos > size:
        raise McapFormatError(f"{result.path.name}: the header record is incomplete")
    summary_start, summary_chunks, statistics = _summary(buf, result)
    limit = summary_start if summary_start is not None else size
    data_end_at = summary_start - 13 if summary_start is not None else None   # DataEnd is 13 bytes
    result.data_end = pos
    saw_data_end = False
    while pos < limit:
        problem = ""
        if pos + 9 > limit:
            problem = "incomplete record header"
        else:
            op = buf[pos]
            (length,) = struct.unpack_from("<Q", buf, pos + 1)
            end = pos + 9 + length
            if op == 0 or op > OP_DATA_END:
                problem = f"unknown opcode 0x{op:02x}"
            elif end > limit:
                problem = "record runs past the end of the data"
            elif op == OP_DATA_END:
                saw_data_end = True
                pos = end
                break
            elif op == OP_CHUNK:
                try:
                    chunk, schemas, channels = _check_chunk(buf, pos, limit)
                except (McapFormatError, struct.error) as error:
                    problem = str(error)
                else:
                    for schema in schemas:
                        result.schemas.setdefault(schema.id, schema)
                    for channel in channels:
                        result.channels.setdefault(channel.id, channel)
                    result.chunks.append(chunk)
                    pos = result.data_end = _read_indexes(buf, chunk, limit)
                    continue
            else:
                try:
                    if op == OP_SCHEMA:
                        schema = parse_schema(buf, pos + 9, end)
                        result.schemas.setdefault(schema.id, schema)
                    elif op == OP_CHANNEL:
                        channel = parse_channel(buf, pos + 9, end)
                        result.channels.setdefault(channel.id, channel)
                    elif op == OP_MESSAGE:
                        if length < 22:
                            raise McapFormatError("message record too short")
                        result.loose_messages += 1
                except (McapFormatError, struct.error) as error:
                    problem = str(error)
                else:
                    pos = end
                    if op in (OP_SCHEMA, OP_CHANNEL):
                        result.data_end = pos
                    continue
        # A bad region: skip to the next chunk that checks out. At the end of an unfinished file it is the tail.
        resume = _resync(buf, pos, limit, data_end_at)
        lost: dict[int, int] = {}
        if summary_chunks is not None:
            for start, counts in summary_chunks.items():
                if pos <= start < resume:
                    for channel_id, n in counts.items():
                        lost[channel_id] = lost.get(channel_id, 0) + n
        if not lost and pos + 9 <= limit and buf[pos] == OP_CHUNK:
            (length,) = struct.unpack_from("<Q", buf, pos + 1)
            if pos + 9 + length < resume:
                lost = _counts_from_index(buf, pos + 9 + length, resume)
        damage = Damage(pos, resume, problem, sum(lost.values()) if lost else None,
                        tuple(sorted({result.channels[k].topic if k in result.channels else f"channel {k}"
                                      for k, n in lost.items() if n})),
                        indexed=summary_chunks is None or any(pos <= k < resume for k in summary_chunks))
        if resume >= limit and summary_start is None:
            result.tail = damage
        else:
            result.damage.append(damage)
        pos = resume
    if summary_start is not None:
        result.finished = True
        if not saw_data_end and not result.summary_problem:
            result.summary_problem = "no DataEnd record before the summary"
        if summary_chunks is not None and not result.summary_problem:
            valid = {c.start for c in result.chunks}
            if valid - set(summary_chunks):
                result.summary_problem = f"{len(valid - set(summary_chunks))} chunks are missing from the index"
            elif set(summary_chunks) - valid and not result.lost:
                result.summary_problem = f"{len(set(summary_chunks) - valid)} indexed chunks are not in the data"
            elif statistics is not None and not result.lost and statistics != result.message_count:
                result.summary_problem = (f"the index counts {statistics} messages, the chunks hold "
                                          f"{result.message_count}")
    known = set(result.channels)
    result.orphans = sum(len(v) for c in result.chunks for k, v in c.index.items() if k not in known)

