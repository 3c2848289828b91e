"""The one place actions are drawn (issue 40): the learner's ``DynEnvAgent.act`` and the ``sample_actions`` of
``soccer.agent_actions`` and ``driving.agent_actions`` (the policy node's and the export checks' samplers) turn their
heads into ``draw_actions``'s arguments and call it, so the tensor operations and the generator's draws are written
once.

What differs between the callers stays with them, so that each draws the numbers it drew before: how a categorical
head's probabilities are computed (the learner's ``Categorical.probs``, the node's softmax of its finite-masked
outputs), the noise's dtype and shape (a driving node draws its three dimensions at once in float64, the learner one
draw per dimension in torch's default float32), the bounds, and what the drawn columns become (docs/decisions.md,
"One head conversion, one sampler per scenario"). Here because ``core`` is the lowest layer the agent and both
worlds may import (.importlinter); like soccer's sampler, it imports torch only when it draws, so core and the soccer
world still load without torch.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:      # imported where actions are drawn: core's modules load without torch (test_layout)
    import torch


@dataclass(frozen=True)
class Gaussian:
    """A Gaussian head: its draw is ``mean + std · noise`` (noise of ``mean``'s shape, in ``noise_dtype``, None:
    torch's default dtype) clipped to [low, high] — numbers, or tensors that broadcast against ``mean``."""
    mean: torch.Tensor
    std: torch.Tensor
    low: float | torch.Tensor
    high: float | torch.Tensor
    noise_dtype: torch.dtype | None = None


def draw_actions(heads: Sequence[torch.Tensor | Gaussian], generator: torch.Generator | None, greedy: bool
                 ) -> list[torch.Tensor]:
    """One column per head, in the heads' order: a categorical head given as its (B, K) probabilities becomes its
    (B,) int64 choice — ``torch.multinomial`` with ``generator``, or the most probable (the first of equals) when
    ``greedy``, which draws nothing —; a ``Gaussian`` becomes its clipped draw, the mean when ``greedy``. A Gaussian
    draws its noise from the generator even when greedy (the learner always has: a generator shared across calls
    gives the same numbers afterwards whichever way the previous call went)."""
    import torch
    columns = []
    for head in heads:
        if isinstance(head, Gaussian):
            noise = torch.randn(head.mean.shape, generator=generator, dtype=head.noise_dtype,
                                device=head.mean.device)
            value = head.mean if greedy else head.mean + head.std * noise
            # torch's stubs type clamp's bounds as two numbers or two tensors, not the union; it takes either
            columns.append(value.clamp(head.low, head.high))  # type: ignore[arg-type]
        elif greedy:
            columns.append(head.argmax(-1))
        else:
            columns.append(torch.multinomial(head, 1, generator=generator).squeeze(-1))
    return columns
