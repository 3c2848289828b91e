#!/usr/bin/env python3
"""The files a shipped policy folder holds, written from a kept training checkpoint: ``policy.safetensors``,
``policy.onnx``, ``train_config.json`` and ``train_summary.json`` — what a run writes at its end, for a checkpoint
in its middle.

Usage::

    .venv/bin/python tools/policy_from_checkpoint.py CHECKPOINT FOLDER

CHECKPOINT is a ``step_*`` folder of a run (or a run folder: its latest checkpoint), or a kept policy file
(``kept_policies/step_*.safetensors``, or its committed copy: a policy file the trainer wrote, meta and all, which is
copied byte for byte, so that its SHA-256 stays the one its evaluations recorded); it is only read. Why a tool:
the best policy by validation is often one of a run's kept checkpoints, not its end (docs/results.md, "Learning
beyond the teacher"), and the folder it ships in must carry what a run's own end-of-run files carry, so that
tools/pretrained_readme.py can describe it from its files:

- ``policy.safetensors``: the checkpoint's policy with the run's meta as the trainer writes it at the end
  (``checkpoints.policy_meta``) plus ``source_checkpoint`` (the folder, step, code revision and the SHA-256 of its
  ``model.safetensors``: the digest that evaluations of the checkpoint record);
- ``policy.onnx``: ``export_onnx`` with its defaults, as the trainer exports at a run's end;
- ``train_config.json``: the training config of the header;
- ``train_summary.json``: the run's counters at the checkpoint (env steps, updates, episodes, wall seconds, the
  measured compute) and the SHA-256 of the ``init_policy`` file it started from, where it names one.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

SUMMARY_KEYS = ("env_steps", "updates", "episodes", "wall_seconds", "compute")


def training_summary(meta: dict[str, Any], root: Path = ROOT) -> dict[str, Any]:
    """A run's summary at a checkpoint, from the policy meta: the trainer's summary keys the meta holds, and the
    init policy's SHA-256 (the file the config names, read relative to ``root``; refused when it is missing)."""
    from dynenv_ros.agent.checkpoint import sha256
    summary = {key: meta[key] for key in SUMMARY_KEYS if key in meta}
    init = (meta.get("config") or {}).get("init_policy")
    if init:
        path = Path(init) if Path(init).is_absolute() else root / init
        if not path.is_file():
            raise ValueError(f"the run started from {init}, which is not here: its sha256 cannot be recorded")
        summary["init_policy_sha256"] = sha256(path)
    return summary


def copy_kept_policy(path: Path, out: Path) -> tuple[Any, dict[str, Any], str]:
    """A kept policy file copied to ``out`` as it is: (the agent, its header's training meta, its SHA-256). Refused
    when it lacks the training meta a run's policy file carries (its config above all: the README needs it)."""
    from dynenv_ros.agent.checkpoint import load_policy, sha256
    agent, meta = load_policy(path)
    if not (meta or {}).get("config"):
        raise ValueError(f"{path} carries no training config in its header: not a policy file a run wrote")
    out.write_bytes(path.read_bytes())
    return agent, meta, sha256(out)


def write_folder(checkpoint: Path, folder: Path) -> dict[str, str]:
    """Write the four files into ``folder`` (which must exist); their SHA-256s by name."""
    from dynenv_ros.agent.checkpoint import sha256
    from dynenv_ros.agent.export import export_onnx
    from dynenv_ros.learning.run.checkpoints import save_policy_from_training_checkpoint
    if not folder.is_dir():
        raise ValueError(f"folder {folder} does not exist")
    summary_path, config_path = folder / "train_summary.json", folder / "train_config.json"
    if checkpoint.is_file():
        agent, meta, digest = copy_kept_policy(checkpoint, folder / "policy.safetensors")
    else:
        agent, meta, digest = save_policy_from_training_checkpoint(checkpoint, folder / "policy.safetensors")
    summary = training_summary(meta)
    export_onnx(agent, folder / "policy.onnx")
    config_path.write_text(json.dumps(meta["config"], indent=2) + "\n")
    summary_path.write_text(json.dumps(summary, indent=2) + "\n")
    return {"policy.safetensors": digest, "policy.onnx": sha256(folder / "policy.onnx"),
            "train_config.json": sha256(config_path), "train_summary.json": sha256(summary_path)}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a training checkpoint (step_* folder), a run folder, or a kept "
                                                      "policy file (copied as it is)")
    parser.add_argument("folder", type=Path, help="where the files go (an existing folder)")
    args = parser.parse_args(argv)
    try:
        written = write_folder(args.checkpoint, args.folder)
    except ValueError as error:
        print(f"policy_from_checkpoint: {error}", file=sys.stderr)
        return 2
    for name, digest in written.items():
        print(f"wrote {args.folder / name} (sha256 {digest})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
