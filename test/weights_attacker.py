"""The attacker of test_weights_attacks.py: a process of its own on the test's ROS domain that tries to make a
running policy node take weights it should not, or choke on them, or starve it of the genuine ones. Every mode
publishes on the trainer's announcement topic from this process and, where a fetch could follow, serves FetchWeights
beside the genuine trainer (whoever answers first wins a fetch): on its own announcements' service, and in the
junk, flood and starve modes on the service the genuine announcements name (read in clear from the topic; "ready"
is printed once that server exists). Prints one JSON line of what it did at the end (after ``seconds``, or on
SIGTERM).

    weights_attacker.py untrusted SECONDS FILE META     # FILE announced and served under a key of its own
    weights_attacker.py tampered SECONDS FILE META      # the genuine announcement's key id and signature, FILE's fields
    weights_attacker.py malformed SECONDS               # an empty sha256, and a size of 1 TiB
    weights_attacker.py replay SECONDS ANNOUNCEMENT     # a recorded genuine announcement (JSON), again and again
    weights_attacker.py flood SECONDS MEGABYTES         # raw oversized bytes on the announcement topic, and
                                                        # BLOB_FLOOD_MB on the blob topic; junk for every fetch
    weights_attacker.py junk SECONDS                    # junk for every fetch, nothing published (a fetch race)
    weights_attacker.py starve SECONDS FILE             # junk for every fetch (FILE's bytes, a policy file of its
                                                        # own), and FILE resized to the release, zeros and a forged
                                                        # manifest on the blob topic every BLOB_JUNK_S
"""
from __future__ import annotations

import array
import dataclasses
import hashlib
import json
import signal
import sys
import time
from pathlib import Path

import rclpy
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from dynenv_msgs.msg import WeightsAnnouncement
from dynenv_msgs.srv import FetchWeights

from benchmarks.weights_flood import oversized_announcement
from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.weights_release import from_message, to_message
from dynenv_ros.security.weights_signing import Announcement, sign

REPEAT_S = 0.5
FLOOD_REPEAT_S = 1.0      # a flood message takes this machine most of a second to hand to DDS
BLOB_JUNK_S = 0.1         # starve: a junk sample of the release's size on the blob topic ten times a second
RACING = ("flood", "junk", "starve")       # modes that answer the genuine trainer's fetch service with junk
BLOB_FLOOD_MB = 20        # flood: each period also a blob sample of this size (20 times the type's bound)


def oversized_blob(size: int) -> bytes:
    """Raw CDR bytes of a blob sample (FetchWeights' response) whose data claims ``size`` bytes and has them: far
    above the type's 1 MiB, so only DDS (the policy node's profile) can refuse it before rclpy, which does not."""
    from rclpy.serialization import serialize_message
    empty = serialize_message(FetchWeights.Response(success=True, message="x"))     # ends in data's length, 0
    return empty[:-4] + size.to_bytes(4, "little") + bytes(size)


def main(mode: str, seconds: float, *args: str) -> None:
    rclpy.init()
    node = rclpy.create_node("weights_attacker")
    publisher = node.create_publisher(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, latched(1))
    report = {"mode": mode, "published": 0, "fetch_requests": 0, "blob_published": 0}
    served: dict[tuple[str, int], bytes] = {}
    messages: list = []             # published in turn, one every REPEAT_S (messages, or raw bytes)
    evil = Path(args[0]).read_bytes() if mode == "starve" else b""
    servers: dict[str, object] = {}
    release = {"size": 0}           # of the genuine release announced last

    def on_fetch(request, response):
        report["fetch_requests"] += 1
        if mode in RACING:                            # junk of the length asked for, as fast as it can
            junk = evil[request.offset:request.offset + request.length].ljust(request.length, b"\0")
            response.success, response.data = True, array.array("B", junk)
            return response
        data = served.get((request.run_id, int(request.version)))
        if data is None:
            response.success, response.message = False, "not mine"
            return response
        response.success = True
        response.data = array.array("B", data[request.offset:request.offset + request.length])
        return response

    if mode not in ("replay", *RACING):      # a replay needs no server: the genuine trainer still holds it
        node.create_service(FetchWeights, topics.FETCH_WEIGHTS, on_fetch)

    def on_announced(msg: WeightsAnnouncement) -> None:
        """Serve the genuine release's fetch service too (its name is in the announcement, in clear)."""
        try:
            name = json.loads(msg.metadata_json)["source"]["fetch_service"]
        except (ValueError, KeyError, TypeError):
            return
        release["size"] = int(msg.size)
        if name not in servers:
            servers[name] = node.create_service(FetchWeights, name, on_fetch)
    if mode in RACING:
        node.create_subscription(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, on_announced, latched(1))
    # a flood keeps one raw sample, not four: this process's own memory
    blob = (node.create_publisher(FetchWeights.Response, topics.WEIGHTS_BLOB, latched(1 if mode == "flood" else 4))
            if mode in ("starve", "flood") else None)
    now = time.time_ns()
    stamp = {"stamp_sec": now // 1_000_000_000 + 3600, "stamp_nanosec": 0}     # an hour ahead: "newest"
    if mode in ("untrusted", "tampered"):
        data, meta = Path(args[0]).read_bytes(), Path(args[1]).read_text()
        mine = Announcement(run_id="evil", version=1000, size=len(data), sha256=hashlib.sha256(data).hexdigest(),
                            metadata_json=meta, **stamp)
        served[("evil", 1000)] = data
        if mode == "untrusted":
            messages.append(to_message(sign(mine, Ed25519PrivateKey.generate())))
        else:
            def on_genuine(msg: WeightsAnnouncement) -> None:
                genuine = from_message(msg)
                if genuine.run_id == "evil" or messages:
                    return
                # the trusted key's id and a signature it really made, on fields that are ours
                forged = dataclasses.replace(mine, run_id=genuine.run_id, version=genuine.version + 1000,
                                             key_id=genuine.key_id, signature=genuine.signature)
                served[(forged.run_id, forged.version)] = data
                messages.append(to_message(forged))
                report["forged_from_version"] = genuine.version
            node.create_subscription(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, on_genuine, latched(1))
    elif mode == "malformed":
        key = Ed25519PrivateKey.generate()
        meta = json.dumps({"config": {"feature_size": 64}})
        messages.append(to_message(sign(Announcement(run_id="evil", version=1000, size=1000, sha256="",
                                                     metadata_json=meta, **stamp), key)))
        messages.append(to_message(sign(Announcement(run_id="evil", version=1001, size=2**40, sha256="0" * 64,
                                                     metadata_json=meta, **stamp), key)))
    elif mode == "replay":
        fields = json.loads(Path(args[0]).read_text())
        fields["signature"] = bytes.fromhex(fields["signature"])
        messages.append(to_message(Announcement(**fields)))
    elif mode == "flood":               # a run_id of that many bytes: DDS must reassemble it before the bound refuses
        messages.append(oversized_announcement(int(float(args[0]) * 1_000_000)))
        blob_flood = oversized_blob(BLOB_FLOOD_MB * 1_000_000)
    elif mode not in ("junk", "starve"):
        raise SystemExit(f"unknown mode {mode!r}")

    while mode in RACING and not servers:           # the genuine service's name comes with an announcement
        rclpy.spin_once(node, timeout_sec=0.05)
    print("ready", flush=True)                      # publishers and servers exist
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    deadline, next_publish, turn, next_junk = time.monotonic() + seconds, 0.0, 0, 0.0
    while not stop[0] and time.monotonic() < deadline:
        if mode == "starve" and time.monotonic() >= next_junk:
            # the release's size: this file (another network's weights, cut or padded), zeros, a forged manifest
            size = release["size"]
            junk = (evil[:size].ljust(size, b"\0"), bytes(size), hashlib.sha256(evil).digest() * 2)
            blob.publish(FetchWeights.Response(success=True, message="chunk 0 of 1",
                                               data=array.array("B", junk[report["blob_published"] % 3])))
            report["blob_published"] += 1
            next_junk = time.monotonic() + BLOB_JUNK_S
        if time.monotonic() >= next_publish and messages:
            # one message a period, in turn: the topic keeps the last one only (depth 1), so two published back to
            # back would let the second replace the first before a loaded subscriber takes it
            publisher.publish(messages[turn % len(messages)])
            report["published"] += 1
            if mode == "flood":
                blob.publish(blob_flood)
                report["blob_published"] += 1
            turn += 1
            next_publish = time.monotonic() + (FLOOD_REPEAT_S if mode == "flood" else REPEAT_S)
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps(report), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), *sys.argv[3:])
