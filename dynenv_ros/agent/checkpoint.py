"""Agent checkpoints: a plain dict of tensors and numbers, loaded with ``torch.load(weights_only=True)`` so a
checkpoint can never run code; written atomically so a crash mid-write leaves the previous file intact."""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import torch

from dynenv_ros.agent.network import DynEnvAgent

FORMAT = "dynenv_agent/1"


def save_checkpoint(model: DynEnvAgent, path: str | os.PathLike[str], extra: dict[str, Any] | None = None) -> str:
    """Write ``path`` (via ``path.tmp`` and a rename); return its SHA-256."""
    target = Path(path)
    if not target.parent.is_dir():
        raise ValueError(f"cannot write checkpoint {target}: folder {target.parent} does not exist")
    payload = {"format": FORMAT,
               "config": {"feature_size": model.feature_size, "head_mode": model.head_mode,
                          "head_units": (model.head_head.out_features - 1) // 2 if model.head_mode == "discrete"
                          else 3, "head_max": float(model.head_max)},
               "state_dict": model.state_dict(), "extra": dict(extra or {})}
    tmp = target.with_name(target.name + ".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, target)
    return sha256(target)


def sha256(path: str | os.PathLike[str]) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def load_checkpoint(path: str | os.PathLike[str]) -> DynEnvAgent:
    """The model in eval mode. Refuses missing, corrupt, foreign or code-carrying files with a clear ValueError."""
    source = Path(path)
    if not source.is_file():
        raise ValueError(f"checkpoint {source} does not exist")
    try:
        payload = torch.load(source, map_location="cpu", weights_only=True)
    except Exception as error:       # unpickling refused or a damaged file: never fall back to full pickle
        raise ValueError(f"checkpoint {source} cannot be read safely: {type(error).__name__}: "
                         f"{str(error).splitlines()[0] if str(error) else ''}") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"checkpoint {source} is not a {FORMAT} checkpoint")
    config = payload.get("config", {})
    try:
        model = DynEnvAgent(**config)
        model.load_state_dict(payload["state_dict"])
    except (TypeError, KeyError, RuntimeError) as error:
        raise ValueError(f"checkpoint {source} does not fit the agent: {str(error).splitlines()[0]}") from None
    return model.eval()
