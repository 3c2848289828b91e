"""QoS profiles, named by what they are for, so publishers and subscribers always match."""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy


def latched(depth: int) -> QoSProfile:
    """Reliable and transient-local: a late subscriber still receives the last ``depth`` messages."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def sim_stream() -> QoSProfile:
    """The simulator's data topics: reliable and KEEP_ALL, so a slow subscriber (a recorder) slows the publisher
    down instead of losing messages; stepped mode then runs as fast as the slowest reader allows."""
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
