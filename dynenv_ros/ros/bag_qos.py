"""rclpy QoS profiles ↔ the rosbags ``Qos`` records a bag's metadata holds (``offered_qos_profiles``).

The recorder turns each discovered publisher's profile into a record; the player turns ``bags.qos.playback_qos``'s
record back into the profile it publishes with. The enums are converted by name: rclpy and rosbags number them
alike today, and a name that one side lacks (rclpy has no deprecated manual-by-node liveliness) becomes the other's
``UNKNOWN`` / system default rather than a wrong value.
"""
from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from dynenv_ros.bags.qos import INFINITE

_INFINITE_NS = INFINITE.sec * 1_000_000_000 + INFINITE.nsec


def _bag_time(duration: Duration) -> QosTime:
    ns = duration.nanoseconds
    if ns >= _INFINITE_NS:
        return INFINITE
    if ns <= 0:
        return QosTime(0, 0)      # unspecified: the middleware's default
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def _ros_duration(time: QosTime) -> Duration:
    return Duration(nanoseconds=min(_INFINITE_NS, time.sec * 1_000_000_000 + time.nsec))


def bag_qos(profile: QoSProfile) -> Qos:
    """A publisher's offered profile (``get_publishers_info_by_topic``) as the record a bag's metadata holds."""
    return Qos(history=QosHistory.__members__.get(profile.history.name, QosHistory.UNKNOWN),
               depth=int(profile.depth),
               reliability=QosReliability.__members__.get(profile.reliability.name, QosReliability.UNKNOWN),
               durability=QosDurability.__members__.get(profile.durability.name, QosDurability.UNKNOWN),
               deadline=_bag_time(profile.deadline), lifespan=_bag_time(profile.lifespan),
               liveliness=QosLiveliness.__members__.get(profile.liveliness.name, QosLiveliness.UNKNOWN),
               liveliness_lease_duration=_bag_time(profile.liveliness_lease_duration),
               avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


def ros_qos(qos: Qos) -> QoSProfile:
    """The rclpy profile of a bag record (the player's offer); an enum rclpy lacks becomes its system default."""
    history = HistoryPolicy.__members__.get(qos.history.name, HistoryPolicy.SYSTEM_DEFAULT)
    return QoSProfile(
        history=history, depth=max(1, qos.depth) if history == HistoryPolicy.KEEP_LAST else qos.depth,
        reliability=ReliabilityPolicy.__members__.get(qos.reliability.name, ReliabilityPolicy.SYSTEM_DEFAULT),
        durability=DurabilityPolicy.__members__.get(qos.durability.name, DurabilityPolicy.SYSTEM_DEFAULT),
        deadline=_ros_duration(qos.deadline), lifespan=_ros_duration(qos.lifespan),
        liveliness=LivelinessPolicy.__members__.get(qos.liveliness.name, LivelinessPolicy.SYSTEM_DEFAULT),
        liveliness_lease_duration=_ros_duration(qos.liveliness_lease_duration),
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


def describe(profile: QoSProfile) -> str:
    """One line for logs, e.g. ``reliable, transient local, keep-last 1``."""
    history = (f"keep-last {profile.depth}" if profile.history == HistoryPolicy.KEEP_LAST
               else profile.history.name.lower().replace("_", "-"))
    return (f"{profile.reliability.name.lower().replace('_', ' ')}, "
            f"{profile.durability.name.lower().replace('_', ' ')}, {history}")
