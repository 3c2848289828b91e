"""What the soccer and the driving evaluations play with: the seeds of one episode (common random numbers), a
uniform random action, and the evaluated policy loaded from a policy file or a training checkpoint. ROS-free; torch
is imported only when a policy is loaded.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np


# -- seeding -----------------------------------------------------------------------------------------------------
def episode_seeds(seed: int, episode: int) -> tuple[int, np.random.SeedSequence, np.random.SeedSequence]:
    """(env reset seed, evaluated team's SeedSequence, opponent's SeedSequence) of episode ``episode`` of seed
    ``seed``: the three children of ``SeedSequence(seed, spawn_key=(episode,))``."""
    env_ss, evaluated, opponent = np.random.SeedSequence(seed, spawn_key=(episode,)).spawn(3)
    return int(env_ss.generate_state(1, np.uint32)[0]), evaluated, opponent


# -- random actions ----------------------------------------------------------------------------------------------
def sample_space(space: Any, rng: np.random.Generator) -> Any:
    """A uniform sample of a gymnasium MultiDiscrete, Discrete, Box or Dict space from ``rng``."""
    from gymnasium import spaces
    if isinstance(space, spaces.MultiDiscrete):
        return (space.start + rng.integers(space.nvec)).astype(np.int64)
    if isinstance(space, spaces.Discrete):
        return int(space.start + rng.integers(space.n))
    if isinstance(space, spaces.Box):
        return rng.uniform(space.low, space.high).astype(space.dtype)
    if isinstance(space, spaces.Dict):
        return {key: sample_space(sub, rng) for key, sub in space.spaces.items()}
    raise ValueError(f"cannot sample a {type(space).__name__} action space")


# -- the evaluated policy ----------------------------------------------------------------------------------------
def load_evaluated_policy(spec: str | os.PathLike[str]) -> tuple[Any, str]:
    """A policy file (``policy.safetensors``), or a training checkpoint folder — a ``step_*`` folder, or a run
    folder (its latest checkpoint) — rebuilt by ``learning.run.checkpoints.policy_from_training_checkpoint``; and the
    SHA-256 of the weights file it came from (recorded in the result)."""
    from dynenv_ros.agent.checkpoint import load_policy, sha256
    if Path(spec).is_dir():
        from dynenv_ros.learning.run.checkpoints import MODEL_FILE, policy_from_training_checkpoint
        model, meta = policy_from_training_checkpoint(spec)
        return model, sha256(Path(meta["checkpoint"]["path"]) / MODEL_FILE)
    return load_policy(spec)[0], sha256(spec)


__all__ = ["episode_seeds", "sample_space", "load_evaluated_policy"]
