"""Issue 27 item 3 on the ROS path, as the attacker: a second process publishes forged Actions for periods that
have not run yet (log_prob −1e30, value 3e38, and plausible ones) and forged NaN / huge rewards into a running
train graph without secrets. Learning goes on, every refusal is counted in the diagnostics, the plausible forged
actions reach the trainer first but the step is the action the simulator ran (the one its feedback names by
digest), and the weights and the files stay finite. With secrets: test_action_auth_graph.py."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.learning.run import checkpoints
from ros_harness import ATTACKER_OUTLIVES_THE_TEST_S, spin_until
from test_trainer_node import _game, _trainer

ATTACKER = Path(__file__).with_name("poison_attacker.py")


def _executed(sim) -> dict[tuple[int, int, int], float]:
    """(robot_id, episode, period) -> log_prob of the action the simulator accepted, so ran (stepped mode): the
    simulator's own record, beside the digests its feedback carries."""
    ran: dict[tuple[int, int, int], float] = {}
    deliver = sim.action_inbox._deliver

    def spy(robot, msg) -> None:
        before = sim.session.counts["accepted"]
        deliver(robot, msg)
        if sim.session.counts["accepted"] > before:
            ran[(int(msg.robot_id), int(msg.episode_id), int(msg.motion_period))] = msg.log_prob
    sim.action_inbox._deliver = spy
    return ran


def test_forged_actions_and_rewards_from_another_process_cannot_kill_learning(make_node, executor, tmp_path):
    run = tmp_path / "run"
    trainer = _trainer(make_node, executor, run, variant="baseline", feature_size=16)
    learnt = []
    put = trainer.background.put
    trainer.background.put = lambda sequences: (learnt.extend(sequences), put(sequences))[1]
    attacker = subprocess.Popen([sys.executable, str(ATTACKER), "team_a_0", str(ATTACKER_OUTLIVES_THE_TEST_S)],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        sim, _ = _game(make_node, executor, seed=5, trusted=tmp_path / "keys")
        ran = _executed(sim)
        counts = trainer.assembler.counts
        assert spin_until(executor, lambda: trainer.message_trainer.progress.updates >= 6 and counts["out_of_range"] >= 20
                          and counts["malformed"] >= 10 and counts["rivals_resolved"] >= 5, 300.0), \
            trainer.diagnostics()
    finally:
        attacker.kill()
        output = attacker.communicate(timeout=10)[0]
    diagnostics = trainer.diagnostics()
    assert not trainer.background.error, diagnostics
    assert int(diagnostics["out_of_range"]) >= 20 and diagnostics["last_refused"], diagnostics
    assert int(diagnostics.get("nonfinite_loss_skipped", 0)) == 0, diagnostics      # refused before learning
    # the plausible forgeries (log_prob -0.5) reached the trainer first; each step is the action the simulator ran
    # (the feedback names it by digest). Without secrets a forgery that reaches the simulator in its own period
    # runs — and is then what happened — but one sent early never pushes out the real answer.
    assert int(diagnostics["rival_answers"]) >= 5 and int(diagnostics["contested_cuts"]) == 0, diagnostics
    checked = 0
    for sequence in learnt:
        robot_id = int(sequence.stream[1] == "team_b_0")
        for t, (episode, period) in enumerate(sequence.keys[:-1]):
            key = (robot_id, episode, period + 1)
            assert key in ran and sequence.log_probs[t] == np.float32(ran[key]), (key, sequence.log_probs[t])
            checked += 1
    assert checked >= 20, checked
    for name, tensor in trainer.message_trainer.agent.state_dict().items():
        assert bool(torch.isfinite(tensor).all()), name
    sequences_ok = [s for s in trainer.message_trainer.last_stats.values() if isinstance(s, float)]
    assert all(torch.isfinite(torch.tensor(sequences_ok))), trainer.message_trainer.last_stats
    trainer.message_trainer.save_checkpoint()
    trainer.destroy_node()                       # writes policy.safetensors: loadable, so finite
    load_policy(run / "policy.safetensors")
    assert checkpoints.list_checkpoints(run), output
