"""Authenticated actions and feedback (issue 27 item 2): who may make a robot act, and which action the trainer learns.

DDS without SROS2 does not say who sent a message, so any process on the ROS domain can publish a robot's
``Action`` or a ``StepFeedback``. Here each message carries an HMAC-SHA256 tag (``mac``, first 16 bytes) of its
canonical bytes under a shared secret, and the simulator executes, and the trainer learns from, only what verifies:

- **Team secrets, one per team** (``team_a.secret``, ``team_b.secret``; driving: ``cars.secret``): 32 random bytes
  in a mode-0600 file, on each of the team's robots and on the simulator's and trainer's machines. Per team, not
  per robot: a team's robots run one stack and are one unit of trust (a robot that leaks its secret has its team's
  stack), and the simulator and trainer would hold every robot's secret anyway. **The simulator's own secret**
  (``simulator.secret``) tags the feedback; no robot holds it.
- **Canonical bytes** (``action_bytes``, ``feedback_bytes``): a domain label, the topic the message is published on
  (length-prefixed; binding the tag to the topic stops a genuine message of one game being replayed into another
  game, or onto another robot's topic), the header (stamp, frame_id) and every field in order, integers big-endian
  at their message widths, floats by their float32 bit pattern, strings and arrays length-prefixed: two different
  messages never share bytes. ``mac`` itself is excluded.
- **Nonce**: (robot_id, episode_id, motion_period) is inside the tagged bytes, so a captured action is valid for its
  own robot and period only; ``ReplayGuard`` refuses a nonce already used (a replay of an accepted action).
- **Digest** (``action_digest``: SHA-256 of the canonical bytes, first 16 bytes): the simulator names the action it
  executed in ``StepFeedback.action_digest``; the trainer learns from that action only (``learning.messages.assembly``).

The secrets are symmetric: whoever verifies a team's actions (the simulator, the trainer) could also forge them.
Standard library only (hmac, hashlib, secrets); no ROS import: messages are read by attribute.
"""
from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import stat
import struct
import threading
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SECRET_BYTES = 32                 # a team or simulator secret: 32 random bytes
TAG_BYTES = 16                    # HMAC-SHA256 truncated to 128 bits (Action.mac, StepFeedback.mac)
DIGEST_BYTES = 16                 # SHA-256 truncated to 128 bits (StepFeedback.action_digest)
SECRET_SUFFIX = ".secret"
SIMULATOR = "simulator"           # the simulator's feedback secret: simulator.secret
ACTION_DOMAIN = b"dynenv_msgs/Action/v1\n"
FEEDBACK_DOMAIN = b"dynenv_msgs/StepFeedback/v1\n"
# Every field after the header, in Action.msg's order: robot_id u16, episode_id u32, motion_period u32, walk, turn,
# kick u8, head_yaw_delta, throttle, brake, steering f32, policy_version u32, log_prob, value f32.
_ACTION = struct.Struct(">iIHIIBBBffffIff")
# stamp, robot_id, episode_id, motion_period, the five reward terms, terminated, truncated, landmarks_seen, the
# number of seen_object_ids (each a u32 after it).
_FEEDBACK = struct.Struct(">iIHIIfffffBBfI")
_LENGTH = struct.Struct(">H")


class SecretError(ValueError):
    """A secret file is missing, unreadable, of the wrong size or readable by others (one line)."""


# -- secrets -----------------------------------------------------------------------------------------------------
def key_name(agent: str) -> str:
    """The secret that authenticates ``agent``'s actions: its team's (``team_a_1`` -> ``team_a``), or for the
    driving cars, which one stack drives, ``cars``."""
    for prefix in ("team_a_", "team_b_"):
        if agent.startswith(prefix):
            return prefix[:-1]
    if agent.startswith("car_"):
        return "cars"
    raise SecretError(f"no team secret for agent {agent!r} (agents are team_a_<k>, team_b_<k> or car_<k>)")


def secret_path(directory: str | os.PathLike[str], name: str) -> Path:
    """``directory/<name>.secret`` (name: a ``key_name`` or ``SIMULATOR``)."""
    return Path(directory).expanduser() / f"{name}{SECRET_SUFFIX}"


def write_team_secret(path: Path) -> None:
    """32 random bytes into a new file of mode 0600 (its folder made 0700 if missing). Refuses an existing file: a
    secret in use is never replaced by accident (rotate by deleting it first)."""
    path = Path(path).expanduser()
    if path.exists() or path.is_symlink():
        raise SecretError(f"{path} exists: refusing to overwrite a secret (delete it first to rotate it)")
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise SecretError(f"{path} exists: refusing to overwrite a secret (delete it first to rotate it)") from None
    except OSError as error:
        raise SecretError(f"cannot write {path}: {error.strerror or error}") from None
    with os.fdopen(fd, "wb") as handle:
        handle.write(secrets.token_bytes(SECRET_BYTES))
        handle.flush()
        os.fsync(handle.fileno())
    os.chmod(path, 0o600)                            # the umask may have removed bits


def load_secret(path: str | os.PathLike[str]) -> bytes:
    """The 32 bytes of a secret file; refused when missing, not a regular file, group- or world-accessible, or of
    another size."""
    file = Path(path).expanduser()
    try:
        fd = os.open(file, os.O_RDONLY | os.O_NOFOLLOW)
    except FileNotFoundError:
        raise SecretError(f"{file} does not exist (make one with `dynenv-keys team-secret {file}`)") from None
    except OSError as error:
        raise SecretError(f"cannot read {file}: {error.strerror or error}") from None
    try:
        info = os.fstat(fd)                          # the file opened, not whatever the path names by now
        if not stat.S_ISREG(info.st_mode):
            raise SecretError(f"{file} is not a regular file")
        mode = stat.S_IMODE(info.st_mode)
        if mode & 0o077:
            raise SecretError(f"{file} has mode {mode:04o}: a secret must be readable by its owner only "
                              f"(chmod 600 {file})")
        data = os.read(fd, SECRET_BYTES + 1)
    except OSError as error:
        raise SecretError(f"cannot read {file}: {error.strerror or error}") from None
    finally:
        os.close(fd)
    if len(data) != SECRET_BYTES:
        raise SecretError(f"{file} holds {len(data)}{'+' if len(data) > SECRET_BYTES else ''} bytes, not "
                          f"{SECRET_BYTES}: not a secret made by `dynenv-keys team-secret`")
    return data


@dataclass(frozen=True)
class GameSecrets:
    """The secrets one node holds: team secrets by ``key_name``, and the simulator's (None where not needed)."""
    teams: dict[str, bytes]
    simulator: bytes | None = None

    def for_agent(self, agent: str) -> bytes:
        name = key_name(agent)
        if name not in self.teams:
            raise SecretError(f"no {name}{SECRET_SUFFIX} loaded for {agent}")
        return self.teams[name]


def load_game_secrets(directory: str | os.PathLike[str], agents: Iterable[str], simulator: bool) -> GameSecrets:
    """The team secrets of ``agents`` (and ``simulator.secret`` if asked) from ``directory``: exactly the files a
    node needs, so a robot's directory holds its own team's secret only."""
    teams = {name: load_secret(secret_path(directory, name)) for name in sorted({key_name(a) for a in agents})}
    return GameSecrets(teams, load_secret(secret_path(directory, SIMULATOR)) if simulator else None)


def write_game_secrets(directory: str | os.PathLike[str], agents: Iterable[str]) -> Path:
    """New secrets for a run: the teams of ``agents`` and the simulator's, in ``directory`` (the train graph's
    run-local secrets). Returns the directory."""
    folder = Path(directory).expanduser()
    for name in sorted({key_name(a) for a in agents}) + [SIMULATOR]:
        write_team_secret(secret_path(folder, name))
    return folder


# -- canonical bytes, digest, tag --------------------------------------------------------------------------------
def _text(value: str) -> bytes:
    data = value.encode("utf-8")
    if len(data) > 0xFFFF:
        raise ValueError(f"a string of {len(data)} bytes cannot be authenticated (at most 65535)")
    return _LENGTH.pack(len(data)) + data


def _header(msg: Any) -> tuple[int, int, str]:
    header = getattr(msg, "header", None)
    if header is None:
        return 0, 0, ""
    return int(header.stamp.sec), int(header.stamp.nanosec), str(header.frame_id)


def action_bytes(msg: Any, topic: str) -> bytes:
    """The canonical bytes of an Action published on ``topic`` (module docstring). ValueError for values no
    Action can hold."""
    sec, nanosec, frame_id = _header(msg)
    try:
        fields = _ACTION.pack(sec, nanosec, int(msg.robot_id), int(msg.episode_id), int(msg.motion_period),
                              int(msg.walk), int(msg.turn), int(msg.kick), float(msg.head_yaw_delta),
                              float(msg.throttle), float(msg.brake), float(msg.steering),
                              int(getattr(msg, "policy_version", 0)), float(getattr(msg, "log_prob", 0.0)),
                              float(getattr(msg, "value", 0.0)))
    except (struct.error, OverflowError) as error:
        raise ValueError(f"an Action field is out of its type's range ({error})") from None
    return ACTION_DOMAIN + _text(topic) + _text(frame_id) + fields


def feedback_bytes(msg: Any, topic: str) -> bytes:
    """The canonical bytes of a StepFeedback published on ``topic``, ``action_digest`` included."""
    sec, nanosec, frame_id = _header(msg)
    seen = [int(i) for i in msg.seen_object_ids]
    digest = bytes(getattr(msg, "action_digest", b""))
    try:
        fields = _FEEDBACK.pack(sec, nanosec, int(msg.robot_id), int(msg.episode_id), int(msg.motion_period),
                                float(msg.reward_primary), float(msg.reward_rule), float(msg.reward_auxiliary),
                                float(msg.reward_observation), float(msg.reward_total), bool(msg.terminated),
                                bool(msg.truncated), float(msg.landmarks_seen), len(seen))
        ids = struct.pack(f">{len(seen)}I", *seen)
    except (struct.error, OverflowError) as error:
        raise ValueError(f"a StepFeedback field is out of its type's range ({error})") from None
    if len(digest) > 255:
        raise ValueError(f"action_digest of {len(digest)} bytes (at most 32)")
    return FEEDBACK_DOMAIN + _text(topic) + _text(frame_id) + fields + ids + bytes([len(digest)]) + digest


def digest(data: bytes) -> bytes:
    return hashlib.sha256(data).digest()[:DIGEST_BYTES]


def action_digest(msg: Any, topic: str) -> bytes:
    """Which action this is (StepFeedback.action_digest): SHA-256 of its canonical bytes, first 16 bytes."""
    return digest(action_bytes(msg, topic))


def tag(secret: bytes, data: bytes) -> bytes:
    """HMAC-SHA256 of ``data`` under ``secret``, first 16 bytes."""
    return hmac.digest(secret, data, "sha256")[:TAG_BYTES]


def verify(secret: bytes, data: bytes, mac: Any) -> bool:
    """``mac`` is ``data``'s tag under ``secret`` (constant-time comparison)."""
    return hmac.compare_digest(tag(secret, data), bytes(mac))


def tag_action(msg: Any, topic: str, secret: bytes) -> bytes:
    return tag(secret, action_bytes(msg, topic))


def tag_feedback(msg: Any, topic: str, secret: bytes) -> bytes:
    return tag(secret, feedback_bytes(msg, topic))


def _check(encode, msg: Any, topic: str, secret: bytes) -> str:
    mac = bytes(getattr(msg, "mac", b""))
    if not mac:
        return "mac_missing"
    try:
        data = encode(msg, topic)
    except ValueError:
        return "mac_invalid"
    return "" if verify(secret, data, mac) else "mac_invalid"


def check_action(msg: Any, topic: str, secret: bytes) -> str:
    """Why an Action on ``topic`` is not authenticated by ``secret``: "" (it is), ``mac_missing`` or
    ``mac_invalid`` (forged, altered, another team's secret, or another topic's)."""
    return _check(action_bytes, msg, topic, secret)


def check_feedback(msg: Any, topic: str, secret: bytes) -> str:
    """As ``check_action``, for a StepFeedback under the simulator's secret."""
    return _check(feedback_bytes, msg, topic, secret)


# -- replays ------------------------------------------------------------------------------------------------------
class ReplayGuard:
    """The nonces (robot_id, episode_id, motion_period) of the last ``capacity`` accepted actions: one already used
    is a replay. Bounded: an older nonce is forgotten, and its period has long run (the simulator refuses an
    action for a past period as ``late`` anyway). Safe to read from one thread while another records."""

    def __init__(self, capacity: int = 4096) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self._used: set[tuple[int, int, int]] = set()
        self._order: deque[tuple[int, int, int]] = deque()
        self._lock = threading.Lock()

    def used(self, nonce: tuple[int, int, int]) -> bool:
        return nonce in self._used

    def use(self, nonce: tuple[int, int, int]) -> bool:
        """Record ``nonce``; False (and nothing recorded) when it was used already."""
        with self._lock:
            if nonce in self._used:
                return False
            self._used.add(nonce)
            self._order.append(nonce)
            while len(self._order) > self.capacity:
                self._used.discard(self._order.popleft())
            return True

    def __len__(self) -> int:
        return len(self._order)


__all__ = ["SECRET_BYTES", "TAG_BYTES", "DIGEST_BYTES", "SIMULATOR", "SecretError", "GameSecrets", "ReplayGuard",
           "key_name", "secret_path", "write_team_secret", "load_secret", "load_game_secrets", "write_game_secrets",
           "action_bytes", "feedback_bytes", "digest", "action_digest", "tag", "verify", "tag_action", "tag_feedback",
           "check_action", "check_feedback"]
