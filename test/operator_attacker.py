"""The attacker of test_operator_attacks.py (issue 43): a process of its own on the test's ROS domain, with no
trusted key, that calls a policy node's operator services to make it act with a policy of its choosing. Each round
it sends every request of its mode once; at the end (after ``seconds``, or on SIGTERM) it prints one JSON line:
calls answered, successes, and the replies' reasons.

    operator_attacker.py load SECONDS NODE FILE TRUSTED_KEY_ID RECORDED
        # LoadPolicy of FILE (a policy the attacker placed on the robot, with a .sig of its own key beside it):
        # unsigned; signed by its own key; its own signature under the trusted key id; signed for another node by
        # its own key; and RECORDED (JSON: a genuine operator's signed request seen on the wire), replayed as is
    operator_attacker.py accept SECONDS NODE TRUSTED_KEY_ID RECORDED
        # AcceptOlderWeights: unsigned, own key, own signature under the trusted key id, and RECORDED (a genuine
        # request signed for another robot's node) replayed here
"""
from __future__ import annotations

import json
import signal
import sys
import time
from collections import Counter
from pathlib import Path

import rclpy
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from dynenv_msgs.srv import AcceptOlderWeights, LoadPolicy

from dynenv_ros.ros.operator_gate import fill_signature, sign_message
from dynenv_ros.security.operator_requests import Signature, sign_file

ROUND_PAUSE_S = 0.3
ANSWER_S = 3.0


def recorded(path: str, kind) -> object:
    """A request exactly as recorded (fields and signature)."""
    fields = json.loads(Path(path).read_text())
    signature = fields.pop("signature")
    request = kind.Request(**fields)
    fill_signature(request.signature, Signature(signature["key_id"], signature["sec"], signature["nanosec"],
                                                bytes.fromhex(signature["nonce"]),
                                                bytes.fromhex(signature["signature"])))
    return request


def forged_requests(mode: str, node_name: str, args: list[str], own: Ed25519PrivateKey):
    """(label, service class, request maker) of the mode: makers sign afresh each round."""
    if mode == "load":
        path, trusted_id, recording = args
        sign_file(own, path)                              # FILE.sig, by the attacker's own key
        kind = LoadPolicy

        def plain():
            return LoadPolicy.Request(checkpoint_path=path)
    else:
        trusted_id, recording = args
        kind = AcceptOlderWeights

        def plain():
            return AcceptOlderWeights.Request()

    def own_key():
        return sign_message(plain(), own, node_name, service)

    def borrowed_id():                                    # the trusted key's id on the attacker's own signature
        request = own_key()
        request.signature.key_id = trusted_id
        return request

    def other_node():
        return sign_message(plain(), own, "/some_other/policy_node", service)

    service = "load_policy" if mode == "load" else "accept_older_weights"
    makers = [("unsigned", plain), ("own_key", own_key), ("borrowed_id", borrowed_id),
              ("replayed", lambda: recorded(recording, kind))]
    if mode == "load":
        makers.append(("other_node", other_node))
    return f"{node_name}/{service}", kind, makers


def main(mode: str, seconds: float, node_name: str, *args: str) -> None:
    rclpy.init()
    node = rclpy.create_node("operator_attacker")
    own = Ed25519PrivateKey.generate()
    service, kind, makers = forged_requests(mode, node_name, list(args), own)
    client = node.create_client(kind, service)
    report = {"mode": mode, "calls": 0, "answered": 0, "successes": 0, "reasons": Counter()}
    print("ready", flush=True)
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    deadline = time.monotonic() + seconds
    client.wait_for_service(timeout_sec=min(seconds, 20.0))
    while not stop[0] and time.monotonic() < deadline:
        for label, make in makers:
            future = client.call_async(make())
            report["calls"] += 1
            rclpy.spin_until_future_complete(node, future, timeout_sec=ANSWER_S)
            if future.done():
                response = future.result()
                report["answered"] += 1
                report["successes"] += int(response.success)
                report["reasons"][f"{label}:{response.reason}"] += 1
            else:
                client.remove_pending_request(future)
            if stop[0]:
                break
        rclpy.spin_once(node, timeout_sec=ROUND_PAUSE_S)
    print(json.dumps(report), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]), *sys.argv[3:])
