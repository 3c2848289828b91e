"""Signed weights without ROS (issue 27 item 1): key files (``security.keys``), the canonical encoding and its
signature (``security.weights_signing``), the signed source (``security.weights_source``), the order of releases
(``security.weights_order``), the download from chunks anyone may send (``security.weights_download``) and the
``dynenv-keys`` command."""
from __future__ import annotations

import dataclasses
import hashlib
import os
import stat

import pytest
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ec import SECP256R1, generate_private_key
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from dynenv_ros.ros import keys_cli
from dynenv_ros.security import keys
from dynenv_ros.security.weights_download import ChunkRefused, Download, SampleRefused, manifest
from dynenv_ros.security.weights_order import ReleaseOrder
from dynenv_ros.security.weights_signing import Announcement, Refused, canonical_bytes, check_fields, sign, verify
from dynenv_ros.security.weights_source import Source, fetch_service_name, source_of, with_source

DATA = bytes(range(256)) * 40


def _announcement(**fields) -> Announcement:
    values = dict(run_id="run_a", version=3, size=len(DATA), sha256=hashlib.sha256(DATA).hexdigest(),
                  metadata_json='{"config": {"feature_size": 64}}', stamp_sec=1_700_000_000, stamp_nanosec=5)
    values.update(fields)
    return Announcement(**values)


# -- keys ----------------------------------------------------------------------------------------------------------
def test_a_generated_pair_loads_and_the_private_key_is_the_owners_only(tmp_path):
    private, public = keys.generate_key_pair(tmp_path / "keys")
    assert (private.name, public.name) == ("trainer.key", "trainer.pub")
    assert stat.S_IMODE(private.stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "keys").stat().st_mode) == 0o700
    secret, trusted = keys.load_private_key(private), keys.load_public_key(public)
    raw = trusted.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    assert keys.key_id(trusted) == hashlib.sha256(raw).hexdigest()[:16] == keys.key_id(secret.public_key())
    assert keys.load_trusted_keys([tmp_path / "keys"]).keys() == {keys.key_id(trusted)}   # a directory of .pub
    assert keys.load_trusted_keys([public]).keys() == {keys.key_id(trusted)}


def test_key_files_are_never_overwritten(tmp_path):
    private, public = keys.generate_key_pair(tmp_path)
    before = private.read_bytes(), public.read_bytes()
    with pytest.raises(keys.KeyFileError, match="exists: refusing to overwrite"):
        keys.generate_key_pair(tmp_path)
    assert (private.read_bytes(), public.read_bytes()) == before
    public.unlink()
    with pytest.raises(keys.KeyFileError, match="trainer.key exists"):     # half a pair is not completed either
        keys.generate_key_pair(tmp_path)


@pytest.mark.parametrize("case, message", [
    ("missing", "does not exist (make a pair with `dynenv-keys generate DIR`)"),
    ("readable", "has mode 0644: a private key must be readable by its owner only (chmod 600"),
    ("corrupt", "is not a PEM private key"),
    ("other kind", "not an Ed25519 private key"),
    ("directory", "is not a regular file"),
    ("huge", "not an Ed25519 key file"),
])
def test_a_bad_private_key_file_is_one_line_of_error(tmp_path, case, message):
    path = tmp_path / "trainer.key"
    if case == "readable":
        keys.generate_key_pair(tmp_path)
        os.chmod(path, 0o644)
    elif case == "corrupt":
        path.write_bytes(b"-----BEGIN PRIVATE KEY-----\nnot base64\n-----END PRIVATE KEY-----\n")
    elif case == "other kind":
        path.write_bytes(generate_private_key(SECP256R1()).private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    elif case == "directory":
        path.mkdir()
    elif case == "huge":
        path.write_bytes(b"x" * (keys.MAX_KEY_FILE_BYTES + 1))
    if path.is_file():
        os.chmod(path, 0o644 if case == "readable" else 0o600)
    with pytest.raises(keys.KeyFileError) as refused:
        keys.load_private_key(path)
    assert message in str(refused.value) and "\n" not in str(refused.value)


def test_bad_public_keys_and_empty_key_directories_are_refused(tmp_path):
    (tmp_path / "bad.pub").write_text("garbage\n")
    with pytest.raises(keys.KeyFileError, match="is not a PEM public key"):
        keys.load_trusted_keys([tmp_path / "bad.pub"])
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(keys.KeyFileError, match="holds no .pub file"):
        keys.load_trusted_keys([empty])
    _, public = keys.generate_key_pair(tmp_path / "pair")
    with pytest.raises(keys.KeyFileError, match="not an Ed25519 public key"):
        keys.load_public_key(_write_ec_public(tmp_path / "ec.pub"))
    assert len(keys.load_trusted_keys([public, public])) == 1


def _write_ec_public(path):
    path.write_bytes(generate_private_key(SECP256R1()).public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo))
    return path


def test_the_default_key_directory_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("DYNENV_KEYS_DIR", str(tmp_path / "k"))
    assert keys.default_keys_dir() == tmp_path / "k"
    monkeypatch.delenv("DYNENV_KEYS_DIR")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert keys.default_keys_dir() == tmp_path / ".config" / "dynenv_ros" / "keys"


# -- the canonical encoding and the signature ------------------------------------------------------------------------
def test_a_signature_covers_every_field():
    key = Ed25519PrivateKey.generate()
    trusted = {keys.key_id(key.public_key()): key.public_key()}
    signed = sign(_announcement(), key)
    verify(signed, trusted)
    changes = {"run_id": "run_b", "version": 4, "size": len(DATA) + 1, "sha256": "0" * 64,
               "metadata_json": '{"config": {"feature_size": 65}}', "stamp_sec": 1_700_000_001, "stamp_nanosec": 6,
               "frame_id": "map"}
    for name, value in changes.items():
        with pytest.raises(Refused) as refused:
            verify(dataclasses.replace(signed, **{name: value}), trusted)
        assert refused.value.reason == "bad_signature", name
    flipped = bytes([signed.signature[0] ^ 1]) + signed.signature[1:]
    with pytest.raises(Refused, match="forged or altered"):
        verify(dataclasses.replace(signed, signature=flipped), trusted)
    with pytest.raises(Refused, match="64"):
        verify(dataclasses.replace(signed, signature=signed.signature[:63]), trusted)


def test_only_trusted_keys_verify():
    key, other = Ed25519PrivateKey.generate(), Ed25519PrivateKey.generate()
    trusted = {keys.key_id(key.public_key()): key.public_key()}
    with pytest.raises(Refused) as refused:
        verify(sign(_announcement(), other), trusted)
    assert refused.value.reason == "untrusted_key"
    # the trusted key's id on another key's signature: the signature does not match
    forged = dataclasses.replace(sign(_announcement(), other), key_id=keys.key_id(key.public_key()))
    with pytest.raises(Refused) as refused:
        verify(forged, trusted)
    assert refused.value.reason == "bad_signature"


def test_the_encoding_is_unambiguous_and_fixed():
    a = _announcement(run_id="ab", frame_id="c")
    b = _announcement(run_id="a", frame_id="bc")               # the same characters, split elsewhere
    assert canonical_bytes(a) != canonical_bytes(b)
    assert canonical_bytes(_announcement(metadata_json="{}", sha256="a")) != canonical_bytes(
        _announcement(metadata_json="{}a", sha256=""))
    # pinned: a change of the encoding breaks every deployed trainer's signatures (bump DOMAIN's /1 instead)
    assert hashlib.sha256(canonical_bytes(_announcement())).hexdigest()[:16] == "73bdd5f3b8eaf064"


@pytest.mark.parametrize("fields, reason", [
    ({"sha256": ""}, "empty_sha256"),
    ({"sha256": "A" * 64}, "malformed"),
    ({"sha256": "0" * 63}, "malformed"),
    ({"size": 1_000_001}, "oversized"),
    ({"size": 0}, "malformed"),
    ({"run_id": ""}, "malformed"),
    ({"version": 0}, "malformed"),
    ({"stamp_nanosec": 1_000_000_000}, "malformed"),
])
def test_fields_are_checked_before_any_fetch(fields, reason):
    with pytest.raises(Refused) as refused:
        check_fields(_announcement(**fields), max_bytes=1_000_000)
    assert refused.value.reason == reason
    check_fields(_announcement(), max_bytes=len(DATA))


# -- the order of releases -----------------------------------------------------------------------------------------
def test_only_newer_releases_pass_and_the_older_one_an_operator_names_once(tmp_path):
    order = ReleaseOrder()
    order.check(_announcement(version=3))                         # nothing acting yet: any release
    order.accept(_announcement(version=3))
    assert order.is_duplicate(_announcement(version=3))
    for older in (_announcement(version=3, sha256="1" * 64), _announcement(version=2)):
        with pytest.raises(Refused) as refused:
            order.check(older)
        assert refused.value.reason == "rollback"
    order.check(_announcement(version=4))
    # another run: only a later signed stamp
    with pytest.raises(Refused) as refused:
        order.check(_announcement(run_id="run_b", version=99, stamp_sec=1_699_999_999))
    assert refused.value.reason == "older_run"
    order.check(_announcement(run_id="run_b", version=1, stamp_sec=1_700_000_001))
    order.allow_older_once("run_a", 1)                             # the operator names version 1 of run_a
    for other in (_announcement(version=2), _announcement(run_id="run_c", version=1, stamp_sec=1_600_000_000)):
        with pytest.raises(Refused):                               # no other older release passes, named or not
            order.check(other)
    order.check(_announcement(version=1))                          # the named one, once
    with pytest.raises(Refused):
        order.check(_announcement(version=1))
    order.allow_older_once("run_a", 2)
    order.check(_announcement(version=9))                          # a newer one does not use the allowance
    assert order.older_allowed == ("run_a", 2)


def test_the_high_water_mark_survives_a_restart_in_its_state_file(tmp_path):
    state = tmp_path / "state" / "weights.json"
    ReleaseOrder(state).accept(_announcement(version=7))
    restarted = ReleaseOrder(state)
    with pytest.raises(Refused, match="not newer than version 7"):
        restarted.check(_announcement(version=6))
    state.write_text("{not json")
    with pytest.raises(ValueError, match="cannot be read.*remove it"):
        ReleaseOrder(state)


# -- the signed source -----------------------------------------------------------------------------------------------
KEY_ID = "0123456789abcdef"


def _sourced(**source) -> Announcement:
    fields = dict(node="/trainer_node", fetch_service=fetch_service_name("/trainer/fetch_weights", KEY_ID),
                  blob_topic="/trainer/weights_blob", manifest_sha256=hashlib.sha256(manifest(DATA)).hexdigest())
    fields.update(source)
    return _announcement(key_id=KEY_ID, metadata_json=with_source('{"config": {"feature_size": 64}}',
                                                                  Source(**fields)))


def test_the_source_names_the_trainer_and_a_service_that_carries_the_key_id():
    source = source_of(_sourced())
    assert source.node == "/trainer_node" and source.fetch_service == "/trainer/fetch_weights_0123456789abcdef"
    assert source_of(_sourced(blob_topic="")).blob_topic == ""               # a trainer that publishes no blob
    with pytest.raises(Refused) as old:                                          # a trainer from before issue 43
        source_of(_announcement(key_id=KEY_ID))
    assert old.value.reason == "no_source" and "names no source" in str(old.value)
    for bad in ({"fetch_service": "/trainer/fetch_weights"}, {"fetch_service": "/trainer/fetch_weights_fedcba9876543210"},
                {"node": "trainer_node"}, {"node": ""}, {"blob_topic": "/a b"}, {"manifest_sha256": "0" * 63}):
        with pytest.raises(Refused) as refused:
            source_of(_sourced(**bad))
        assert refused.value.reason == "bad_source", bad
    with pytest.raises(Refused) as missing:
        source_of(_announcement(key_id=KEY_ID, metadata_json='{"source": {"node": "/t"}}'))
    assert missing.value.reason == "bad_source"


# -- the download --------------------------------------------------------------------------------------------------
NOISE = b"".join(hashlib.sha256(i.to_bytes(2, "big")).digest() for i in range(320))    # 10,240 bytes, no repeats


def test_a_download_by_offset_checks_each_chunk_it_can_and_the_whole_file():
    download = Download(len(NOISE), hashlib.sha256(NOISE).hexdigest(), chunk_bytes=4096)
    assert len(download.buffer) == len(NOISE) and download.chunks == 3          # exactly the announced size, no more
    while not download.complete:
        offset, length = download.next_range()
        with pytest.raises(ChunkRefused):
            download.add(offset, NOISE[offset:offset + length] + b"x")     # longer than asked
        with pytest.raises(ChunkRefused):
            download.add(offset + 1, NOISE[offset + 1:offset + 1 + length])
        download.add(offset, NOISE[offset:offset + length])
    assert download.finish() == NOISE
    # one chunk: its digest is the file's, signed, so junk is refused as it arrives
    junk = Download(len(NOISE), hashlib.sha256(NOISE).hexdigest(), chunk_bytes=len(NOISE))
    with pytest.raises(Refused) as refused:
        junk.add(0, bytes(len(NOISE)))
    assert refused.value.reason == "hash_mismatch" and not junk.complete
    # several chunks and no manifest: the junk chunk is found with the whole file, and only it is dropped
    partly = Download(len(NOISE), hashlib.sha256(NOISE).hexdigest(), chunk_bytes=4096)
    partly.add(0, NOISE[:4096])
    partly.add(4096, bytes(4096))
    partly.add(8192, NOISE[8192:])
    with pytest.raises(Refused) as refused:
        partly.finish()
    assert refused.value.reason == "hash_mismatch" and partly.next_range() == (0, 4096) and partly.dropped == 3


def test_blob_samples_are_placed_by_their_bytes_and_junk_displaces_nothing():
    chunks = [NOISE[i:i + 4096] for i in range(0, len(NOISE), 4096)]
    digest = hashlib.sha256(manifest(NOISE, 4096)).hexdigest()
    download = Download(len(NOISE), hashlib.sha256(NOISE).hexdigest(), digest, chunk_bytes=4096)
    for sample, reason in ((chunks[0], "unverifiable"), (bytes(5000), "oversized")):
        with pytest.raises(SampleRefused) as refused:
            download.offer(sample)                                    # before the manifest: nothing to check against
        assert refused.value.reason == reason
    with pytest.raises(SampleRefused):
        download.offer(manifest(NOISE[::-1], 4096))                     # a manifest, not the signed one
    assert download.offer(manifest(NOISE, 4096)) == "manifest"
    # junk of a chunk's length, another release's chunk: refused, the buffer untouched; the genuine chunks land
    for junk in (bytes(4096), chunks[1][::-1], NOISE[1:4097]):
        with pytest.raises(SampleRefused) as refused:
            download.offer(junk)
        assert refused.value.reason == "unmatched"
    assert download.buffer == bytearray(len(NOISE))
    assert download.offer(chunks[2]) == "chunk" and download.offer(chunks[2]) == "duplicate"
    assert download.offer(chunks[0]) == "chunk" and not download.complete
    # the fetch service fills the rest; a junk answer is now refused at once (the manifest gives its digest)
    assert download.next_range() == (4096, 4096)
    with pytest.raises(Refused):
        download.add(4096, bytes(4096))
    download.add(4096, chunks[1])
    assert download.complete and download.finish() == NOISE
    # equal chunks have one digest: one sample fills them all (DATA repeats every 256 bytes)
    periodic = Download(len(DATA), hashlib.sha256(DATA).hexdigest(), hashlib.sha256(manifest(DATA, 4096)).hexdigest(),
                        chunk_bytes=4096)
    periodic.offer(manifest(DATA, 4096))
    assert periodic.offer(DATA[:4096]) == "chunk" and periodic.verified == 2


def test_the_manifest_drops_fetched_junk_and_keeps_genuine_chunks():
    digest = hashlib.sha256(manifest(NOISE, 4096)).hexdigest()
    download = Download(len(NOISE), hashlib.sha256(NOISE).hexdigest(), digest, chunk_bytes=4096)
    download.add(0, NOISE[:4096])                                       # unverified: no manifest yet
    download.add(4096, bytes(4096))                                    # junk from a faster server
    assert download.offer(manifest(NOISE, 4096)) == "manifest"
    assert download.dropped == 1 and download.verified == 1 and download.next_range() == (4096, 4096)


# -- dynenv-keys ---------------------------------------------------------------------------------------------------
def test_dynenv_keys_generates_shows_and_refuses(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DYNENV_KEYS_DIR", str(tmp_path / "default"))
    assert keys_cli.main(["generate"]) == 0
    out = capsys.readouterr().out
    key_id = keys.key_id(keys.load_public_key(tmp_path / "default" / "trainer.pub"))
    assert key_id in out and "0600" in out
    assert keys_cli.main(["show", str(tmp_path / "default" / "trainer.pub")]) == 0
    assert capsys.readouterr().out.strip() == key_id
    assert keys_cli.main(["show", str(tmp_path / "default" / "trainer.key")]) == 0
    assert capsys.readouterr().out.strip() == key_id
    assert keys_cli.main(["generate", str(tmp_path / "default")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dynenv-keys: error:") and "refusing to overwrite" in err and err.count("\n") == 1
    assert keys_cli.main(["show", str(tmp_path / "nothing.pub")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_dynenv_keys_team_secret_calls_the_action_authentication(tmp_path, capsys):
    pytest.importorskip("dynenv_ros.security.action_auth")
    target = tmp_path / "secrets" / "team_a.secret"
    assert keys_cli.main(["team-secret", str(target)]) == 0
    assert target.is_file() and stat.S_IMODE(target.stat().st_mode) == 0o600
    assert keys_cli.main(["team-secret", str(target)]) == 2
    assert "dynenv-keys: error:" in capsys.readouterr().err
