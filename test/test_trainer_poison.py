"""Issue 27 item 3 on the ROS path, as the attacker: a second process publishes forged Actions for periods that
have not run yet (log_prob −1e30, value 3e38, and plausible ones) and forged NaN / huge rewards into a running
train graph. Learning goes on, every refusal is counted in the diagnostics, and the weights and the files stay
finite."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import torch

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.learning import checkpoints
from ros_harness import spin_until
from test_trainer_node import _game, _trainer

ATTACKER = Path(__file__).with_name("poison_attacker.py")


def test_forged_actions_and_rewards_from_another_process_cannot_kill_learning(make_node, executor, tmp_path):
    run = tmp_path / "run"
    trainer = _trainer(make_node, executor, run, variant="baseline", feature_size=16)
    attacker = subprocess.Popen([sys.executable, str(ATTACKER), "team_a_0", "60"], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
    try:
        _game(make_node, executor, seed=5)
        counts = trainer.assembler.counts
        assert spin_until(executor, lambda: trainer.learner.updates >= 6 and counts["out_of_range"] >= 20
                          and counts["malformed"] >= 10, 150.0), trainer.diagnostics()
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    diagnostics = trainer.diagnostics()
    assert not trainer.background.error, diagnostics
    assert int(diagnostics["out_of_range"]) >= 20 and diagnostics["last_refused"], diagnostics
    assert int(diagnostics.get("nonfinite_loss_skipped", 0)) == 0, diagnostics      # refused before learning
    for name, tensor in trainer.learner.agent.state_dict().items():
        assert bool(torch.isfinite(tensor).all()), name
    sequences_ok = [s for s in trainer.learner.last_stats.values() if isinstance(s, float)]
    assert all(torch.isfinite(torch.tensor(sequences_ok))), trainer.learner.last_stats
    trainer.learner.save_checkpoint()
    trainer.destroy_node()                       # writes policy.safetensors: loadable, so finite
    load_policy(run / "policy.safetensors")
    assert checkpoints.list_checkpoints(run), output
