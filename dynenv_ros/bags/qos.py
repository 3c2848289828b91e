"""The QoS a bag records for each topic and the QoS a player offers when it republishes the topic (ROS-free: rosbags'
``Qos`` records, what rosbag2 version 9 writes under ``offered_qos_profiles`` in metadata.yaml).

The recorder writes one profile per publisher it discovered on the topic, as DDS discovery reported it (as Jazzy's
``ros2 bag record`` does). Discovery carries reliability, durability, deadline, lifespan and liveliness but not the
history, so a recorded profile says ``history: unknown, depth: 0`` unless the bag was written by other means.

The player offers, per topic, what lets every reader the original publishers matched match it again, and gives a
late reader of a latched topic what it would have got: ``playback_qos``. Bags with no usable profiles (written
before issue 28, or by tools that write none) play as before: reliable, volatile, KEEP_ALL — except topics named
``tf_static``, which tf2 always latches (its listeners request transient local and would not match a volatile
offer at all), so they play transient local whatever the bag says.
"""
from __future__ import annotations

from collections.abc import Sequence

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

INFINITE = QosTime(9223372036, 854775807)     # RMW_DURATION_INFINITE, as Jazzy's ros2 bag writes it
UNSPECIFIED = QosTime(0, 0)                   # RMW_DURATION_UNSPECIFIED: the middleware's default (infinite)
# A transient-local topic keeps up to this many of its played messages for late readers: enough for every
# /tf_static or action message of the bags we make, bounded so a long bag cannot hold the player's memory.
LATCHED_DEPTH_MAX = 1000

# What the player offers a topic the bag says nothing usable about: the simulator's stepped-mode stream, lossless.
DEFAULT_PLAYBACK_QOS = Qos(history=QosHistory.KEEP_ALL, depth=0, reliability=QosReliability.RELIABLE,
                           durability=QosDurability.VOLATILE, deadline=UNSPECIFIED, lifespan=UNSPECIFIED,
                           liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=UNSPECIFIED,
                           avoid_ros_namespace_conventions=False)

_KNOWN_RELIABILITY = (QosReliability.RELIABLE, QosReliability.BEST_EFFORT)
_KNOWN_DURABILITY = (QosDurability.VOLATILE, QosDurability.TRANSIENT_LOCAL)
_KNOWN_LIVELINESS = (QosLiveliness.AUTOMATIC, QosLiveliness.MANUAL_BY_NODE, QosLiveliness.MANUAL_BY_TOPIC)


def is_latched_by_convention(topic: str) -> bool:
    """``/tf_static`` (in any namespace): tf2's static broadcasters and listeners are always transient local."""
    return topic.rsplit("/", 1)[-1] == "tf_static"


def _ns(time: QosTime) -> int | None:
    """Nanoseconds of a finite, specified duration; None for infinite or unspecified (both mean "no limit")."""
    if time in (INFINITE, UNSPECIFIED) or time.sec < 0 or time.nsec < 0:
        return None
    total = time.sec * 1_000_000_000 + time.nsec
    return None if total >= INFINITE.sec * 1_000_000_000 + INFINITE.nsec else total


def _time(ns: int | None) -> QosTime:
    """No limit is offered as unspecified: the middleware's default (infinite), as rclpy's own profiles leave it."""
    return UNSPECIFIED if ns is None else QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def _liveliness(kinds: set[QosLiveliness]) -> QosLiveliness:
    """The recorded kind when all publishers agree, else automatic. Manual-by-node (deprecated in ROS 2) plays
    manual-by-topic, which matches the same requests and is asserted by publishing."""
    if len(kinds) != 1:
        return QosLiveliness.AUTOMATIC
    kind = next(iter(kinds))
    return QosLiveliness.MANUAL_BY_TOPIC if kind == QosLiveliness.MANUAL_BY_NODE else kind


def playback_qos(topic: str, offered: Sequence[Qos], message_count: int) -> Qos:
    """The profile to republish ``topic`` with, from its recorded publishers' ``offered`` profiles.

    Per policy, the strongest offer recorded, because a stronger offer matches every request a weaker one matched:
    reliable unless every publisher was best effort; transient local if any publisher was (or the topic is
    ``tf_static``); the shortest finite deadline and liveliness lease; the liveliness kind when all agree
    (``_liveliness``); the longest lifespan. History is not part of matching and discovery does not report it:
    a volatile topic plays KEEP_ALL (a slow reader slows playback rather than losing messages, as the simulator's
    stepped stream does); a transient-local topic keeps its last ``message_count`` messages (at most
    ``LATCHED_DEPTH_MAX``, at least a recorded KEEP_LAST depth), so a reader that joins after they were played still
    gets them — every static transform of the bag, for a late tf2 listener. Values a profile gives as unknown or
    system default count as not given."""
    reliabilities = {q.reliability for q in offered if q.reliability in _KNOWN_RELIABILITY}
    durabilities = {q.durability for q in offered if q.durability in _KNOWN_DURABILITY}
    reliability = (QosReliability.BEST_EFFORT if reliabilities == {QosReliability.BEST_EFFORT}
                   else QosReliability.RELIABLE)
    latched = QosDurability.TRANSIENT_LOCAL in durabilities or is_latched_by_convention(topic)
    deadlines = [ns for q in offered if (ns := _ns(q.deadline)) is not None]
    leases = [ns for q in offered if (ns := _ns(q.liveliness_lease_duration)) is not None]
    lifespans = [_ns(q.lifespan) for q in offered]
    kinds = {q.liveliness for q in offered if q.liveliness in _KNOWN_LIVELINESS}
    lifespan = None if not lifespans or None in lifespans else max(ns for ns in lifespans if ns is not None)
    if latched:
        recorded_depth = max((q.depth for q in offered if q.history == QosHistory.KEEP_LAST), default=0)
        history, depth = QosHistory.KEEP_LAST, max(1, min(LATCHED_DEPTH_MAX, max(message_count, recorded_depth)))
    else:
        history, depth = QosHistory.KEEP_ALL, 0
    return Qos(history=history, depth=depth, reliability=reliability,
               durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
               deadline=_time(min(deadlines, default=None)), lifespan=_time(lifespan),
               liveliness=_liveliness(kinds),
               liveliness_lease_duration=_time(min(leases, default=None)),
               avoid_ros_namespace_conventions=False)
