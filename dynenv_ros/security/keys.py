"""Ed25519 key files for signed weights releases: the trainer's private key (``trainer.key``, PKCS#8 PEM, mode
0600, only on the trainer's machine) and the public keys a robot trusts (``*.pub``, SubjectPublicKeyInfo PEM,
world-readable is fine). PEM so that ``openssl pkey`` reads them too.

A key is named by its id: the first 16 hex characters of SHA-256 of the raw 32-byte public key
(``WeightsAnnouncement.key_id``). Every failure is a ``KeyFileError`` with a one-line message that names the file
and what to do.
"""
from __future__ import annotations

import hashlib
import os
import re
import stat
from collections.abc import Iterable
from pathlib import Path

from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

PRIVATE_NAME = "trainer.key"
PUBLIC_NAME = "trainer.pub"
OPERATOR_NAME = "operator"          # an operator's pair: operator.key / operator.pub (signed requests, issue 43)
PUBLIC_SUFFIX = ".pub"
KEY_ID_CHARS = 16
MAX_KEY_FILE_BYTES = 16 * 1024      # a PEM Ed25519 key is about 120 bytes; anything far larger is not a key
ENV_DIR = "DYNENV_KEYS_DIR"


class KeyFileError(ValueError):
    """A key file is missing, unreadable, corrupt, of the wrong kind or readable by others (one line)."""


def default_keys_dir() -> Path:
    """``$DYNENV_KEYS_DIR``, else ``~/.config/dynenv_ros/keys``: where ``dynenv-keys`` writes by default and where
    the trainer looks for ``trainer.key`` when no ``signing_key`` is given."""
    configured = os.environ.get(ENV_DIR, "")
    return Path(configured).expanduser() if configured else Path.home() / ".config" / "dynenv_ros" / "keys"


def key_id(public_key: Ed25519PublicKey) -> str:
    """First 16 hex characters of SHA-256 of the raw 32-byte public key."""
    raw = public_key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:KEY_ID_CHARS]


def generate_key_pair(directory: str | os.PathLike[str], name: str = "trainer") -> tuple[Path, Path]:
    """Write a new pair as ``directory/<name>.key`` (0600) and ``directory/<name>.pub`` (``trainer``: signs weights;
    ``operator``: signs requests and files); refuse (KeyFileError) if either exists, so a key in use is never
    replaced by accident. Returns (private path, public path)."""
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", name):
        raise KeyFileError(f"key name {name!r}: use 1-64 letters, digits, '_' or '-'")
    folder = Path(directory).expanduser()
    private_path, public_path = folder / f"{name}.key", folder / f"{name}{PUBLIC_SUFFIX}"
    for path in (private_path, public_path):
        if path.exists():
            raise KeyFileError(f"{path} exists: refusing to overwrite a key (move it away first)")
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError as error:
        raise KeyFileError(f"cannot create {folder}: {error.strerror or error}") from None
    key = Ed25519PrivateKey.generate()
    private_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                    serialization.NoEncryption())
    public_pem = key.public_key().public_bytes(serialization.Encoding.PEM,
                                               serialization.PublicFormat.SubjectPublicKeyInfo)
    _write_new(private_path, private_pem, 0o600)
    try:
        _write_new(public_path, public_pem, 0o644)
    except KeyFileError:
        private_path.unlink(missing_ok=True)        # no half pair left behind
        raise
    return private_path, public_path


def _write_new(path: Path, data: bytes, mode: int) -> None:
    """Create ``path`` with ``mode`` from the start (O_EXCL: never follows or replaces an existing file)."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except FileExistsError:
        raise KeyFileError(f"{path} exists: refusing to overwrite a key (move it away first)") from None
    except OSError as error:
        raise KeyFileError(f"cannot write {path}: {error.strerror or error}") from None
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.chmod(path, mode)                             # the umask may have removed bits we asked for


def _read_key_file(path: Path) -> bytes:
    try:
        info = path.stat()
    except FileNotFoundError:
        raise KeyFileError(f"{path} does not exist (make a pair with `dynenv-keys generate DIR`)") from None
    except OSError as error:
        raise KeyFileError(f"cannot read {path}: {error.strerror or error}") from None
    if not stat.S_ISREG(info.st_mode):
        raise KeyFileError(f"{path} is not a regular file")
    if info.st_size > MAX_KEY_FILE_BYTES:
        raise KeyFileError(f"{path} is {info.st_size} bytes: not an Ed25519 key file")
    try:
        return path.read_bytes()
    except OSError as error:
        raise KeyFileError(f"cannot read {path}: {error.strerror or error}") from None


def load_private_key(path: str | os.PathLike[str]) -> Ed25519PrivateKey:
    """The trainer's signing key. Refused when group or others may read or write it (``chmod 600``): a key others
    can read signs for them too."""
    file = Path(path).expanduser()
    data = _read_key_file(file)
    mode = stat.S_IMODE(file.stat().st_mode)
    if mode & 0o077:
        raise KeyFileError(f"{file} has mode {mode:04o}: a private key must be readable by its owner only "
                           f"(chmod 600 {file})")
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError, UnsupportedAlgorithm) as error:
        raise KeyFileError(f"{file} is not a PEM private key ({_first_line(error)})") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyFileError(f"{file} holds a {type(key).__name__.removeprefix('_')}, not an Ed25519 private key")
    return key


def load_public_key(path: str | os.PathLike[str]) -> Ed25519PublicKey:
    """A trusted public key (``*.pub``)."""
    file = Path(path).expanduser()
    data = _read_key_file(file)
    try:
        key = serialization.load_pem_public_key(data)
    except (ValueError, TypeError, UnsupportedAlgorithm) as error:
        raise KeyFileError(f"{file} is not a PEM public key ({_first_line(error)})") from None
    if not isinstance(key, Ed25519PublicKey):
        raise KeyFileError(f"{file} holds a {type(key).__name__.removeprefix('_')}, not an Ed25519 public key")
    return key


def load_trusted_keys(paths: Iterable[str | os.PathLike[str]]) -> dict[str, Ed25519PublicKey]:
    """{key id: key} of every public key named: a file, or a directory meaning each ``*.pub`` in it (a directory
    without one is refused: trusting nothing by accident should be loud)."""
    trusted: dict[str, Ed25519PublicKey] = {}
    for entry in paths:
        path = Path(entry).expanduser()
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.name.endswith(PUBLIC_SUFFIX))
            if not files:
                raise KeyFileError(f"{path} holds no {PUBLIC_SUFFIX} file")
        else:
            files = [path]
        for file in files:
            key = load_public_key(file)
            trusted[key_id(key)] = key
    return trusted


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__
