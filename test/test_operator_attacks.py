"""Issue 43, items 2 and 3, as the attacker: a second process (``operator_attacker.py``) on the test's ROS domain,
with no trusted key, calls the policy node's ``~/load_policy`` and ``~/accept_older_weights`` — unsigned, signed by
its own key, with the trusted key's id on its own signature, signed for another node, and replaying a genuine
operator's request — while the node plays. Not one action comes from the attacker's policy or from the older
weights it tries to roll back to; every call is refused with its reason and counted. The operator's own signed
requests still work, and a file the operator loads must carry a trusted detached signature."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import torch
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from dynenv_msgs.srv import AcceptOlderWeights, LoadPolicy
from rclpy.parameter import Parameter

from dynenv_ros.agent.checkpoint import policy_bytes
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.ros.operator_gate import sign_message
from dynenv_ros.security.keys import generate_key_pair, key_id, load_private_key, load_public_key
from dynenv_ros.security.operator_requests import sign_file
from policy_node.policy_node import PolicyNode
from operator_helpers import operator_pair, operator_params, signed_call
from ros_harness import finish_attacker, spin_until
from test_policy_node_faults import Feeder, _policy_node
from test_weights_attacks import _weights
from weights_helpers import SignedTrainer, key_pair

ATTACKER = Path(__file__).with_name("operator_attacker.py")
NODE = "/policy_node"


def _policy_file(path: Path, seed: int, updates: int) -> Path:
    """A policy file whose actions carry policy_version ``updates + 1``."""
    torch.manual_seed(seed)
    path.write_bytes(policy_bytes(DynEnvAgent(feature_size=16), {"updates": updates}))
    return path


def _record(request, path: Path) -> Path:
    """What a recorder of the wire has of a signed request: its fields and signature (JSON)."""
    fields = {k: getattr(request, k) for k in request.get_fields_and_field_types() if k != "signature"}
    s = request.signature
    fields["signature"] = {"key_id": s.key_id, "sec": s.stamp.sec, "nanosec": s.stamp.nanosec,
                           "nonce": bytes(s.nonce).hex(), "signature": bytes(s.signature).hex()}
    path.write_text(json.dumps(fields))
    return path


def _attacker(*args: object) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, str(ATTACKER), *map(str, args)], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    assert process.stdout.readline().strip() == "ready"
    return process



def _trusted_id() -> str:
    return key_id(load_public_key(operator_pair()[1]))


def test_load_policy_obeys_only_the_operator_and_the_attacker_never_acts(make_node, executor, tmp_path):
    start = _policy_file(tmp_path / "start.safetensors", 1, 5)              # version 6
    policy = _policy_node(make_node, executor, checkpoint=str(start), **operator_params(allow_unsigned_files=False))
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    assert feeder.act(0)["team_a_0"].policy_version == 6
    operator = make_node("operator")
    executor.add_node(operator)
    private = load_private_key(operator_pair()[0])
    # the operator loads B (version 11), then C (version 21), both signed; the attacker recorded B's request
    genuine = {}
    for name, seed, updates in (("b", 2, 10), ("c", 3, 20)):
        genuine[name] = _policy_file(tmp_path / f"{name}.safetensors", seed, updates)
        sign_file(private, genuine[name])
        request = sign_message(LoadPolicy.Request(checkpoint_path=str(genuine[name])), private, NODE, "load_policy")
        if name == "b":
            recorded = _record(request, tmp_path / "recorded.json")
        client = operator.create_client(LoadPolicy, f"{NODE}/load_policy")
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(request)
        assert spin_until(executor, future.done, 20.0)
        assert future.result().success and future.result().reason == "", future.result().message
    assert feeder.act(1)["team_a_0"].policy_version == 21
    # the attacker's own policy (version 100) placed on the robot, with a .sig of the attacker's key beside it
    evil = _policy_file(tmp_path / "evil.safetensors", 99, 99)
    attacker = _attacker("load", 60, NODE, evil, _trusted_id(), recorded)
    versions, period = [], 2
    try:
        assert spin_until(executor, lambda: policy.counts["operator_refused"] >= 10, 40.0), policy.counts
        for _ in range(10):                                    # the node plays on, with the operator's C
            versions.append(feeder.act(period)["team_a_0"].policy_version)
            period += 1
    finally:
        report = finish_attacker(attacker)
    versions += [feeder.act(p)["team_a_0"].policy_version for p in range(period, period + 3)]
    print(f"attacker: {report}; versions acted: {versions}; counts "
          f"{ {k: v for k, v in policy.counts.items() if k.startswith('operator')} }")
    assert versions.count(100) == 0 and versions.count(11) == 0 and set(versions) == {21}
    assert report["successes"] == 0 and report["answered"] >= 10, report
    reasons = {k for k in report["reasons"]}
    assert reasons == {"unsigned:unsigned", "own_key:untrusted_key", "borrowed_id:bad_signature",
                       "replayed:replayed", "other_node:untrusted_key"}, report
    for reason in ("unsigned", "untrusted_key", "bad_signature", "replayed"):
        assert policy.counts[f"operator_refused_{reason}"] >= 1, policy.counts
    assert policy.counts["operator_requests_accepted"] == 2
    values = policy.diagnostics()
    assert values["operator_services"] == "on"     # every call counted (one may be cut short by the SIGTERM)
    assert report["answered"] <= int(values["operator_refused"]) <= report["calls"], (values, report)
    assert policy.checkpoint_sha256 == hashlib.sha256(genuine["c"].read_bytes()).hexdigest()


def test_a_file_the_operator_loads_needs_a_trusted_detached_signature(make_node, executor, tmp_path):
    """The operator's signed request names a file the attacker could write: without FILE.sig, with one of another
    key, or changed after it was signed, it is refused; the node plays on with what it has."""
    start = _policy_file(tmp_path / "start.safetensors", 1, 5)
    policy = _policy_node(make_node, executor, checkpoint=str(start), **operator_params(allow_unsigned_files=False))
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    private = load_private_key(operator_pair()[0])
    evil = _policy_file(tmp_path / "evil.safetensors", 99, 99)

    def load(path):
        return signed_call(policy, executor, LoadPolicy, f"{NODE}/load_policy",
                           LoadPolicy.Request(checkpoint_path=str(path)))

    reply = load(evil)
    assert (reply.success, reply.reason) == (False, "file_unsigned"), reply.message
    assert reply.message.startswith("kept the current policy: refused (file_unsigned)"), reply.message
    sign_file(Ed25519PrivateKey.generate(), evil)
    assert load(evil).reason == "file_untrusted_key"
    good = _policy_file(tmp_path / "good.safetensors", 2, 10)
    sign_file(private, good)
    good.write_bytes(evil.read_bytes())                      # replaced after the operator signed it
    assert load(good).reason == "file_bad_signature"
    assert load(tmp_path / "missing.safetensors").reason == "load_failed"
    assert feeder.act(0)["team_a_0"].policy_version == 6
    assert [policy.counts[f"operator_refused_file_{r}"] for r in ("unsigned", "untrusted_key", "bad_signature")] \
        == [1, 1, 1]
    _policy_file(good, 2, 10)
    sign_file(private, good)
    reply = load(good)
    assert reply.success and reply.reason == "", reply.message
    assert feeder.act(1)["team_a_0"].policy_version == 11


def test_without_operator_keys_the_services_are_off(make_node, executor, tmp_path):
    private, public = key_pair(tmp_path / "keys")
    policy = make_node(PolicyNode, parameter_overrides=[Parameter(k, value=v) for k, v in {
        "players_per_team": 1, "team": "a", "trusted_weights_keys": [str(public)]}.items()])
    executor.add_node(policy)
    assert policy.load_srv is None and policy.weights.accept_service is None and policy.operator is None
    probe = make_node("probe")
    executor.add_node(probe)
    spin_until(executor, lambda: False, 1.0)
    services = {name for name, _ in probe.get_service_names_and_types()}
    assert f"{NODE}/load_policy" not in services and f"{NODE}/accept_older_weights" not in services
    assert f"{NODE}/get_parameters" in services                 # discovery did see the node's services
    assert policy.diagnostics()["operator_services"] == "off"


def test_accept_older_weights_obeys_only_the_operator_and_no_rollback_acts(make_node, executor, tmp_path):
    """The issue's attack: call ~/accept_older_weights, then replay a recorded older genuine release. Before, 21 of
    22 actions came from the old weights."""
    private, public = key_pair(tmp_path / "keys")
    trainer = SignedTrainer(make_node, executor, private)
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)])
    feeder = Feeder(make_node, executor)
    feeder.wait_for()
    data_1, meta = _weights(1)
    first = trainer.release(data_1, 1, meta)
    assert spin_until(executor, lambda: policy.policy_version == 1, 20.0), policy.counts
    data_2, meta = _weights(2)
    trainer.release(data_2, 2, meta)
    assert spin_until(executor, lambda: policy.policy_version == 2, 20.0), policy.counts
    # a genuine operator request, signed for another robot's node, recorded on the wire
    other = sign_message(AcceptOlderWeights.Request(), load_private_key(operator_pair()[0]),
                         "/robot_2/policy_node", "accept_older_weights")
    recorded = _record(other, tmp_path / "recorded.json")
    announcement = tmp_path / "version_1.json"
    announcement.write_text(json.dumps({**dataclasses.asdict(first), "signature": first.signature.hex()}))
    attacker = _attacker("accept", 60, NODE, _trusted_id(), recorded)
    replayer = subprocess.Popen([sys.executable, str(Path(__file__).with_name("weights_attacker.py")), "replay",
                                 "60", announcement], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    versions, period = [], 0
    try:
        assert spin_until(executor, lambda: policy.counts["operator_refused"] >= 8
                          and policy.counts["weights_refused_rollback"] >= 3, 40.0), policy.counts
        for _ in range(10):
            versions.append(feeder.act(period)["team_a_0"].policy_version)
            period += 1
    finally:
        report = finish_attacker(attacker)
        if replayer.poll() is None:
            replayer.terminate()
        replayer.communicate(timeout=30)
    print(f"attacker: {report}; versions acted: {versions}")
    assert versions.count(1) == 0 and set(versions) == {2}
    assert policy.weights_acting == ("run", 2) and not policy.weights.order.older_allowed
    assert report["successes"] == 0 and report["answered"] >= 8, report
    assert set(report["reasons"]) == {"unsigned:unsigned", "own_key:untrusted_key", "borrowed_id:bad_signature",
                                      "replayed:bad_signature"}, report
    # the operator's own signed call naming version 1 still opens the door once: the refused version 1 is taken
    reply = signed_call(policy, executor, AcceptOlderWeights, f"{NODE}/accept_older_weights",
                        AcceptOlderWeights.Request(run_id="run", version=1))
    assert reply.success and "version 1 of run run will be accepted once" in reply.message, reply.message
    assert spin_until(executor, lambda: policy.weights_acting == ("run", 1), 20.0), policy.counts


def test_dynenv_keys_call_exits_0_3_or_1_and_sign_request_signs_once(make_node, executor, tmp_path):
    """docs/ros_graph.md, "Who may command a node": ``dynenv-keys call`` (a process of its own, as an operator runs
    it) exits 0 when the service says success, 3 when it refuses (the reply says why), 1 when the service does not
    appear; ``sign-request`` prints a signed request as YAML, obeyed once (a second send is ``replayed``)."""
    from dynenv_ros.ros.service_call import request_from_yaml
    _, public = key_pair(tmp_path / "keys")
    own, _ = generate_key_pair(tmp_path / "attacker", "operator")
    policy = _policy_node(make_node, executor, trusted_weights_keys=[str(public)], allow_unsigned_files=False)
    unsigned = _policy_file(tmp_path / "unsigned.safetensors", 3, 30)

    def keys(*args: object) -> tuple[int, str]:
        process = subprocess.Popen([sys.executable, "-m", "dynenv_ros.ros.keys_cli", *map(str, args)],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert spin_until(executor, lambda: process.poll() is not None, 90.0)
        return process.returncode, process.communicate()[0]

    operator_key = ("--key", operator_pair()[0])
    named = "{run_id: run, version: 1}"
    code, said = keys("call", f"{NODE}/accept_older_weights", "dynenv_msgs/srv/AcceptOlderWeights", named,
                      *operator_key)
    assert code == 0 and "success: true" in said, said
    code, said = keys("call", f"{NODE}/load_policy", "dynenv_msgs/srv/LoadPolicy",
                      f"{{checkpoint_path: {unsigned}}}", *operator_key)
    assert code == 3 and "reason: file_unsigned" in said, said
    code, said = keys("call", f"{NODE}/accept_older_weights", "dynenv_msgs/srv/AcceptOlderWeights", named, "--key",
                      own)
    assert code == 3 and "reason: untrusted_key" in said, said
    code, said = keys("call", "/nobody/accept_older_weights", "dynenv_msgs/srv/AcceptOlderWeights", "--timeout", 2,
                      *operator_key)
    assert code == 1 and "not available" in said, said
    code, said = keys("sign-request", f"{NODE}/accept_older_weights", "dynenv_msgs/srv/AcceptOlderWeights", named,
                      *operator_key)
    assert code == 0, said
    kind, request = request_from_yaml("dynenv_msgs/srv/AcceptOlderWeights", said.strip().splitlines()[-1])
    caller = make_node("ros2cli")
    executor.add_node(caller)
    client = caller.create_client(kind, f"{NODE}/accept_older_weights")
    assert client.wait_for_service(timeout_sec=10.0)
    replies = []
    for _ in range(2):
        future = client.call_async(request)
        assert spin_until(executor, future.done, 20.0)
        replies.append(future.result())
    assert replies[0].success and (replies[1].success, replies[1].reason) == (False, "replayed"), replies
    # accepted: the two calls of accept_older_weights and the load_policy request (its file then refused)
    assert policy.counts["operator_requests_accepted"] == 3 and policy.counts["operator_refused_untrusted_key"] == 1
    assert policy.counts["operator_refused_file_unsigned"] == 1 and policy.counts["operator_refused_replayed"] == 1


def test_refusals_are_each_counted_and_logged_at_most_once_per_5_s(make_node, executor, capfd):
    """docs/ros_graph.md, "Who may command a node": a WARN line for a refusal, at most one per 5 s for the node's
    operator services together (a flood of unsigned calls is counted, not a line each). 20 unsigned requests to
    both services, then one more after the 5 s have passed: one more line."""
    policy = _policy_node(make_node, executor)
    capfd.readouterr()

    def lines() -> list[str]:
        return [line for line in capfd.readouterr().err.splitlines() if "refused: unsigned" in line]

    started = time.monotonic()
    for number in range(20):
        service, kind = (("load_policy", LoadPolicy), ("accept_older_weights", AcceptOlderWeights))[number % 2]
        assert policy.operator.refusal(service, kind.Request())[0] == "unsigned"
    elapsed = time.monotonic() - started
    first = lines()
    assert policy.counts["operator_refused_unsigned"] == 20 and "WARN" in first[0], first
    assert 1 <= len(first) <= 1 + elapsed // 5.0, (elapsed, first)        # at most one per 5 s
    time.sleep(5.2)                                                        # past the last line's 5 s
    policy.operator.refusal("load_policy", LoadPolicy.Request())
    assert len(lines()) == 1 and policy.counts["operator_refused_unsigned"] == 21
