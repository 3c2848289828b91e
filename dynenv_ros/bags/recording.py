"""A bag being recorded live: the recorder node's ROS-free part (``nodes/recorder.py`` subscribes and hands over
raw CDR bytes).

Bag time of a message is its receive time in ns, like ``ros2 bag record``: wall time, or with ``use_sim_time`` the
latest ``/clock`` value recorded (read from the raw bytes, so it never depends on callback order between the clock
and the data). A write that fails (disk full, I/O error) stops the recording: what follows is counted as dropped,
and at the end what reached the disk is reindexed (``bags.recovery``).
"""
from __future__ import annotations

import errno
import struct
import time

from dynenv_ros.bags.recovery import RecoveryError, reindex
from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.bags.writer import BagWriter

CLOCK_TOPIC = "/clock"


class Recording:
    """One bag from its creation to its end. Creating it refuses an existing ``output`` (FileExistsError) and a
    directory that cannot be written (OSError)."""

    def __init__(self, output: str, use_sim_time: bool) -> None:
        self.output = output
        self.bag = BagWriter(output, dynenv_typestore())
        self.use_sim_time = use_sim_time
        self.sim_ns = 0
        self.failure = ""             # why nothing is being recorded any more ("" while recording)
        self.dropped = 0              # messages received but not on disk because a write failed
        self.recovered: int | None = None   # messages the reindex after a failure kept

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        return dict(self.bag.counts)

    @property
    def written(self) -> int:
        """Messages written: all while recording, those on disk after a failure."""
        return self.bag.flushed_messages if self.failure else sum(self.bag.counts.values())

    def write(self, topic: str, data: bytes) -> None:
        """Record one message (raw CDR). OSError: the write failed (call ``fail``)."""
        if topic == CLOCK_TOPIC and len(data) >= 12:   # CDR: 4-byte header, int32 sec, uint32 nanosec
            sec, nanosec = struct.unpack_from("<iI", data, 4)
            self.sim_ns = sec * 1_000_000_000 + nanosec
        if self.failure:
            self.dropped += 1
        elif not self.bag.closed:
            self.bag.write(topic, self.sim_ns if self.use_sim_time else time.time_ns(), data)

    def fail(self, error: OSError, this_message: int = 0) -> str:
        """A write failed: stop recording (the file now ends in a partial record); what to tell the operator.
        ``this_message``: 1 when the message being written is lost too."""
        reason = "disk full" if error.errno == errno.ENOSPC else (error.strerror or str(error))
        self.failure = f"cannot write {self.output}: {reason}"
        # accepted but not on disk (the chunk that failed and any still open), and the message being written
        self.dropped += sum(self.bag.counts.values()) - self.bag.flushed_messages + this_message
        said = (f"{self.failure}: nothing is being recorded any more; the {self.bag.flushed_messages} messages "
                "already on disk are kept and the bag is reindexed when the recorder stops")
        self.bag.abort()
        return said

    def close(self) -> str:
        """Finish the bag so it is readable (after a failure: reindex what reached the disk); the summary."""
        if not self.failure:
            try:
                self.bag.close()
            except OSError as error:   # the index did not fit: what is on disk is reindexed below
                self.failure = f"cannot finish {self.output}: {error.strerror or error}"
                self.bag.abort()
        if self.failure:
            return self._recover()
        counts = self.counts
        lines = [f"  {topic}: {count}" for topic, count in sorted(counts.items())]
        return (f"bag {self.output} finished: {sum(counts.values())} messages on {len(counts)} topics"
                + ("\n" + "\n".join(lines) if lines else ""))

    def _recover(self) -> str:
        """After a write failure: index what reached the disk (truncating the partial record frees its space)."""
        try:
            report = reindex(self.output)
        except (OSError, RecoveryError) as error:
            return (f"bag {self.output} NOT finished ({self.failure}); recovering it failed too ({error}): run "
                    f"`dynenv-bag reindex {self.output}` once there is space")
        self.recovered = report.messages
        return (f"bag {self.output} NOT complete ({self.failure}; {self.dropped} messages dropped): "
                f"{report.describe()}")


__all__ = ["Recording"]
