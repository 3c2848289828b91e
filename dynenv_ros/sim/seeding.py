"""Seeds as every scenario's reset and the simulator node's ResetSimulation service accept them."""
from __future__ import annotations

from typing import Any

import numpy as np

MAX_SEED = 2 ** 64 - 1      # the whole uint64 of ResetSimulation.seed and SeedSequence's child seeds


def checked_seed(seed: Any) -> int | None:
    """None, or a whole number in [0, 2^64 - 1]; floats, bools, strings and out-of-range numbers are refused with
    the reason rather than failing inside numpy's generator."""
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be a whole number in [0, 2**64 - 1] or None, got {seed!r} "
                         f"({type(seed).__name__})")
    if not 0 <= int(seed) <= MAX_SEED:
        raise ValueError(f"seed must be in [0, 2**64 - 1], got {seed}")
    return int(seed)
