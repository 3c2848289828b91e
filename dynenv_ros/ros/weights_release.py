"""The trainer's side of signed weights (docs/ros_graph.md, "Who may change the weights"): each release is signed
(``security.weights_signing``) and announced on ``/trainer/weights_announcement`` (reliable, transient local,
depth 1: a policy node that starts late gets the latest at once). Its signed metadata names its source
(``security.weights_source``): this node, the fetch service ``/trainer/fetch_weights_<key id>`` and the blob topic
``/trainer/weights_blob``, with the digest of the chunk manifest.

The bytes go out two ways. On the blob topic (reliable, transient local, one sample per chunk of at most 1 MiB and
the manifest first; the writer keeps exactly the current release, so a reader that (re)subscribes gets it whole),
where a policy node checks every sample against the signed digests, so no other writer can displace them. And on
the fetch service, in chunks by offset, for a node the topic does not reach; the last ``HELD`` releases stay
servable there, so a policy node still fetching version v when v + 1 is announced can finish. The blob is published
before the announcement, so a node that subscribes on the announcement finds it held.

The blob topic's type is FetchWeights' response (``data``: a bounded chunk; ``message`` says which, for people
only: a node places a sample by its bytes), so no interface changed (docs/decisions.md).
"""
from __future__ import annotations

import array
import hashlib
import threading
import time
from collections import OrderedDict
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from dynenv_msgs.msg import WeightsAnnouncement
from dynenv_msgs.srv import FetchWeights
from rclpy.node import Node

from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import latched
from dynenv_ros.security.keys import key_id
from dynenv_ros.security.weights_download import CHUNK_BYTES, chunk_count, manifest
from dynenv_ros.security.weights_signing import MAX_METADATA, Announcement, sign
from dynenv_ros.security.weights_source import Source, fetch_service_name, with_source

HELD = 2          # the current release and the one before, on the fetch service
# A policy node's blob reader keeps at least this many samples for its executor (each at most a chunk, 1 MiB), and
# while a release is wanted as many as it has (manifest and chunks): a short burst of junk between two takes cannot
# push a genuine sample out; a longer one costs a resubscription (ros.weights_follower).
BLOB_READER_DEPTH = 4


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

    def __init__(self, node: Node, private_key: Ed25519PrivateKey, run_id: str, blob: bool = True) -> None:
        """``blob`` false: the bytes are served on the fetch service only (the source names no blob topic)."""
        self.node, self.key, self.run_id = node, private_key, run_id
        self.held: OrderedDict[tuple[str, int], bytes] = OrderedDict()     # (run, version) -> file bytes
        self.lock = threading.Lock()
        self.served_chunks = 0
        self.refused_requests = 0
        self.blob_samples = 0
        self.publisher = node.create_publisher(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, latched(1))
        self.service = node.create_service(FetchWeights, fetch_service_name(topics.FETCH_WEIGHTS,
                                                                            key_id(private_key.public_key())),
                                           self._on_fetch)
        self.blob_publisher: Any = None
        self.blob_depth = 0
        self.blob = blob

    def source(self, data: bytes) -> Source:
        """What a release of ``data`` says of where it comes from."""
        return Source(node=self.node.get_fully_qualified_name(), fetch_service=self.service.service_name,
                      blob_topic=topics.WEIGHTS_BLOB if self.blob else "",
                      manifest_sha256=hashlib.sha256(manifest(data)).hexdigest())

    def release(self, version: int, data: bytes, metadata_json: str) -> Announcement:
        """Hold ``data`` as ``version``, publish its bytes on the blob topic, then its signed announcement (stamped
        now, wall clock)."""
        metadata_json = with_source(metadata_json, self.source(data))
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
        if self.blob:
            self._publish_blob(announcement, data)
        self.publisher.publish(to_message(announcement))
        return announcement

    def _publish_blob(self, announcement: Announcement, data: bytes) -> None:
        """The manifest (several chunks only), then every chunk, on a writer that keeps exactly these samples."""
        chunks = chunk_count(len(data))
        samples = ([manifest(data)] if chunks > 1 else []) + [data[i * CHUNK_BYTES:(i + 1) * CHUNK_BYTES]
                                                              for i in range(chunks)]
        if self.blob_publisher is None or self.blob_depth != len(samples):
            if self.blob_publisher is not None:      # a release of another chunk count (a new network size)
                self.node.destroy_publisher(self.blob_publisher)
            self.blob_depth = len(samples)
            self.blob_publisher = self.node.create_publisher(FetchWeights.Response, topics.WEIGHTS_BLOB,
                                                             latched(self.blob_depth))
        a = announcement
        for index, sample in enumerate(samples):
            what = "manifest" if chunks > 1 and index == 0 else f"chunk {index - (chunks > 1)} of {chunks}"
            self.blob_publisher.publish(FetchWeights.Response(
                success=True, message=f"version {a.version} of run {a.run_id[:80]}: {what}",
                data=array.array("B", sample)))
            self.blob_samples += 1

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
