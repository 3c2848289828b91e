"""Writing rosbag2 bags (MCAP, format version 9) from raw CDR bytes, without rclpy.

The recorder node hands over the bytes its raw subscriptions received, so nothing is deserialised on the way to
disk. Each topic's connection embeds the message definition and RIHS01 hash from the typestore, so the bag is
readable by rosbags, Foxglove and ``ros2 bag`` without the interface package built.
"""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys.store import Typestore

_INFINITE = QosTime(9223372036, 854775807)   # RMW_DURATION_INFINITE, as Jazzy's ros2 bag writes it

# What the simulator publishes with (dynenv_ros.ros.qos.sim_stream), in rosbags' terms: ``ros2 bag play`` of our
# bags then offers the same reliable KEEP_ALL stream.
SIM_STREAM_QOS = Qos(history=QosHistory.KEEP_ALL, depth=0, reliability=QosReliability.RELIABLE,
                     durability=QosDurability.VOLATILE, deadline=_INFINITE, lifespan=_INFINITE,
                     liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=_INFINITE,
                     avoid_ros_namespace_conventions=False)


class BagWriter:
    """One new rosbag2 MCAP bag; topics are added as they are discovered, messages written as they arrive.

    ``close()`` writes the MCAP summary/footer and metadata.yaml; until then the bag is not readable, so callers
    must close it on every exit path (it is safe to call twice, and the object is a context manager).
    """

    def __init__(self, path: str | os.PathLike[str], typestore: Typestore) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"bag {str(self.path)!r} already exists: choose a new output directory "
                                  "(bags are never overwritten or appended to)")
        self.typestore = typestore
        self._writer: Writer | None = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    @property
    def closed(self) -> bool:
        return self._writer is None

    @property
    def topics(self) -> dict[str, str]:
        """Topic name → message type of every topic added so far."""
        return {topic: connection.msgtype for topic, connection in self._connections.items()}

    def add_topic(self, name: str, msgtype: str, qos: Sequence[Qos] = (SIM_STREAM_QOS,)) -> None:
        """Register a topic before writing to it; the type must be known to the typestore (its definition is
        embedded in the bag). Adding a topic again with the same type is a no-op; another type is refused."""
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
