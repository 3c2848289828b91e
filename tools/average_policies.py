#!/usr/bin/env python3
"""One policy whose weights are the uniform mean of several policies' weights (stochastic weight averaging,
Izmailov et al. 2018, over the kept checkpoints of one run).

Usage::

    .venv/bin/python tools/average_policies.py OUT.safetensors POLICY_OR_CHECKPOINT [POLICY_OR_CHECKPOINT ...]

Each input is what ``dynenv-eval`` takes: a policy file, or a training checkpoint (a ``step_*`` folder, or a run
folder: its latest checkpoint). Every input must describe the same network (the agent's config); the averaged file
records the SHA-256 of each input's weights file in its meta (``averaged_from``). Why a tool: averaging the
checkpoints of a run whose play swings from checkpoint to checkpoint is a choice that costs no training, to be made
on validation games like any other (docs/results.md, "Learning beyond the teacher").
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def average_state(states: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The uniform mean of floating-point tensors (summed in float64), the first state's others (integer buffers)."""
    import torch
    if not states:
        raise ValueError("nothing to average: give at least one policy")
    keys = set(states[0])
    for index, state in enumerate(states[1:], start=1):
        if set(state) != keys:
            raise ValueError(f"input {index + 1} has other tensors than input 1: not the same network")
        for name in keys:
            if state[name].shape != states[0][name].shape:
                raise ValueError(f"input {index + 1}'s {name} has shape {tuple(state[name].shape)}, input 1's "
                                 f"{tuple(states[0][name].shape)}: not the same network")
    out = {}
    for name, first in states[0].items():
        if first.is_floating_point():
            out[name] = (torch.stack([s[name].double() for s in states]).mean(0)).to(first.dtype)
        else:
            out[name] = first.clone()
    return out


def average_policies(out: Path, inputs: Sequence[str]) -> str:
    """Write the averaged policy to ``out``; its SHA-256."""
    from dynenv_ros.agent.checkpoint import agent_config, save_policy
    from dynenv_ros.evaluation.episodes import load_evaluated_policy
    loaded = [load_evaluated_policy(spec) for spec in inputs]
    configs = [agent_config(model) for model, _ in loaded]
    for index, config in enumerate(configs[1:], start=1):
        if config != configs[0]:
            raise ValueError(f"input {index + 1} ({inputs[index]}) is another network than input 1 ({inputs[0]}): "
                             f"{config} against {configs[0]}")
    model = loaded[0][0]
    model.load_state_dict(average_state([m.state_dict() for m, _ in loaded]))
    return save_policy(model, out, {"averaged_from": [digest for _, digest in loaded],
                                    "averaged_inputs": [str(spec) for spec in inputs]})


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the averaged policy file (.safetensors)")
    parser.add_argument("inputs", nargs="+", help="policy files or training checkpoints, as dynenv-eval takes them")
    args = parser.parse_args(argv)
    try:
        digest = average_policies(args.out, args.inputs)
    except ValueError as error:
        print(f"average_policies: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} (sha256 {digest}), the mean of {len(args.inputs)} policies")
    return 0


if __name__ == "__main__":
    sys.exit(main())
