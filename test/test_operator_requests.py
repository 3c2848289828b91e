"""Issue 43, signed operator requests and policy files, without ROS (``security/operator_requests.py``): a request
verifies only for the fields, node, service, time and nonce it was signed for, once; every other case is refused
with its reason."""
from __future__ import annotations

import dataclasses
import json

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from dynenv_ros.security.keys import key_id
from dynenv_ros.security.operator_requests import (RequestVerifier, Signature, canonical_bytes, sign_file,
                                                   sign_request, signature_path, verify_file)
from dynenv_ros.security.weights_signing import Refused

NOW = 1_800_000_000 * 10**9                 # a fixed wall-clock time (ns)
NODE = "/policy_node"
FIELDS = {"checkpoint_path": "/robot/policies/new.onnx", "runtime": "onnxruntime"}
NONCE = bytes(range(16))


@pytest.fixture()
def operator() -> Ed25519PrivateKey:
    return Ed25519PrivateKey.generate()


def _verifier(operator: Ed25519PrivateKey, node: str = NODE) -> RequestVerifier:
    return RequestVerifier({key_id(operator.public_key()): operator.public_key()}, node)


def _reason(verifier: RequestVerifier, service: str, fields: dict, signature: Signature, now: int = NOW) -> str:
    with pytest.raises(Refused) as refused:
        verifier.check(service, fields, signature, now)
    return refused.value.reason


def test_a_signed_request_verifies_once_for_its_node_service_and_fields(operator):
    signature = sign_request(operator, NODE, "load_policy", FIELDS, NOW, NONCE)
    assert signature.key_id == key_id(operator.public_key()) and signature.nonce == NONCE
    assert (signature.stamp_sec, signature.stamp_nanosec) == (1_800_000_000, 0)
    assert len(signature.signature) == 64
    verifier = _verifier(operator)
    verifier.check("load_policy", FIELDS, signature, NOW + 29 * 10**9)       # 29 s later: inside the window
    assert _reason(verifier, "load_policy", FIELDS, signature) == "replayed"   # the same request again


def test_each_covered_field_tampered_is_a_bad_signature(operator):
    signature = sign_request(operator, NODE, "load_policy", FIELDS, NOW, NONCE)
    verifier = _verifier(operator)
    tampered_fields = [{**FIELDS, "checkpoint_path": "/tmp/evil.onnx"}, {**FIELDS, "runtime": "torch"},
                       {"checkpoint_path": FIELDS["checkpoint_path"]},                      # a field dropped
                       {**FIELDS, "extra": "x"}]                                            # a field added
    for fields in tampered_fields:
        assert _reason(verifier, "load_policy", fields, signature) == "bad_signature", fields
    tampered_signatures = [dataclasses.replace(signature, stamp_sec=signature.stamp_sec + 1),
                           dataclasses.replace(signature, stamp_nanosec=1),
                           dataclasses.replace(signature, nonce=bytes(16)),
                           dataclasses.replace(signature, signature=bytes(64))]
    for forged in tampered_signatures:
        assert _reason(verifier, "load_policy", FIELDS, forged) == "bad_signature", forged
    assert _reason(verifier, "accept_older_weights", FIELDS, signature) == "bad_signature"   # another service
    # none of the refusals spent the nonce: the genuine request still goes through, once
    verifier.check("load_policy", FIELDS, signature, NOW)


def test_a_request_signed_for_another_node_does_not_verify_here(operator):
    for_other_robot = sign_request(operator, "/robot_2/policy_node", "load_policy", FIELDS, NOW, NONCE)
    assert _reason(_verifier(operator), "load_policy", FIELDS, for_other_robot) == "bad_signature"
    _verifier(operator, "/robot_2/policy_node").check("load_policy", FIELDS, for_other_robot, NOW)
    with pytest.raises(ValueError, match="fully qualified"):
        sign_request(operator, "policy_node", "load_policy", FIELDS, NOW)


def test_typed_values_are_signed_as_their_type(operator):
    """A string "1" is not the integer 1, nor a bool; moving characters between fields changes the bytes."""
    base = canonical_bytes(NODE, "x", {"a": "1"}, Signature())
    assert base != canonical_bytes(NODE, "x", {"a": 1}, Signature())
    assert canonical_bytes(NODE, "x", {"a": 1}, Signature()) != canonical_bytes(NODE, "x", {"a": True}, Signature())
    assert canonical_bytes(NODE, "x", {"a": "bc", "b": ""}, Signature()) != \
        canonical_bytes(NODE, "x", {"a": "b", "b": "c"}, Signature())
    assert canonical_bytes("/a", "bc", {}, Signature()) != canonical_bytes("/ab", "c", {}, Signature())
    with pytest.raises(ValueError, match="cannot be signed"):
        canonical_bytes(NODE, "x", {"a": [1, 2]}, Signature())
    with pytest.raises(ValueError, match="only finite"):
        canonical_bytes(NODE, "x", {"a": float("nan")}, Signature())


def test_stale_and_future_requests_are_refused(operator):
    verifier = _verifier(operator)
    old = sign_request(operator, NODE, "accept_older_weights", {}, NOW - 31 * 10**9, NONCE)
    assert _reason(verifier, "accept_older_weights", {}, old) == "stale"
    ahead = sign_request(operator, NODE, "accept_older_weights", {}, NOW + 31 * 10**9, NONCE)
    assert _reason(verifier, "accept_older_weights", {}, ahead) == "stale"
    with pytest.raises(Refused, match="signed 31.0 s before this node's clock"):
        verifier.check("accept_older_weights", {}, old, NOW)


def test_a_replay_stays_refused_after_its_nonce_is_forgotten(operator):
    verifier = _verifier(operator)
    signature = sign_request(operator, NODE, "accept_older_weights", {}, NOW, NONCE)
    verifier.check("accept_older_weights", {}, signature, NOW)
    assert _reason(verifier, "accept_older_weights", {}, signature, NOW + 10**9) == "replayed"
    # 31 s on, the nonce has left the guard, and the time refuses the replay
    later = NOW + 31 * 10**9
    assert _reason(verifier, "accept_older_weights", {}, signature, later) == "stale"
    verifier.check("accept_older_weights", {}, sign_request(operator, NODE, "accept_older_weights", {}, later), later)
    assert len(verifier._seen) == 1 and NONCE not in verifier._seen       # the next accepted request pruned it


def test_unsigned_untrusted_and_malformed_requests_are_refused(operator):
    verifier = _verifier(operator)
    assert _reason(verifier, "load_policy", FIELDS, Signature()) == "unsigned"
    stranger = Ed25519PrivateKey.generate()
    own_key = sign_request(stranger, NODE, "load_policy", FIELDS, NOW, NONCE)
    assert _reason(verifier, "load_policy", FIELDS, own_key) == "untrusted_key"
    genuine = sign_request(operator, NODE, "load_policy", FIELDS, NOW, NONCE)
    for malformed in (dataclasses.replace(genuine, nonce=b"short"), dataclasses.replace(genuine, signature=b"x"),
                      dataclasses.replace(genuine, key_id="not-a-key-id!!!!"),
                      dataclasses.replace(genuine, stamp_nanosec=2_000_000_000)):
        assert _reason(verifier, "load_policy", FIELDS, malformed) == "malformed", malformed
    with pytest.raises(Refused, match=r"stamp -1 s 0 ns \(want sec >= 0"):         # the message names the field
        verifier.check("load_policy", FIELDS, dataclasses.replace(genuine, stamp_sec=-1), NOW)
    # the trusted key's id on a stranger's signature
    borrowed = dataclasses.replace(own_key, key_id=genuine.key_id)
    assert _reason(verifier, "load_policy", FIELDS, borrowed) == "bad_signature"


def test_the_replay_guard_is_bounded(operator):
    verifier = RequestVerifier({key_id(operator.public_key()): operator.public_key()}, NODE, max_nonces=3)
    for n in range(5):
        verifier.check("accept_older_weights", {}, sign_request(operator, NODE, "accept_older_weights", {}, NOW,
                                                                bytes([n]) * 16), NOW)
    assert list(verifier._seen) == [bytes([2]) * 16, bytes([3]) * 16, bytes([4]) * 16]
    with pytest.raises(ValueError):
        RequestVerifier({}, NODE, window_s=0)


def test_a_detached_file_signature_verifies_only_the_bytes_it_signed(operator, tmp_path):
    trusted = {key_id(operator.public_key()): operator.public_key()}
    policy = tmp_path / "new.onnx"
    policy.write_bytes(b"policy bytes")
    with pytest.raises(Refused) as refused:
        verify_file(policy.read_bytes(), signature_path(policy), trusted)
    assert refused.value.reason == "file_unsigned"
    written = sign_file(operator, policy)
    assert written == tmp_path / "new.onnx.sig" and signature_path(policy) == written
    fields = json.loads(written.read_text())
    assert sorted(fields) == ["key_id", "sha256", "signature"]
    assert fields["sha256"] == "5c03b910b231b823c172f571b37df4bfac46f83a5691fe724bcbe6485a76418f"   # of b"policy bytes"
    assert fields["key_id"] == key_id(operator.public_key()) and len(bytes.fromhex(fields["signature"])) == 64
    assert verify_file(b"policy bytes", written, trusted) == key_id(operator.public_key())
    cases = [(b"policy bytes!", written, trusted, "file_bad_signature"),                # the file changed
             (b"policy bytes", written, {}, "file_untrusted_key")]
    for data, sig, keys, reason in cases:
        with pytest.raises(Refused) as refused:
            verify_file(data, sig, keys)
        assert refused.value.reason == reason
    # a stranger re-signing the altered file under the trusted key's id
    stranger = Ed25519PrivateKey.generate()
    policy.write_bytes(b"evil bytes")
    sign_file(stranger, policy)
    forged = json.loads(written.read_text())
    forged["key_id"] = key_id(operator.public_key())
    written.write_text(json.dumps(forged))
    for text, reason in ((json.dumps(forged), "file_bad_signature"), ("not json", "file_bad_signature"),
                         (json.dumps({"key_id": 1}), "file_bad_signature"), ("x" * 5000, "file_bad_signature")):
        written.write_text(text)
        with pytest.raises(Refused) as refused:
            verify_file(b"evil bytes", written, trusted)
        assert refused.value.reason == reason, text
