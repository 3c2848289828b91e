"""Training checkpoints: safetensors + JSON, written atomically, resumable; and the policy files that ship.

A run keeps its checkpoints in ``<run_dir>/checkpoints/``::

    checkpoints/
      latest                      one line: the name of the newest complete checkpoint (replaced atomically)
      step_000000012000/
        model.safetensors         model.state_dict()
        optimizer.safetensors     every tensor of optimizer.state_dict(): "state.<param_index>.<key>" (Adam's
                                  exp_avg, exp_avg_sq and step included) and tensor-valued param-group entries
                                  as "param_groups.<group_index>.<key>"; absent when no optimizer was given
        extra.safetensors         the caller's extra tensors (RNG states, running statistics, …)
        meta.json                 {"format": "dynenv_training/1", "step", "created_unix", "code_revision",
                                   "files": {file name: SHA-256}, "optimizer": {"class", "param_groups" (without
                                   the tensor entries), "state_values" (non-tensor state)} | null,
                                   "meta": the caller's meta}

Atomicity: the files are written (and fsynced) into a temp folder beside the checkpoints, which is renamed into
place; only then is ``latest`` replaced (temp file + ``os.replace``) and older checkpoints pruned. A kill at any
moment leaves the previous ``latest`` checkpoint complete and loadable; a half-written temp folder is never taken
for a checkpoint (its name starts with a dot) and is removed by the next save. Loading verifies every file's
SHA-256 and, given a run folder, falls back to the newest valid checkpoint (with a ``CheckpointWarning``) when
``latest`` is missing or names a missing or damaged one. One writer per run folder.

No pickle anywhere: tensors in safetensors, everything else in JSON. Policy files (``save_policy``/``load_policy``)
are implemented in ``dynenv_ros.agent.checkpoint`` and re-exported here.
"""
from __future__ import annotations

import hashlib
import json
import os
import random
import re
import shutil
import tempfile
import time
import uuid
import warnings
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from safetensors.torch import save as _st_save

from dynenv_ros.core.revision import code_revision
from dynenv_ros.agent.checkpoint import (FORMAT as POLICY_FORMAT, atomic_write, check_state_dict_fits, fsync_dir,
                                         json_dumps, load_policy, read_safetensors, refuse_non_finite,
                                         save_policy, sha256, tensors_for_saving, write_synced)
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.config import TrainConfig

__all__ = ["FORMAT", "POLICY_FORMAT", "CheckpointWarning", "save_training_checkpoint", "load_training_checkpoint",
           "read_checkpoint_meta", "resolve_checkpoint", "list_checkpoints", "capture_rng_state",
           "restore_rng_state", "save_policy", "load_policy", "sha256", "policy_from_training_checkpoint",
           "policy_meta", "save_policy_from_training_checkpoint"]

FORMAT = "dynenv_training/1"
# the "version" of a run's meta (in its checkpoints and policy files): what wrote it
META_VERSION = "dynenv_ros.learning/1"
CHECKPOINTS = "checkpoints"
LATEST = "latest"
# In a fresh run's directory (the trainer node's): the policy file it starts from, to measure what it learnt against.
START_POLICY = "policy_start.safetensors"
MODEL_FILE, OPTIMIZER_FILE, EXTRA_FILE, META_FILE = ("model.safetensors", "optimizer.safetensors",
                                                     "extra.safetensors", "meta.json")
_STEP_DIR = re.compile(r"^step_(\d{12,})$")
_TMP_PREFIX, _OLD_PREFIX = ".tmp-", ".old-"


class CheckpointWarning(UserWarning):
    """A run folder's ``latest`` pointer was missing or named a missing/damaged checkpoint; an older one is used."""


# -- saving --------------------------------------------------------------------------------------------------------
def _step_name(step: int) -> str:
    return f"step_{step:012d}"


def _optimizer_payload(optimizer: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """(tensors, JSON description) of ``optimizer.state_dict()``."""
    state_dict = optimizer.state_dict()
    tensors: dict[str, torch.Tensor] = {}
    values: dict[str, dict[str, Any]] = {}
    for index, entries in state_dict["state"].items():
        for key, value in entries.items():
            if isinstance(value, torch.Tensor):
                tensors[f"state.{index}.{key}"] = value
            else:
                values.setdefault(str(index), {})[key] = value
    groups = []
    for g, group in enumerate(state_dict["param_groups"]):
        plain = {}
        for key, value in group.items():
            if isinstance(value, torch.Tensor):
                tensors[f"param_groups.{g}.{key}"] = value
            else:
                plain[key] = value
        groups.append(plain)
    cls = type(optimizer)
    return tensors_for_saving(tensors), {"class": f"{cls.__module__}.{cls.__qualname__}", "param_groups": groups,
                                         "state_values": values}


def _remove_dir(path: Path) -> None:
    """Rename out of the checkpoint namespace first, then delete, so a kill mid-delete leaves no half checkpoint."""
    aside = path.with_name(f"{_OLD_PREFIX}{path.name}-{uuid.uuid4().hex[:8]}")
    try:
        os.rename(path, aside)
    except OSError:
        aside = path
    shutil.rmtree(aside, ignore_errors=True)


def save_training_checkpoint(run_dir: str | os.PathLike[str], step: int, model: torch.nn.Module,
                             optimizer: torch.optim.Optimizer | None, meta: Mapping[str, Any],
                             extra_tensors: Mapping[str, torch.Tensor] | None = None, keep: int = 3) -> Path:
    """Write ``<run_dir>/checkpoints/step_<step, 12 digits>/`` atomically, point ``latest`` at it, keep the newest
    ``keep`` checkpoints (by step; the one just written always stays) and return its path.

    ``meta`` must be JSON-serialisable (tuples come back as lists) and must not use the reserved key
    ``"checkpoint"`` (``load_training_checkpoint`` adds it). Saving the same step twice replaces that checkpoint.
    """
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise ValueError(f"step must be a non-negative int, got {step!r}")
    if isinstance(keep, bool) or not isinstance(keep, int) or keep < 1:
        raise ValueError(f"keep must be an int >= 1, got {keep!r}")
    if not isinstance(meta, Mapping):
        raise ValueError(f"meta must be a mapping, got {type(meta).__name__}")
    if "checkpoint" in meta:
        raise ValueError("meta key 'checkpoint' is reserved (load_training_checkpoint fills it in)")
    json_dumps(dict(meta), "meta")                                    # refuse before anything touches the disk
    weights = tensors_for_saving(model.state_dict())
    refuse_non_finite(weights, "the model to checkpoint")          # a NaN is never saved
    blobs = {MODEL_FILE: _st_save(weights),
             EXTRA_FILE: _st_save(tensors_for_saving(dict(extra_tensors or {})))}
    optimizer_json = None
    if optimizer is not None:
        optimizer_tensors, optimizer_json = _optimizer_payload(optimizer)
        refuse_non_finite(optimizer_tensors, "the optimizer state to checkpoint")
        json_dumps(optimizer_json, "the optimizer's non-tensor state")
        blobs[OPTIMIZER_FILE] = _st_save(optimizer_tensors)
    record = {"format": FORMAT, "step": step, "created_unix": time.time(), "code_revision": code_revision(),
              "files": {name: hashlib.sha256(data).hexdigest() for name, data in blobs.items()},
              "optimizer": optimizer_json, "meta": dict(meta)}
    blobs[META_FILE] = json.dumps(record, indent=1, sort_keys=True).encode("utf-8")

    folder = Path(run_dir) / CHECKPOINTS
    folder.mkdir(parents=True, exist_ok=True)
    name = _step_name(step)
    tmp = Path(tempfile.mkdtemp(prefix=f"{_TMP_PREFIX}{name}-", dir=folder))
    try:
        for file_name, data in blobs.items():                        # meta.json last: it vouches for the rest
            write_synced(tmp / file_name, data)
        fsync_dir(tmp)
        final = folder / name
        if final.exists():
            aside = folder / f"{_OLD_PREFIX}{name}-{uuid.uuid4().hex[:8]}"
            os.rename(final, aside)
            os.rename(tmp, final)
            shutil.rmtree(aside, ignore_errors=True)
        else:
            os.rename(tmp, final)
        fsync_dir(folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write(folder / LATEST, (name + "\n").encode("ascii"))
    _prune(folder, keep, final)
    return final


def _prune(folder: Path, keep: int, written: Path) -> None:
    for stale in folder.iterdir():                   # leftovers of killed writers / deletions
        if stale.is_dir() and stale.name.startswith((_TMP_PREFIX, _OLD_PREFIX)):
            shutil.rmtree(stale, ignore_errors=True)
    for old in list_checkpoints(folder)[keep:]:
        if old != written:
            _remove_dir(old)


# -- finding and verifying -----------------------------------------------------------------------------------------
def list_checkpoints(run_or_checkpoints_dir: str | os.PathLike[str]) -> list[Path]:
    """The ``step_*`` folders of a run (or of its ``checkpoints`` folder), newest step first; not verified."""
    folder = Path(run_or_checkpoints_dir)
    if (folder / CHECKPOINTS).is_dir():
        folder = folder / CHECKPOINTS
    if not folder.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := _STEP_DIR.match(p.name)) and p.is_dir()]
    return [p for _, p in sorted(found, key=lambda item: item[0], reverse=True)]


def _verify(directory: Path) -> tuple[dict[str, Any], dict[str, bytes]]:
    """(meta.json record, file bytes) of a complete, undamaged checkpoint folder; ValueError saying what is wrong."""
    if not directory.is_dir():
        raise ValueError(f"checkpoint {directory} does not exist")
    try:
        record = json.loads((directory / META_FILE).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"checkpoint {directory} has no {META_FILE} (incomplete)") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"checkpoint {directory}: {META_FILE} is damaged ({error})") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        found = record.get("format") if isinstance(record, dict) else None
        raise ValueError(f"checkpoint {directory} is not a {FORMAT} checkpoint (format {found!r})")
    files = record.get("files")
    needed = {MODEL_FILE, EXTRA_FILE} | ({OPTIMIZER_FILE} if record.get("optimizer") is not None else set())
    if not isinstance(files, dict) or set(files) != needed:
        raise ValueError(f"checkpoint {directory}: {META_FILE} lists files {sorted(files or {})}, "
                         f"expected {sorted(needed)}")
    blobs = {}
    for file_name, digest in files.items():
        try:
            data = (directory / file_name).read_bytes()
        except FileNotFoundError:
            raise ValueError(f"checkpoint {directory} is missing {file_name}") from None
        if hashlib.sha256(data).hexdigest() != digest:
            raise ValueError(f"checkpoint {directory}: {file_name} is damaged (SHA-256 mismatch)")
        blobs[file_name] = data
    return record, blobs


def _checkpoints_folder(path: Path) -> Path | None:
    if (path / CHECKPOINTS).is_dir():
        return path / CHECKPOINTS
    if path.is_dir() and ((path / LATEST).is_file() or list_checkpoints(path)) and not (path / META_FILE).exists():
        return path
    return None


def _resolve(path: str | os.PathLike[str]) -> tuple[Path, dict[str, Any], dict[str, bytes]]:
    source = Path(path)
    folder = _checkpoints_folder(source)
    if folder is None:                                  # a checkpoint folder itself: no fallback, errors are errors
        if not source.exists():
            raise ValueError(f"checkpoint {source} does not exist")
        if source.is_dir() and not (source / META_FILE).exists() and not _STEP_DIR.match(source.name):
            raise ValueError(f"no checkpoint in {source}: neither a checkpoint folder ({META_FILE}) nor a run "
                             f"folder with {CHECKPOINTS}/")
        return (source, *_verify(source))
    problems = []
    pointer = folder / LATEST
    if pointer.is_file():
        try:
            target = pointer.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError) as error:
            target, problems = "", [f"{pointer} cannot be read ({error})"]
        if target and _STEP_DIR.match(target):
            try:
                return (folder / target, *_verify(folder / target))
            except ValueError as error:
                problems.append(f"{pointer} names {target}, which is unusable: {error}")
        elif not problems:
            problems.append(f"{pointer} is damaged (content {target[:40]!r})")
    else:
        problems.append(f"{pointer} does not exist")
    for candidate in list_checkpoints(folder):
        try:
            record, blobs = _verify(candidate)
        except ValueError as error:
            problems.append(str(error))
            continue
        warnings.warn(f"{'; '.join(problems)}; using the newest valid checkpoint {candidate}", CheckpointWarning,
                      stacklevel=3)
        return candidate, record, blobs
    raise ValueError(f"no valid checkpoint in {folder}: " + ("; ".join(problems) or "none written"))


def resolve_checkpoint(path: str | os.PathLike[str]) -> Path:
    """The checkpoint folder ``load_training_checkpoint(path, …)`` would load (verified; same fallback rules)."""
    return _resolve(path)[0]


def _caller_meta(directory: Path, record: dict[str, Any]) -> dict[str, Any]:
    meta = dict(record.get("meta") or {})
    meta["checkpoint"] = {"path": str(directory), "step": record.get("step"), "format": record["format"],
                          "code_revision": record.get("code_revision"), "created_unix": record.get("created_unix")}
    return meta


def read_checkpoint_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The meta ``load_training_checkpoint`` would return, without a model (e.g. to rebuild the config first)."""
    directory, record, _ = _resolve(path)
    return _caller_meta(directory, record)


# -- loading -------------------------------------------------------------------------------------------------------
def _optimizer_state_dict(directory: Path, record: dict[str, Any], data: bytes,
                          optimizer: torch.optim.Optimizer) -> dict[str, Any]:
    description = record["optimizer"]
    cls = type(optimizer)
    if description.get("class") != f"{cls.__module__}.{cls.__qualname__}":
        raise ValueError(f"checkpoint {directory} holds a {description.get('class')} state, "
                         f"not one of {cls.__module__}.{cls.__qualname__}")
    try:
        tensors, _ = read_safetensors(data)
    except ValueError as error:
        raise ValueError(f"checkpoint {directory}: {OPTIMIZER_FILE} cannot be read: {error}") from None
    current = optimizer.state_dict()["param_groups"]
    saved = [dict(group) for group in description["param_groups"]]
    if len(saved) != len(current):
        raise ValueError(f"checkpoint {directory}: optimizer has {len(saved)} parameter groups, "
                         f"this optimizer {len(current)}")
    for g, (old, new) in enumerate(zip(saved, current)):
        if len(old.get("params", [])) != len(new["params"]):
            raise ValueError(f"checkpoint {directory}: optimizer parameter group {g} holds {len(old['params'])} "
                             f"parameters, this optimizer's {len(new['params'])}")
        for key, value in old.items():                 # JSON made tuples lists (Adam's betas): give them back
            if isinstance(new.get(key), tuple) and isinstance(value, list):
                old[key] = tuple(value)
    state: dict[int, dict[str, Any]] = {}
    for index, values in description.get("state_values", {}).items():
        state.setdefault(int(index), {}).update(values)
    for name, tensor in tensors.items():
        kind, index, key = name.split(".", 2)
        if kind == "state":
            state.setdefault(int(index), {})[key] = tensor
        elif kind == "param_groups":
            saved[int(index)][key] = tensor
        else:
            raise ValueError(f"checkpoint {directory}: unexpected optimizer tensor {name!r}")
    return {"state": state, "param_groups": saved}


def load_training_checkpoint(path: str | os.PathLike[str], model: torch.nn.Module,
                             optimizer: torch.optim.Optimizer | None = None
                             ) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """Restore ``model`` (and ``optimizer``, exactly) from a checkpoint folder, or from a run folder / its
    ``checkpoints`` folder (then the ``latest`` one, falling back to the newest valid one with a
    ``CheckpointWarning``). Returns (the caller's meta plus ``meta["checkpoint"]`` = {path, step, format,
    code_revision, created_unix}, the extra tensors on the CPU).

    ValueError for: nothing there, a damaged file (SHA-256 mismatch, unreadable), a foreign format, weights that
    do not fit ``model`` (naming the first offending key), weights holding a NaN or infinity (named), an optimizer of another class or parameter layout, or
    an optimizer asked for when none was saved. Nothing is modified unless every check passes.
    """
    directory, record, blobs = _resolve(path)
    try:
        state, _ = read_safetensors(blobs[MODEL_FILE])
        extra, _ = read_safetensors(blobs[EXTRA_FILE])
    except ValueError as error:
        raise ValueError(f"checkpoint {directory} cannot be read: {error}") from None
    check_state_dict_fits(model, state, f"checkpoint {directory}")
    refuse_non_finite(state, f"checkpoint {directory}")
    optimizer_state = None
    if optimizer is not None:
        if record.get("optimizer") is None:
            raise ValueError(f"checkpoint {directory} holds no optimizer state")
        optimizer_state = _optimizer_state_dict(directory, record, blobs[OPTIMIZER_FILE], optimizer)
    model.load_state_dict(state)
    if optimizer_state is not None:
        optimizer.load_state_dict(optimizer_state)
    return _caller_meta(directory, record), extra


# -- RNG state as tensors (for extra_tensors) ----------------------------------------------------------------------
def _json_tensor(value: Any) -> torch.Tensor:
    return torch.frombuffer(bytearray(json.dumps(value).encode("utf-8")), dtype=torch.uint8).clone()


def _tensor_json(tensor: torch.Tensor) -> Any:
    return json.loads(bytes(tensor.to(torch.uint8).tolist()).decode("utf-8"))


def capture_rng_state() -> dict[str, torch.Tensor]:
    """The global RNG states (torch CPU, every initialised CUDA device, Python ``random``, NumPy's legacy global
    generator) as uint8 tensors named ``rng.*``, for ``extra_tensors``."""
    np_state = np.random.get_state()
    out = {"rng.torch": torch.get_rng_state(),
           "rng.python": _json_tensor(random.getstate()),
           "rng.numpy": _json_tensor([np_state[0], np_state[1].tolist(), *[v.item() if hasattr(v, "item") else v
                                                                           for v in np_state[2:]]])}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        for index, state in enumerate(torch.cuda.get_rng_state_all()):
            out[f"rng.cuda.{index}"] = state
    return out


def restore_rng_state(extra: Mapping[str, torch.Tensor]) -> None:
    """Restore whatever ``capture_rng_state`` entries ``extra`` holds (CUDA ones only for devices present)."""
    if "rng.torch" in extra:
        torch.set_rng_state(extra["rng.torch"].to(torch.uint8))
    if "rng.python" in extra:
        version, internal, gauss = _tensor_json(extra["rng.python"])
        random.setstate((version, tuple(internal), gauss))
    if "rng.numpy" in extra:
        name, keys, pos, has_gauss, cached = _tensor_json(extra["rng.numpy"])
        np.random.set_state((name, np.array(keys, dtype=np.uint32), pos, has_gauss, cached))
    if torch.cuda.is_available():
        for name, state in extra.items():
            if name.startswith("rng.cuda.") and int(name.rsplit(".", 1)[1]) < torch.cuda.device_count():
                torch.cuda.set_rng_state(state.to(torch.uint8), int(name.rsplit(".", 1)[1]))


def policy_from_training_checkpoint(path: str | Path) -> tuple[DynEnvAgent, dict[str, Any]]:
    """The policy of a training checkpoint — a ``step_*`` folder, or a run folder or its ``checkpoints`` folder (then
    the latest valid one) — in eval mode on the CPU, with the checkpoint's meta: to evaluate a run part-way, or one
    stopped before it wrote ``policy.safetensors``. The agent is rebuilt from the config the checkpoint carries.
    ValueError for a missing, damaged or foreign checkpoint, or weights that do not fit."""
    meta = read_checkpoint_meta(path)
    try:
        cfg = TrainConfig.from_dict(meta["config"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"checkpoint {meta['checkpoint']['path']} has no usable training config: {error}") from None
    agent = make_agent(cfg)
    meta, _ = load_training_checkpoint(meta["checkpoint"]["path"], TrainingNetworks(agent, cfg.ltp_horizon))
    return agent.eval(), meta


def policy_meta(meta: Mapping[str, Any]) -> dict[str, Any]:
    """What a policy file carries of its run: a training checkpoint's meta less the generator state (a policy file
    resumes nothing) and less the loader's record of the folder it was read from (``save_policy_from_training_
    checkpoint`` names that as ``source_checkpoint``). The trainer's end-of-run ``policy.safetensors`` has this."""
    return {k: v for k, v in meta.items() if k not in ("numpy_rng", "checkpoint")}


def save_policy_from_training_checkpoint(path: str | Path, out: str | Path) -> tuple[DynEnvAgent, dict[str, Any], str]:
    """Write the policy of a kept training checkpoint (a ``step_*`` folder, or a run folder: its latest) to ``out``
    with the meta a run's own end-of-run policy file carries (``policy_meta``), plus ``source_checkpoint``: the
    folder, its step, format, code revision and creation time, and the SHA-256 of its ``model.safetensors`` (the
    digest a ``dynenv-eval`` of the checkpoint records, so its evaluations can be told apart from the file's).
    Why: a run's best policy by validation is often one of its checkpoints, not its end. Returns (the agent, in eval
    mode on the CPU, the meta written, the file's SHA-256); ValueError as ``policy_from_training_checkpoint``."""
    agent, meta = policy_from_training_checkpoint(path)
    record = meta["checkpoint"]
    source = {**record, "model_sha256": sha256(Path(record["path"]) / MODEL_FILE)}
    written = {**policy_meta(meta), "source_checkpoint": source}
    return agent, written, save_policy(agent, out, written)
