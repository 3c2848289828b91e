"""Policy files: one self-describing ``.safetensors`` file per trained agent — the weights, plus the agent's
constructor settings and the caller's metadata as JSON strings in the safetensors header. No pickle anywhere, so a
policy file can never run code; written atomically (temp file, fsync, rename) so a crash mid-write leaves the
previous file intact.

Layout of a policy file (format ``dynenv_policy/1``):

* tensors: ``model.state_dict()`` under its own names;
* header metadata (string → string): ``format`` = ``dynenv_policy/1``, ``config`` = JSON of the ``DynEnvAgent``
  constructor arguments (feature_size, head_mode, head_units, head_max; ``uses_pose: true`` for an agent that takes
  the self-localization estimate — absent, as in every earlier file, means false), ``meta`` = JSON of the caller's metadata,
  ``data_sha256`` = SHA-256 of the tensor data section (so a flipped byte in the weights is caught on load).

Limits on what a file may ask for, checked before anything is allocated (a tiny file whose config asks for a huge
network is refused, not built): at most ``MAX_POLICY_BYTES`` (256 MiB; a feature size of 1024, the largest
allowed, makes a 163 MB file), ``feature_size`` 1..``MAX_FEATURE_SIZE`` (1024; the paper's is 64, 40.6 M weights at
1024), ``head_units`` 1..``MAX_HEAD_UNITS`` (64), ``head_max`` finite in (0, π]. The weights' names and shapes are
then checked against the network the config describes built on torch's ``meta`` device (no memory), so a config
that the tensors do not match is refused before the real network is allocated.

This module is the single implementation of the format; ``dynenv_ros.learning.run.checkpoints`` re-exports
``save_policy``/``load_policy`` and uses the helpers here (atomic writes, state-dict fitting) for the training
checkpoints (a policy file is not a checkpoint: a training checkpoint also holds the optimiser and the run's state).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import struct
import tempfile
from pathlib import Path
from dataclasses import dataclass
from typing import Any, Callable, Mapping, cast

import torch
from safetensors.torch import load as _st_load
from safetensors.torch import save as _st_save

from dynenv_ros.agent.network import DynEnvAgent

FORMAT = "dynenv_policy/1"
POLICY_SUFFIX = ".safetensors"
_HEADER_LIMIT = 100 * 1024 * 1024      # safetensors' own limit on the JSON header
MAX_POLICY_BYTES = 256 * 1024 * 1024   # a policy file, safetensors or ONNX (D = 1024 is 163 MB)
MAX_FEATURE_SIZE = 1024
MAX_HEAD_UNITS = 64
CONFIG_KEYS = ("feature_size", "head_mode", "head_units", "head_max", "scenario", "action_mode", "uses_pose")
SOCCER_ONLY_KEYS = ("head_mode", "head_units", "head_max", "uses_pose")


# -- generic helpers (also used by the training checkpoints) -------------------------------------------------------
def sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fsync_dir(path: str | os.PathLike[str]) -> None:
    """Make a rename/creation inside folder ``path`` durable (no-op where folders cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_synced(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` and fsync the file (not atomic by itself: use inside a temp folder)."""
    with open(path, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


def atomic_write(path: str | os.PathLike[str], data: bytes) -> None:
    """Replace ``path`` with ``data`` atomically: a temp file in the same folder, fsync, ``os.replace``, fsync of
    the folder. A kill at any moment leaves either the old file or the new one, never a partial one."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    fsync_dir(target.parent)


def tensors_for_saving(tensors: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """CPU, contiguous, storage-owning copies (safetensors refuses tensors that share memory)."""
    out = {}
    for name, tensor in tensors.items():
        if not isinstance(name, str) or not isinstance(tensor, torch.Tensor):
            raise TypeError(f"tensor entry {name!r} must map a str to a torch.Tensor, got {type(tensor).__name__}")
        out[name] = tensor.detach().to("cpu", copy=True).contiguous()
    return out


def safetensors_header(data: bytes) -> tuple[dict[str, Any], int]:
    """The parsed JSON header of safetensors bytes and the offset where the tensor data starts; ValueError if the
    bytes do not start with a well-formed header."""
    if len(data) < 8:
        raise ValueError(f"{len(data)} bytes, shorter than a safetensors header")
    (size,) = struct.unpack("<Q", data[:8])
    if size > _HEADER_LIMIT or 8 + size > len(data):
        raise ValueError(f"header length {size} does not fit a file of {len(data)} bytes")
    try:
        header = json.loads(data[8:8 + size].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"header is not JSON: {error}") from None
    if not isinstance(header, dict):
        raise ValueError("header is not a JSON object")
    return header, 8 + size


def read_safetensors(data: bytes) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    """Tensors (on the CPU) and header metadata from safetensors bytes; ValueError on anything malformed."""
    try:
        header, _ = safetensors_header(data)
        tensors = _st_load(data)
    except Exception as error:                      # SafetensorError, ValueError, …: all mean "damaged"
        raise ValueError(f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}") from None
    metadata = header.get("__metadata__") or {}
    if not isinstance(metadata, dict):
        raise ValueError("header metadata is not a mapping")
    return tensors, metadata


def check_state_dict_fits(model: torch.nn.Module, state: Mapping[str, torch.Tensor], source: str) -> None:
    """ValueError naming the first key that keeps ``state`` from loading strictly into ``model``: in the model's
    own order, a key the state lacks or whose shape differs; then (in sorted order) a key the model does not have."""
    expected = model.state_dict()
    for key, tensor in expected.items():
        if key not in state:
            raise ValueError(f"{source} does not fit the model: missing key {key!r}")
        if tuple(state[key].shape) != tuple(tensor.shape):
            raise ValueError(f"{source} does not fit the model: key {key!r} has shape {tuple(state[key].shape)}, "
                             f"the model expects {tuple(tensor.shape)}")
    for key in sorted(state):
        if key not in expected:
            raise ValueError(f"{source} does not fit the model: unexpected key {key!r}")


def json_dumps(value: Any, what: str) -> str:
    """Compact, sorted JSON; ValueError saying ``what`` could not be stored otherwise."""
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError) as error:
        raise ValueError(f"{what} is not JSON-serialisable: {error}") from None


def check_file_size(path: Path, what: str) -> None:
    """ValueError if ``path`` is not a regular file or is larger than ``MAX_POLICY_BYTES`` (read nothing)."""
    if not path.exists():
        raise ValueError(f"{what} {path} does not exist")
    if not path.is_file():
        raise ValueError(f"{what} {path} is not a regular file")
    size = path.stat().st_size
    if size > MAX_POLICY_BYTES:
        raise ValueError(f"{what} {path} is {size / 2**20:.0f} MiB, more than the {MAX_POLICY_BYTES >> 20} MiB "
                         f"a policy may have")


def _bounded_int(config: Mapping[str, Any], key: str, low: int, high: int) -> int:
    value = config.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"{key} must be an integer in {low}..{high}, got {value!r}")
    return value


def check_head(head_mode: Any, head_units: Any, head_max: Any) -> None:
    """ValueError unless the head settings describe a head a robot can use: a known mode, at least one unit per
    side in discrete mode (the node divides by it), a finite positive ``head_max`` of at most π rad per period."""
    if head_mode not in ("discrete", "continuous"):
        raise ValueError(f"head_mode must be 'discrete' or 'continuous', got {head_mode!r}")
    if head_mode == "discrete" and (isinstance(head_units, bool) or not isinstance(head_units, int)
                                    or not 1 <= head_units <= MAX_HEAD_UNITS):
        raise ValueError(f"head_units must be an integer in 1..{MAX_HEAD_UNITS}, got {head_units!r}")
    if (isinstance(head_max, bool) or not isinstance(head_max, (int, float)) or not math.isfinite(head_max)
            or not 0 < head_max <= math.pi):
        raise ValueError(f"head_max must be a finite angle in (0, π] rad, got {head_max!r}")


def check_agent_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """The ``DynEnvAgent`` arguments of a file's config, bounded (module docstring); ValueError otherwise. A config
    without ``scenario`` is soccer's (every soccer file; soccer's config keeps its four keys). Driving's names
    ``scenario`` 'driving' and its ``action_mode``, and has no head settings."""
    unknown = sorted(set(config) - set(CONFIG_KEYS))
    if unknown:
        raise ValueError(f"unknown config keys {unknown}")
    out = dict(config)
    if "feature_size" in config:
        _bounded_int(config, "feature_size", 1, MAX_FEATURE_SIZE)
    scenario = config.get("scenario", "soccer")
    if not isinstance(scenario, str) or scenario not in _AGENT_CONFIGS:
        raise ValueError(f"scenario must be 'soccer' or 'driving', got {scenario!r}")
    _AGENT_CONFIGS[scenario].check(config)
    return out


def _check_driving_config(config: Mapping[str, Any]) -> None:
    extra = sorted(set(config) & set(SOCCER_ONLY_KEYS))
    if extra:
        raise ValueError(f"a driving agent has no head settings, got {extra}")
    if config.get("action_mode") not in ("discrete", "continuous"):
        raise ValueError(f"action_mode must be 'discrete' or 'continuous', got {config.get('action_mode')!r}")


def _check_soccer_config(config: Mapping[str, Any]) -> None:
    if "action_mode" in config:
        raise ValueError("action_mode is a driving setting; a soccer agent's head has head_mode")
    if not isinstance(config.get("uses_pose", False), bool):
        raise ValueError(f"uses_pose must be true or false, got {config['uses_pose']!r}")
    check_head(config.get("head_mode", "discrete"), config.get("head_units", 3),
               config.get("head_max", math.radians(37.5)))
    if config.get("head_mode") == "continuous" and "head_units" in config:
        _bounded_int(config, "head_units", 0, MAX_HEAD_UNITS)


def non_finite_tensors(tensors: Mapping[str, torch.Tensor]) -> list[str]:
    """Names of the floating-point tensors holding a NaN or an infinity (a diverged run's weights)."""
    return [name for name, tensor in tensors.items()
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all())]


def refuse_non_finite(tensors: Mapping[str, torch.Tensor], source: str) -> None:
    """ValueError naming the first tensor that holds a NaN or an infinity: such weights are never saved,
    published or loaded."""
    bad = non_finite_tensors(tensors)
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise ValueError(f"{source} holds NaN or infinite values in tensor {bad[0]!r}{more}")


# -- policy files --------------------------------------------------------------------------------------------------
def agent_config(model: DynEnvAgent) -> dict[str, Any]:
    """The ``DynEnvAgent`` constructor arguments that rebuild ``model``'s architecture (soccer: the four keys it
    always had, no ``scenario``, and ``uses_pose: True`` when it takes the pose estimate; driving: feature_size,
    scenario, action_mode)."""
    return _AGENT_CONFIGS[getattr(model, "scenario", "soccer")].of(model)


def _driving_config(model: DynEnvAgent) -> dict[str, Any]:
    return {"feature_size": int(model.feature_size), "scenario": "driving", "action_mode": str(model.action_mode)}


def _soccer_config(model: DynEnvAgent) -> dict[str, Any]:
    discrete = model.head_mode == "discrete"
    config = {"feature_size": int(model.feature_size), "head_mode": str(model.head_mode),
              "head_units": (model.head_head.out_features - 1) // 2 if discrete else 3,
              "head_max": float(cast(float, model.head_max))}
    if getattr(model, "uses_pose", False):      # only then: a file without the pose stays byte-identical
        config["uses_pose"] = True
    return config


@dataclass(frozen=True)
class AgentConfigRules:
    """A scenario's part of a policy file's ``config``: ``of`` writes it for a model, ``check`` refuses a bad one
    (after the keys and the feature size every scenario shares are checked)."""
    of: Callable[[DynEnvAgent], dict[str, Any]]
    check: Callable[[Mapping[str, Any]], None]


# Each scenario's config, by its name (the registry, dynenv_ros.scenarios, sits above this layer).
_AGENT_CONFIGS = {"soccer": AgentConfigRules(_soccer_config, _check_soccer_config),
                  "driving": AgentConfigRules(_driving_config, _check_driving_config)}


def policy_bytes(model: DynEnvAgent, meta: Mapping[str, Any] | None = None) -> bytes:
    """A policy file's content (what ``save_policy`` writes; what the trainer node announces and serves)."""
    tensors = tensors_for_saving(model.state_dict())
    refuse_non_finite(tensors, "the policy to save or publish")
    metadata = {"format": FORMAT, "config": json_dumps(agent_config(model), "the agent's config"),
                "meta": json_dumps(dict(meta or {}), "policy meta")}
    first = _st_save(tensors, metadata=metadata)
    _, start = safetensors_header(first)
    metadata["data_sha256"] = hashlib.sha256(first[start:]).hexdigest()
    data = _st_save(tensors, metadata=metadata)
    _, start2 = safetensors_header(data)
    if data[start2:] != first[start:]:                  # the data section never depends on the metadata
        raise RuntimeError("safetensors serialisation is not deterministic; cannot checksum the policy")
    return data


def _write_policy(model: DynEnvAgent, path: str | os.PathLike[str], meta: Mapping[str, Any] | None) -> str:
    target = Path(path)
    if not target.parent.is_dir():
        raise ValueError(f"cannot write policy {target}: folder {target.parent} does not exist")
    data = policy_bytes(model, meta)
    atomic_write(target, data)
    return hashlib.sha256(data).hexdigest()


def save_policy(model: DynEnvAgent, path: str | os.PathLike[str], meta: Mapping[str, Any] | None = None) -> str:
    """Write the policy file ``path`` (must end in ``.safetensors``) atomically; return its SHA-256 (hex).
    ``meta`` must be JSON-serialisable (tuples come back as lists)."""
    if not str(path).endswith(POLICY_SUFFIX):
        raise ValueError(f"a policy file name must end in {POLICY_SUFFIX}, got {str(path)!r}")
    return _write_policy(model, path, meta)


def load_policy(path: str | os.PathLike[str]) -> tuple[DynEnvAgent, dict[str, Any]]:
    """The agent (eval mode, on the CPU) and the caller's meta. Refuses with ValueError: a missing file
    ("does not exist"), a damaged one ("cannot be read safely" — truncated, not safetensors, a pickle, or a tensor
    checksum mismatch), a foreign one ("not a dynenv_policy/1 file"), one whose weights do not fit the agent
    its config describes ("does not fit") and one with a NaN or infinite tensor ("holds NaN or infinite values in
    tensor 'name'")."""
    source = Path(path)
    check_file_size(source, "policy file")
    return policy_from_bytes(source.read_bytes(), f"policy file {source}")


def policy_from_bytes(data: bytes, source: str = "policy") -> tuple[DynEnvAgent, dict[str, Any]]:
    """``load_policy`` on bytes (weights fetched from a trainer); ``source`` names them in the errors."""
    try:
        tensors, metadata = read_safetensors(data)
    except ValueError as error:
        raise ValueError(f"{source} cannot be read safely: {error}") from None
    if metadata.get("format") != FORMAT:
        raise ValueError(f"{source} is not a {FORMAT} file (format {metadata.get('format')!r})")
    _, start = safetensors_header(data)
    if hashlib.sha256(data[start:]).hexdigest() != metadata.get("data_sha256"):
        raise ValueError(f"{source} cannot be read safely: tensor data checksum mismatch (damaged)")
    try:
        config = json.loads(metadata["config"])
        meta = json.loads(metadata.get("meta", "{}"))
    except (KeyError, json.JSONDecodeError) as error:
        raise ValueError(f"{source} cannot be read safely: bad metadata ({error})") from None
    if not isinstance(config, dict) or not isinstance(meta, dict):
        raise ValueError(f"{source} cannot be read safely: config/meta are not JSON objects")
    try:
        config = check_agent_config(config)
        with torch.device("meta"):          # shapes only: nothing is allocated until the tensors are known to fit
            shape_model = DynEnvAgent(**config)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{source} does not fit the agent: config {config}: {error}") from None
    check_state_dict_fits(shape_model, tensors, source)
    refuse_non_finite(tensors, source)
    model = DynEnvAgent(**config)
    model.load_state_dict(tensors)
    return model.eval(), meta
