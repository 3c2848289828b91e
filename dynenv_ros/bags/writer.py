"""Writing rosbag2 bags (MCAP, format version 9) from raw CDR bytes, without rclpy.

The recorder node hands over the bytes its raw subscriptions received, so nothing is deserialised on the way to
disk. Each topic's connection embeds the message definition and RIHS01 hash from the typestore, so the bag is
readable by rosbags, Foxglove and ``ros2 bag`` without the interface package built.

rosbags' ``Writer`` writes metadata.yaml; the MCAP file itself is written by ``CrashSafeMcapStorage``
(``dynenv_ros.bags.mcap``): chunks of at most 256 KiB / 0.5 s with CRCs, handed to the OS as they close, so a
killed process leaves a file ``dynenv-bag reindex`` makes readable again, losing at most the open chunk.
"""
from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys.store import Typestore

from dynenv_ros.bags.mcap import CrashSafeMcapStorage

_INFINITE = QosTime(9223372036, 854775807)   # RMW_DURATION_INFINITE, as Jazzy's ros2 bag writes it

# What the simulator publishes with (dynenv_ros.ros.qos.sim_stream), in rosbags' terms: ``ros2 bag play`` of our
# bags then offers the same reliable KEEP_ALL stream.
SIM_STREAM_QOS = Qos(history=QosHistory.KEEP_ALL, depth=0, reliability=QosReliability.RELIABLE,
                     durability=QosDurability.VOLATILE, deadline=_INFINITE, lifespan=_INFINITE,
                     liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_INFINITE,
                     avoid_ros_namespace_conventions=False)


class _Writer(Writer):
    """rosbags' Writer with the crash-safe MCAP storage."""

    STORAGE_PLUGINS = {StoragePlugin.MCAP: CrashSafeMcapStorage}


class BagWriter:
    """One new rosbag2 MCAP bag; topics are added as they are discovered, messages written as they arrive.

    ``close()`` writes the MCAP summary/footer and metadata.yaml; until then only ``dynenv-bag reindex`` makes
    the bag readable, so callers close it on every exit path (it is safe to call twice, and the object is a
    context manager). Callers that see no messages for a while call ``flush`` on a timer (the recorder every
    FLUSH_PERIOD_S) so that a quiet topic's last messages reach the disk too.

    Writing errors (disk full, I/O errors) are OSError from ``write``/``flush``/``close``; afterwards ``failed``
    holds the error, the file ends in a partial record and ``abort()`` closes it for ``reindex``.
    """

    def __init__(self, path: str | os.PathLike[str], typestore: Typestore) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"bag {str(self.path)!r} already exists: choose a new output directory "
                                  "(bags are never overwritten or appended to)")
        self.typestore = typestore
        writer = _Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            writer.open()
        except OSError:
            if self.path.is_dir() and not any(p.stat().st_size > 64 for p in self.path.iterdir()):
                shutil.rmtree(self.path, ignore_errors=True)   # ours, and holding nothing (e.g. disk full)
            raise
        self._writer: Writer | None = writer
        self._storage: CrashSafeMcapStorage = writer.storage  # type: ignore[assignment]
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    @property
    def closed(self) -> bool:
        return self._writer is None

    @property
    def failed(self) -> OSError | None:
        """The write error that stopped this bag, if any."""
        return self._storage.failed

    @property
    def flushed_messages(self) -> int:
        """Messages handed to the OS in complete chunks: what ``reindex`` recovers after a crash."""
        return self._storage.flushed_messages

    @property
    def mcap_path(self) -> Path:
        return self._storage.path

    def flush(self, max_age_s: float | None = None) -> None:
        """Write the open chunk if it holds messages (with ``max_age_s``: only if it is at least that old)."""
        if self._writer is not None:
            self._storage.flush(max_age_s)

    def abort(self) -> None:
        """Close the file without an index (after a write error); idempotent."""
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.abort()

    @property
    def topics(self) -> dict[str, str]:
        """Topic name → message type of every topic added so far."""
        return {topic: connection.msgtype for topic, connection in self._connections.items()}

    def add_topic(self, name: str, msgtype: str, qos: Sequence[Qos] = (SIM_STREAM_QOS,)) -> None:
        """Register a topic before writing to it; the type must be known to the typestore (its definition is
        embedded in the bag). ``qos``: the profiles its publishers offer, one each (``offered_qos_profiles``, what
        the player republishes with; the recorder passes what discovery reported, the default is the simulator's
        stepped stream). Adding a topic again with the same type is a no-op; another type is refused."""
        writer = self._open_writer()
        known = self._connections.get(name)
        if known is not None:
            if known.msgtype != msgtype:
                raise ValueError(f"topic {name!r} is already recorded as {known.msgtype}, not {msgtype}")
            return
        if msgtype not in self.typestore.types:
            raise KeyError(f"message type {msgtype!r} is unknown to the typestore: its definition cannot be "
                           "embedded in the bag")
        self._connections[name] = writer.add_connection(name, msgtype, typestore=self.typestore,
                                                        offered_qos_profiles=list(qos))
        self.counts[name] = 0

    def write(self, topic: str, timestamp_ns: int, data: bytes | bytearray | memoryview) -> None:
        """Append one serialized (CDR) message; ``timestamp_ns`` is the bag time (ns since the epoch)."""
        writer = self._open_writer()
        connection = self._connections.get(topic)
        if connection is None:
            raise KeyError(f"topic {topic!r} was not added to the bag (add_topic first)")
        writer.write(connection, int(timestamp_ns), bytes(data))
        self.counts[topic] += 1

    def close(self) -> None:
        """Finish the bag (MCAP footer, metadata.yaml). Idempotent."""
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()

    def _open_writer(self) -> Writer:
        if self._writer is None:
            raise RuntimeError(f"bag {str(self.path)!r} is closed")
        return self._writer

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
