"""Reading a subscription's queue from inside its callback, so a flood cannot push the wanted messages out.

rclpy's executor takes one message per subscription per wake-up; a node with a few dozen entities wakes a few
hundred times a second. A keep-last queue fed faster than that drops its oldest messages, and under a flood those
are the legitimate ones. ``take`` reads the next queued message directly, the way the executor does, so a callback
can drain its own queue in a bounded batch.
"""
from __future__ import annotations

from typing import Any

from rclpy.subscription import Subscription


def take(subscription: Subscription) -> Any | None:
    """The next message queued on ``subscription``, or None when it is empty (or the handle is gone)."""
    try:
        with subscription.handle:
            taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
    except Exception:       # destroyed during shutdown, or an rclpy without this call: nothing to drain
        return None
    return None if taken is None else taken[0]
