"""How much disk a training run needs, estimated before it starts, so that a run that would fill the disk part-way is
refused up front (``core.writable.check_free_space``) instead of stopping at its first or fifth checkpoint.

A checkpoint holds the learner's parameters (the policy and the learning heads) and Adam's two moments of every
trainable one, float32, and against snapshots (or the league) the pool of ``snapshot_pool`` policy copies; the run also writes the policy file and its ONNX export, and logs (metrics, TensorBoard),
which ``LOG_BYTES`` bounds generously, and the kept policies of ``keep_policy_every_env_steps``. ``keep_checkpoints + 1`` checkpoints exist at once: the new one is written
before the oldest is removed. The sizes come from the network built on torch's meta device: no memory is used.
"""
from __future__ import annotations

import torch

from dynenv_ros.learning.algo.networks import make_agent
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.algo.networks import TrainingNetworks

FLOAT_BYTES = 4
LOG_BYTES = 32 * 2**20      # metrics.csv and TensorBoard of a long run (a 700 k-step run wrote 0.6 MB)


def run_disk_bytes(cfg: TrainConfig) -> tuple[int, str]:
    """(bytes a run of ``cfg`` needs on disk, how that number is made up, for the refusal's message)."""
    with torch.device("meta"):
        networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon)
    parameters = sum(p.numel() for p in networks.parameters())
    trainable = sum(p.numel() for p in networks.parameters() if p.requires_grad)
    policy = sum(p.numel() for p in networks.agent.parameters())
    checkpoint = FLOAT_BYTES * (parameters + 2 * trainable)
    if cfg.opponent in ("snapshot", "league"):      # the snapshot pool (run.snapshot_history)
        checkpoint += FLOAT_BYTES * cfg.snapshot_pool * sum(p.numel() for p in networks.agent.state_dict().values())
    copies = cfg.keep_checkpoints + 1
    policy_files = 2 + (cfg.best_policy_window is not None)        # safetensors, ONNX, best_policy.safetensors
    if cfg.keep_policy_every_env_steps is not None:                # kept_policies/, one per multiple passed
        policy_files += cfg.total_env_steps // cfg.keep_policy_every_env_steps
    total = copies * checkpoint + policy_files * FLOAT_BYTES * policy + LOG_BYTES
    return total, (f"{copies} checkpoints of {checkpoint / 2**20:.1f} MB, the policy files and "
                   f"{LOG_BYTES // 2**20} MB of logs")
