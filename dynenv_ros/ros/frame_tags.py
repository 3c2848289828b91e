"""The nodes' side of authenticated frames (``security/frame_auth.py``): the read-only parameter
``authenticated_frames``, the simulator's companion tag topics (``<topic>_mac``) and a receiver's gate.

Off by default: a real robot's vision stack signs nothing, so a policy node on a robot reads frames as they come.
The train graph turns it on in the simulator, the policy nodes and the trainer, with ``frames.secret`` in their
``secrets_dir`` (docs/ros_graph.md, "Which frames count").
"""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.exceptions import ParameterException
from rclpy.node import Node
from std_msgs.msg import UInt8MultiArray

from dynenv_ros.ros.authentication import SECRETS_PARAMETER
from dynenv_ros.ros.drain import take
from dynenv_ros.ros.parameters import declare_bool
from dynenv_ros.security.action_auth import SecretError, load_secret, secret_path
from dynenv_ros.security.frame_auth import FRAMES, REASONS, TAG_SUFFIX, FrameGate, tag_frame

PARAMETER = "authenticated_frames"


def frames_secret(node: Node, secrets_dir: str, does: str) -> bytes | None:
    """Declare ``authenticated_frames`` and, when it is true, load ``secrets_dir/frames.secret`` (a one-line
    parameter error without secrets_dir or with a bad secret); None when off. ``does``: for ``--help``."""
    on = declare_bool(node, PARAMETER, False, f"{does} under secrets_dir/frames.secret (the train graph; "
                      "docs/ros_graph.md, 'Which frames count'); false: frames as they come (a real robot's "
                      "vision stack signs nothing).", read_only=True)
    if not on:
        return None
    if not secrets_dir:
        raise ParameterException(f"{PARAMETER} needs {SECRETS_PARAMETER} (the directory holding frames.secret)",
                                 [PARAMETER, SECRETS_PARAMETER])
    try:
        return load_secret(secret_path(secrets_dir, FRAMES))
    except SecretError as error:
        raise ParameterException(str(error), [SECRETS_PARAMETER]) from None


def tag_topic(topic: str) -> str:
    """The companion topic of a frame topic (fully qualified in, fully qualified out)."""
    return topic + TAG_SUFFIX


def tag_message(secret: bytes, data: bytes) -> UInt8MultiArray:
    """The companion message of a frame of canonical bytes ``data``."""
    return UInt8MultiArray(data=tag_frame(secret, data))


class FrameReceiver:
    """A receiver's gate (policy node, trainer): ``subscribe`` the companion topic of each frame topic it reads,
    hand each frame to ``frame``; ``release`` gets every frame once its tag came. Refusals are counted by the gate
    (``diagnostics``: ``frames_refused_<reason>``) and logged at most every 5 s."""

    def __init__(self, node: Node, secret: bytes) -> None:
        self.node = node
        self.gate = FrameGate(secret)
        self.subscriptions: list[Any] = []
        self._logged = ""

    def subscribe(self, frame_topic: str, qos: Any, release: Callable[[list[Any]], None]) -> Any:
        """Read the tags of ``frame_topic`` (fully qualified); ``release`` is called with verified frames."""
        def receive(msg: UInt8MultiArray) -> None:
            released = self._queued_tags()
            released += self.gate.tag(msg.data, time.monotonic_ns())
            self._count()
            if released:
                release(released)
        sub = self.node.create_subscription(UInt8MultiArray, tag_topic(frame_topic), receive, qos)
        self.subscriptions.append(sub)
        return sub

    def frame(self, item: Any, data: bytes | None, what: str) -> list[Any]:
        """The frames verified now: ``item`` if its tag came first, else none (it waits for its tag), and any
        waiting frame whose tag was queued. ``data`` None: the frame's bytes could not be computed (a value out of
        its type's range), refused as ``frame_mac_missing``."""
        released = self._queued_tags()
        if data is None:
            self.gate.refuse("frame_mac_missing", f"{what}: a value no genuine frame holds")
        else:
            released += self.gate.frame(item, data, time.monotonic_ns(), what)
        self._count()
        return released

    def _queued_tags(self) -> list[Any]:
        """Take every tag already queued on the companion topics (the executor takes one per subscription per
        wake-up, and frames are drained in batches), before anything can expire: a node busy for longer than the
        gate's wait (a loaded machine, a weights swap) refused frames whose tags sat in its queue, and a stepped
        game stalled. Returns the frames those tags verified."""
        released: list[Any] = []
        for sub in self.subscriptions:
            for _ in range(self.gate.capacity):
                msg = take(sub)
                if msg is None:
                    break
                released += self.gate.tag(msg.data, time.monotonic_ns(), expire=False)
        return released

    def _count(self) -> None:
        if self.gate.last_refusal and self.gate.last_refusal != self._logged:
            self._logged = self.gate.last_refusal
            self.node.get_logger().warning(f"frame refused: {self.gate.last_refusal}", throttle_duration_sec=5.0)

    def diagnostics(self) -> dict[str, str]:
        values = {"frame_authentication": "on", "frames_verified": str(self.gate.counts["frames_verified"]),
                  "frames_awaiting_tag": str(self.gate.waiting), "frame_refusal": self.gate.last_refusal}
        for reason in REASONS:
            values[f"frames_refused_{reason}"] = str(self.gate.counts[reason])
        return values
