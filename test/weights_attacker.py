"""The attacker of test_weights_attacks.py: a process of its own on the test's ROS domain that tries to make a
running policy node take weights it should not, or choke on them. Every mode publishes on the trainer's
announcement topic from this process and, where a fetch could follow, serves FetchWeights on the trainer's service
name beside the genuine trainer (whoever answers first wins a fetch). Prints one JSON line of what it did at the end
(after ``seconds``, or on SIGTERM).

    weights_attacker.py untrusted SECONDS FILE META     # FILE announced and served under a key of its own
    weights_attacker.py tampered SECONDS FILE META      # the genuine announcement's key id and signature, FILE's fields
    weights_attacker.py malformed SECONDS               # an empty sha256, and a size of 1 TiB
    weights_attacker.py replay SECONDS ANNOUNCEMENT     # a recorded genuine announcement (JSON), again and again
    weights_attacker.py flood SECONDS MEGABYTES         # raw oversized bytes on the topic; junk for every fetch
    weights_attacker.py junk SECONDS                    # junk for every fetch, nothing published (a fetch race)
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


def main(mode: str, seconds: float, *args: str) -> None:
    rclpy.init()
    node = rclpy.create_node("weights_attacker")
    publisher = node.create_publisher(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, latched(1))
    report = {"mode": mode, "published": 0, "fetch_requests": 0}
    served: dict[tuple[str, int], bytes] = {}
    messages: list = []             # published in turn, one every REPEAT_S (messages, or raw bytes)

    def on_fetch(request, response):
        report["fetch_requests"] += 1
        if mode in ("flood", "junk"):                 # junk of the length asked for, as fast as it can
            response.success, response.data = True, array.array("B", bytes(request.length))
            return response
        data = served.get((request.run_id, int(request.version)))
        if data is None:
            response.success, response.message = False, "not mine"
            return response
        response.success = True
        response.data = array.array("B", data[request.offset:request.offset + request.length])
        return response

    if mode != "replay":          # a replay needs no server: the genuine trainer still holds what it replays
        node.create_service(FetchWeights, topics.FETCH_WEIGHTS, on_fetch)
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
    elif mode != "junk":
        raise SystemExit(f"unknown mode {mode!r}")

    print("ready", flush=True)                      # publishers and server exist
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    deadline, next_publish, turn = time.monotonic() + seconds, 0.0, 0
    while not stop[0] and time.monotonic() < deadline:
        if time.monotonic() >= next_publish and messages:
            # one message a period, in turn: the topic keeps the last one only (depth 1), so two published back to
            # back would let the second replace the first before a loaded subscriber takes it
            publisher.publish(messages[turn % len(messages)])
            turn += 1
            report["published"] += 1
            next_publish = time.monotonic() + (FLOOD_REPEAT_S if mode == "flood" else REPEAT_S)
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps(report), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), *sys.argv[3:])
