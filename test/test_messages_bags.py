"""Learning from recorded bags (``dynenv-train --from-bag``): the sample bag gives the same sequences the trainer
node would build live — the recorded actions as labels, the ground truth as targets — and behaviour cloning on
them lowers the imitation and localization losses and writes a policy file a policy node loads."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.bags.inspect import open_bag
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.messages.bags import bag_layout, bag_sequences, train_from_bags
from dynenv_ros.learning.train_cli import main as train_main

SAMPLE = Path(__file__).resolve().parent.parent / "bags" / "sample_2v2_realistic_30s"
HEAD_STEP = 0.6544984694978736 / 3          # the discrete head: 37.5° in 3 steps each way
T = 6


def _recorded(topic: str) -> list:
    with open_bag(SAMPLE) as bag:
        wanted = [c for c in bag.connections if c.topic == topic]
        return [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages(wanted)]


def test_the_sample_bag_gives_sequences_of_its_recorded_actions_and_ground_truth():
    # the sample bag (bags/README.md): one 30-s 2v2 episode, 5 frames per period, 61 observations (periods 0..60)
    assert bag_layout([SAMPLE]) == (2, 5)
    sequences, counts = bag_sequences([SAMPLE], T, 2, 5, with_targets=True)
    # 60 steps per robot (observations 0..59; 60 is the final one); a whole sequence also needs the observation
    # after its last step, which the 10th lacks (no next episode): 9 sequences of 6 per robot, 6 steps unused each
    assert len(sequences) == 4 * 9 and counts["steps_unused"] == 4 * 6
    assert counts["missing"] == 0 and counts["malformed"] == 0
    actions = {a.motion_period: a for a in _recorded("/team_a_1/action")}
    frames = {m.motion_period: m for m in _recorded("/team_a_1/detections") if m.frame_index == 4}
    truth = {(w.header.stamp.sec, w.header.stamp.nanosec): w for w in _recorded("/world_state")}
    mine = sorted((s for s in sequences if s.stream[1] == "team_a_1"), key=lambda s: s.index)
    for n, sequence in enumerate(mine):
        for t in range(T):
            period = n * T + t
            recorded = actions[period + 1]
            head_index = max(0, min(6, round(recorded.head_yaw_delta / HEAD_STEP) + 3))
            assert tuple(sequence.actions[t]) == (recorded.walk, recorded.turn, recorded.kick, head_index)
            stamp = frames[period].header.stamp
            me = next(o for o in truth[(stamp.sec, stamp.nanosec)].objects if o.id == 1)   # team A: field frame
            assert sequence.targets["pose"][t][:2] == pytest.approx((me.x, me.y), abs=1e-4)


def test_cloning_the_recorded_team_lowers_its_losses_and_writes_a_policy(tmp_path):
    cfg = TrainConfig(rollout_length=T, feature_size=32, learning_rate=3e-3, seed=1)
    summary = train_from_bags(cfg, [SAMPLE], tmp_path / "run", epochs=6, batch_sequences=12,
                              learns=lambda name: name.startswith("team_b"))
    assert summary["sequences"] == 2 * 9
    first, last = summary["first_epoch"], summary["last_epoch"]
    assert last["imitation_loss"] < 0.8 * first["imitation_loss"], summary
    assert last["localization_loss"] < first["localization_loss"], summary
    agent, meta = load_policy(tmp_path / "run" / "policy.safetensors")
    assert agent.feature_size == 32 and meta["source"] == "bags" and meta["updates"] == summary["updates"]
    assert (tmp_path / "run" / "metrics.csv").is_file()


def test_the_cli_learns_from_a_bag_and_refuses_what_is_not_one(tmp_path, capsys):
    status = train_main(["--from-bag", str(SAMPLE), "--run-dir", str(tmp_path / "bc"), "--epochs", "1",
                         "--set", "rollout_length=6", "--set", "feature_size=16"])
    out = capsys.readouterr().out
    assert status == 0 and "36 sequences (216 robot-periods)" in out and "imitation_loss" in out, out
    assert json.loads((tmp_path / "bc" / "summary.json").read_text())["epochs"] == 1
    (tmp_path / "empty").mkdir()
    assert train_main(["--from-bag", str(tmp_path / "empty"), "--run-dir", str(tmp_path / "x")]) == 2
    assert "dynenv-train:" in capsys.readouterr().err
    assert train_main(["--from-bag", str(SAMPLE), "--run-dir", str(tmp_path / "bc"), "--epochs", "1"]) == 2
    assert "already holds a run" in capsys.readouterr().err
