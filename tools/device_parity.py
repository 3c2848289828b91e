#!/usr/bin/env python3
"""CPU against CUDA on one seed: the first A2C rollout of 2 worlds (share of equal sampled actions, largest value
difference) and one update's losses, as JSON. Run by tools/gpu_check.sh on a machine with a GPU."""
import json
import tempfile

import numpy as np

from dynenv_ros.learning.config import load_config
from dynenv_ros.learning.train_cli import preset_path
from dynenv_ros.learning.trainer import Trainer
from dynenv_ros.learning.algo.ppo import update
out = {}
for dev in ("cpu", "cuda"):
    cfg = load_config(preset_path("paper_a2c"), [f"device={dev}", "backend=inprocess", "num_envs=2",
                                                 "log_every_updates=1000000", "checkpoint_every_minutes=1000000"])
    with tempfile.TemporaryDirectory() as d:
        tr = Trainer(cfg, d, progress=False)
        tr.networks.eval()
        r = tr.source.collector.collect(cfg.rollout_length)
        tr.networks.train()
        st = update(tr.networks, tr.optimizer, r.as_tensors(tr.device), tr.settings, tr.generator)
        out[dev] = (r.actions.copy(), r.values.copy(), {k: float(v) for k, v in st.items() if "loss" in k})
        tr.close()
a0, v0, l0 = out["cpu"]
a1, v1, l1 = out["cuda"]
print(json.dumps({"actions_equal_fraction": float((a0 == a1).mean()), "values_max_abs_diff": float(np.abs(v0 - v1).max()),
                  "losses_cpu": l0, "losses_cuda": l1}, indent=1))
