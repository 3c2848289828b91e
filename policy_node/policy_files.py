"""The policy a policy node acts with, from a file or untrained: ROS-free. A .safetensors policy file runs in torch
(``agent.checkpoint``: no pickle), an .onnx file in onnxruntime; either way the policy must pass the node's check
(a trial decision, ``batch_policy.BatchPolicy.check``) before it may act, and anything a hostile or broken file
provokes is a ValueError with a one-line reason, never a crash.
"""
from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

import torch

from dynenv_ros.scenarios import Scenario
from dynenv_ros.agent.checkpoint import load_policy, policy_from_bytes, sha256
from dynenv_ros.agent.export import TorchPolicy
from dynenv_ros.agent.network import DynEnvAgent
from policy_node.batch_policy import one_line

RUNTIMES = ("torch", "onnxruntime")


def runtime_of(path: str) -> str:
    """The runtime a policy file needs: an .onnx file runs in onnxruntime, anything else (safetensors) in torch."""
    return "onnxruntime" if path.lower().endswith(".onnx") else "torch"


def version_of(meta: dict[str, Any]) -> int:
    """A policy file's version: 1 + the updates its training recorded (``meta["updates"]``), 1 if unknown."""
    updates = meta.get("updates", 0)
    if isinstance(updates, bool) or not isinstance(updates, int) or not 0 <= updates < 2**32 - 1:
        return 1
    return updates + 1


def load(path: str, runtime: str, check: Callable[[Any], None], data: bytes | None = None):
    """(policy, sha256, version) of a file that passed every check; ValueError with a one-line reason
    otherwise. ``data``: the file's bytes already read (and their signature checked): nothing is read again."""
    if runtime not in RUNTIMES:
        raise ValueError(f"runtime must be one of {RUNTIMES}, got {runtime!r}")
    suffix = path.lower().rsplit(".", 1)[-1] if "." in path else ""
    if runtime == "torch" and suffix == "onnx":
        raise ValueError(f"{path} is an ONNX file: load it with runtime onnxruntime (the torch runtime loads "
                         f".safetensors policy files)")
    if runtime == "onnxruntime" and suffix in ("safetensors", "pt", "pth"):
        raise ValueError(f"{path} is a torch policy file: load it with runtime torch, or export it to ONNX "
                         f"(dynenv_ros.agent.export.export_onnx)")
    try:
        version = 1
        if runtime == "torch":
            agent, meta = load_policy(path) if data is None else policy_from_bytes(data, f"policy file {path}")
            policy, version = TorchPolicy(agent), version_of(meta)
        else:
            from dynenv_ros.agent.export import OnnxPolicy
            policy = OnnxPolicy(path, data=data)
        check(policy)
        digest = sha256(path) if data is None else hashlib.sha256(data).hexdigest()
    except ValueError as error:
        raise ValueError(one_line(error)) from None
    except Exception as error:           # anything else a hostile or broken file provokes: refused, not fatal
        raise ValueError(f"cannot load {path}: {type(error).__name__}: {one_line(error)}") from None
    return policy, digest, version


def untrained(scenario: Scenario, action_mode: str, seed: int) -> TorchPolicy:
    """Untrained weights of ``scenario``'s network from ``seed`` (smoke tests only: no checkpoint given;
    ``action_mode``: driving's heads)."""
    torch.manual_seed(seed)
    return TorchPolicy(DynEnvAgent(scenario=scenario.policy_metadata_name(), action_mode=action_mode))


__all__ = ["RUNTIMES", "load", "runtime_of", "untrained", "version_of"]
