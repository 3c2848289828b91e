"""The trainer's side of signed weights (docs/ros_graph.md, "Who may change the weights"): each release is signed
(``security.weights_signing``) and announced on ``/trainer/weights_announcement`` (reliable, transient local,
depth 1: a policy node that starts late gets the latest at once), and its bytes are served in chunks of at most
1 MiB on ``/trainer/fetch_weights``. The last ``HELD`` releases stay servable, so a policy node still fetching
version v when v + 1 is announced can finish.
"""
from __future__ import annotations

import array
import hashlib
import threading
import time
from collections import OrderedDict

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from dynenv_msgs.msg import WeightsAnnouncement
from dynenv_msgs.srv import FetchWeights
from rclpy.node import Node

from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import latched
from dynenv_ros.security.weights_download import CHUNK_BYTES
from dynenv_ros.security.weights_signing import MAX_METADATA, Announcement, sign

HELD = 2          # the current release and the one before


def to_message(announcement: Announcement) -> WeightsAnnouncement:
    a = announcement
    msg = WeightsAnnouncement(run_id=a.run_id, version=a.version, size=a.size, sha256=a.sha256,
                              metadata_json=a.metadata_json, key_id=a.key_id,
                              signature=array.array("B", a.signature))
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = a.stamp_sec, a.stamp_nanosec, a.frame_id
    return msg


def from_message(msg: WeightsAnnouncement) -> Announcement:
    return Announcement(run_id=msg.run_id, version=int(msg.version), size=int(msg.size), sha256=msg.sha256,
                        metadata_json=msg.metadata_json, stamp_sec=int(msg.header.stamp.sec),
                        stamp_nanosec=int(msg.header.stamp.nanosec), frame_id=msg.header.frame_id,
                        key_id=msg.key_id, signature=bytes(msg.signature))


class WeightsRelease:
    """Signs, announces and serves the trainer's weights. ``release`` may be called from any thread (the
    learner's); the service answers in the node's executor."""

    def __init__(self, node: Node, private_key: Ed25519PrivateKey, run_id: str) -> None:
        self.node, self.key, self.run_id = node, private_key, run_id
        self.held: OrderedDict[tuple[str, int], bytes] = OrderedDict()     # (run, version) -> file bytes
        self.lock = threading.Lock()
        self.served_chunks = 0
        self.refused_requests = 0
        self.publisher = node.create_publisher(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, latched(1))
        self.service = node.create_service(FetchWeights, topics.FETCH_WEIGHTS, self._on_fetch)

    def release(self, version: int, data: bytes, metadata_json: str) -> Announcement:
        """Hold ``data`` as ``version`` and publish its signed announcement (stamped now, wall clock)."""
        if len(metadata_json) > MAX_METADATA:
            raise ValueError(f"metadata_json of {len(metadata_json)} characters exceeds {MAX_METADATA}")
        now = time.time_ns()
        announcement = sign(Announcement(run_id=self.run_id, version=version, size=len(data),
                                         sha256=hashlib.sha256(data).hexdigest(), metadata_json=metadata_json,
                                         stamp_sec=now // 1_000_000_000, stamp_nanosec=now % 1_000_000_000),
                            self.key)
        with self.lock:
            self.held[(self.run_id, version)] = data
            self.held.move_to_end((self.run_id, version))
            while len(self.held) > HELD:
                self.held.popitem(last=False)
        self.publisher.publish(to_message(announcement))
        return announcement

    def _on_fetch(self, request: FetchWeights.Request, response: FetchWeights.Response) -> FetchWeights.Response:
        with self.lock:
            data = self.held.get((request.run_id, int(request.version)))
            latest = next(reversed(self.held), ("", 0))
        problem = ""
        if data is None:
            problem = (f"version {request.version} of run {request.run_id[:40]!r} is not held; latest is "
                       f"{latest[1]} of run {latest[0]!r}")
        elif not 1 <= request.length <= CHUNK_BYTES:
            problem = f"length {request.length} is outside 1..{CHUNK_BYTES}"
        elif request.offset >= len(data):
            problem = f"offset {request.offset} is beyond the file's {len(data)} bytes"
        if problem:
            self.refused_requests += 1
            response.success, response.message = False, problem[:256]
            return response
        chunk = memoryview(data)[request.offset:request.offset + request.length]
        response.success, response.data = True, array.array("B", chunk)
        self.served_chunks += 1
        return response
