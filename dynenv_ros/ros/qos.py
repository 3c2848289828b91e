"""QoS profiles, named by what they are for, so publishers and subscribers always match.

A publisher's history (KEEP_ALL / KEEP_LAST and depth) is not part of QoS compatibility: a KEEP_ALL subscriber
(the recorder) matches a KEEP_LAST publisher, it just cannot get more than the publisher still holds.
Depths and why are documented in docs/ros_graph.md ("Real time, QoS and security").
"""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Real-time mode: how many messages a publisher keeps for a reader that has not acknowledged them yet. Five motion
# periods of the topic's rate; a reader further behind loses the oldest (in real time the newest is what counts),
# and the simulator's memory stays bounded however slow its readers are.
REALTIME_FRAME_DEPTH = 25        # /clock, /world_state, /<robot>/detections: 5 frames per period x 5 periods
REALTIME_FEEDBACK_DEPTH = 5      # /<robot>/feedback: one per period
# The simulator's action subscriptions. Stepped: a policy sends one action per period, so ten is ample. Real time:
# deeper, because under a flood the legitimate action must survive in the queue until the simulator's next read
# (it drains the queue in batches); a hundred small messages per robot is still a bounded few kB.
ACTION_QUEUE_DEPTH = 10
REALTIME_ACTION_QUEUE_DEPTH = 100
# Policies keep their last actions for readers that match late (transient local): a recorder that discovers a
# policy's writer a few periods after the game started still gets its first actions.
ACTION_HISTORY_DEPTH = 20


def latched(depth: int) -> QoSProfile:
    """Reliable and transient-local: a late subscriber still receives the last ``depth`` messages."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def sim_stream() -> QoSProfile:
    """The simulator's data topics in stepped mode, and the readers that must lose nothing (recorder): reliable and
    KEEP_ALL, so a slow subscriber slows the publisher down instead of losing messages; stepped mode then runs as
    fast as the slowest reader allows."""
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def realtime_stream(depth: int) -> QoSProfile:
    """The simulator's data topics in real-time mode: reliable but keep-last ``depth``, so readers slower than the
    wall clock cannot make the publisher hold (or wait for) an unbounded backlog."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def action_queue(realtime: bool, latched_offers: bool = True) -> QoSProfile:
    """The simulator's subscriptions to actions, keep-last so a flood on a robot's topic cannot pile up in the
    simulator. Stepped mode reads reliably: a lost action would stall the game. Real time reads best effort: under
    a flood of a few thousand messages/s, a reliable reader's repair traffic stalled delivery on the whole topic,
    the legitimate policy's actions included, for as long as the flood lasted (measured, docs/benchmarks.md); best
    effort keeps delivering, and a lost action in real time is one missing action, the same as a late one.

    Stepped mode also reads transient local while every publisher on the topic offers it (``latched_offers``; the
    policies' ``action_stream`` does): a policy's writer can match the simulator's reader after the policy has
    answered the first observation (discovery is asymmetric; CI under load saw a driving game stall at period 1),
    and a volatile reader never gets an action published before the match, a transient-local one gets the writer's
    kept history. A volatile publisher does not match such a reader, so for its topic the simulator reads volatile
    (``latched_offers=False``), as before."""
    if realtime:
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=REALTIME_ACTION_QUEUE_DEPTH,
                          reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=ACTION_QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched_offers else DurabilityPolicy.VOLATILE)


def action_stream() -> QoSProfile:
    """The policies' action publishers: reliable, transient local, keep-last ``ACTION_HISTORY_DEPTH``. Discovery is
    asymmetric: the simulator may see the recorder's reader before the policy's writer has matched it, and a short
    stepped game can be over by then; the writer's history hands a late reader what it missed: the recorder, the
    trainer, and the stepped simulator (``action_queue``). Volatile readers match it too and get only new actions."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=ACTION_HISTORY_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def recording_qos(offered: list[QoSProfile]) -> QoSProfile:
    """The recorder's subscription to a topic, adapted to its publishers' ``offered`` profiles as rosbag2 does:
    KEEP_ALL; reliable when every publisher offers it (best effort otherwise, which matches them all); transient
    local when every publisher offers it, so their kept history (latched /tf_static, the policies' first actions)
    reaches it (volatile otherwise, which matches any publisher)."""
    profile = sim_stream()
    if offered and not all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered):
        profile.reliability = ReliabilityPolicy.BEST_EFFORT
    if offered and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered):
        profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return profile
