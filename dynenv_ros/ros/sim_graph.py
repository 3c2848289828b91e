"""Stepped mode's look at the graph around the simulator: whether everyone the first observation waits for is
there (``wait_for_subscribers``, ``wait_for_ground_truth_subscribers``, ``wait_for_recorder``), and which action
topics a volatile publisher offers (a transient-local reader does not match it; its actions would never arrive).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy

from dynenv_ros.ros import topics
from dynenv_ros.ros.action_inbox import ActionInbox
from dynenv_ros.ros.qos import action_queue
from dynenv_ros.ros.sim_outlet import SimOutlet
from dynenv_ros.ros.sim_parameters import SimSettings
from dynenv_ros.ros.topics import local


class SimGraph:
    """The graph queries of one simulator node (module docstring)."""

    def __init__(self, node: Node, settings: SimSettings, outlet: SimOutlet, inbox: ActionInbox,
                 controlled: Sequence[int], recorder_matched: Mapping[str, int]) -> None:
        self.node, self.settings, self.outlet, self.inbox = node, settings, outlet, inbox
        self.controlled, self.recorder_matched = controlled, recorder_matched
        self.actions = [local(topics.action(n)) for n in settings.names]

    def read_volatile_where_offered(self) -> None:
        """Read a robot's actions volatile once a publisher there offers only volatile durability, and say so once."""
        for robot, subscription in enumerate(self.inbox.subscriptions):
            if subscription.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL:
                continue
            topic = subscription.topic_name
            volatile = [info for info in self.node.get_publishers_info_by_topic(topic)
                        if info.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL]
            if volatile:
                self.inbox.resubscribe(robot, action_queue(realtime=False, latched_offers=False))
                # A writer can be discovered before its participant's node names are ("_NODE_NAME_UNKNOWN_").
                names = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in volatile
                                if "_UNKNOWN_" not in i.node_name + i.node_namespace})
                who = ", ".join(names) if names else "a publisher whose node is not known yet"
                self.node.get_logger().warning(
                    f"{topic}: volatile actions from {who}; "
                    "reading this topic volatile from now on (an action sent before its writer matches this reader "
                    "is lost: publish with dynenv_ros.ros.qos.action_stream(), transient local)")

    def ready(self) -> bool:
        """Everyone the first observation waits for is there."""
        node, outlet, settings = self.node, self.outlet, self.settings
        ready = all(p.get_subscription_count() >= settings.wait_for_subscribers for p in outlet.detection_pubs)
        ready = ready and outlet.world_pub.get_subscription_count() >= settings.wait_for_truth_readers
        if outlet.frame_tag_pubs:
            # ... and as many readers of their tags: a tag sent before its reader matched (discovery is asymmetric,
            # slow under load) is lost, its frame refused, and the stepped game stalls at its first period
            ready = ready and all(p.get_subscription_count() >= settings.wait_for_subscribers
                                  for p in outlet.frame_tag_pubs[1:])
        # ... and every controlled robot has someone to act for it, matched by the action inbox's own participant
        # (it discovers writers on its own schedule), so no first action is sent into the void.
        ready = ready and all(self.inbox.subscriptions[i].get_publisher_count()
                              >= max(1, node.count_publishers(self.actions[i])) for i in self.controlled)
        if settings.wait_for_recorder:
            ready = ready and all(p.get_subscription_count() >= 1
                                  for p in outlet.feedback_pubs + outlet.pose_pubs + [outlet.clock_pub])
            # ... and every action topic has a reader besides this node (the recorder), or the first actions a
            # policy sends are accepted here but never recorded.
            ready = ready and all(node.count_subscribers(a) >= 2 for a in self.actions)
            # Seeing both the recorder's reader and a policy's writer does not mean they have matched each other;
            # a dynenv recorder says which publishers it has matched (another recorder: the check above only).
            if node.count_publishers(local(topics.RECORDER_DIAGNOSTICS)) > 0:
                ready = ready and all(self.recorder_matched.get(node.resolve_topic_name(a), 0)
                                      >= node.count_publishers(a) for a in self.actions)
        return ready


__all__ = ["SimGraph"]
