"""Learning from a recorded driving bag (``dynenv-train --from-bag`` with a driving config): a game of the scripted
drivers recorded in-process gives each car's sequences of its recorded commands (as the discrete choices they are),
behaviour cloning on them (either action mode) lowers the imitation loss and writes a driving policy, and a bag of
the other scenario than the config's — or ``--team`` on a driving bag — is refused with the reason."""
from __future__ import annotations

import json

from rclpy.parameter import Parameter

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.bags.inspect import open_bag
from dynenv_ros.learning.messages.bags import bag_layout, bag_scenario, bag_sequences
from dynenv_ros.learning.train_cli import main as train_main
from experience_game import W
from ros_harness import spin_until

PERIODS = 30          # 3 s of 100 ms periods, one episode
T = 6
ACCELERATION = {-1.0: 0, 0.0: 1, 1.0: 2}      # throttle of the nine commands → the acceleration choice


def _record(make_node, executor, bag) -> None:
    from dynenv_ros.nodes.recorder import Recorder
    from dynenv_ros.nodes.sim_node import SimNode
    from policy_node.scripted_driver import ScriptedDriverNode
    recorder = make_node(Recorder, exit_when_done=False,
                         parameter_overrides=[Parameter("output", Parameter.Type.STRING, str(bag))])
    driver = make_node(ScriptedDriverNode, parameter_overrides=[Parameter("n_cars", value=2)])
    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in {
        "scenario": "driving", "n_cars": 2, "seed": 3, "episode_seconds": PERIODS / 10, "auto_reset": False,
        "publish_markers": False, "wait_for_subscribers": 2, "wait_for_ground_truth_subscribers": 2,
        "wait_for_recorder": True}.items()])
    for node in (recorder, driver, sim):
        executor.add_node(node)
    assert spin_until(executor, lambda: sim.session.finished, 30.0), dict(sim.session.counts)
    assert spin_until(executor, lambda: all(recorder.counts.get(f"/car_{i}/feedback") == PERIODS + 1
                                            for i in range(2)), 10.0), recorder.counts
    recorder.finish()


def _recorded(bag, topic: str) -> list:
    with open_bag(bag) as reader:
        wanted = [c for c in reader.connections if c.topic == topic]
        return [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(wanted)]


def test_a_driving_bag_is_cloned_into_a_driving_policy(make_node, executor, tmp_path, capsys):
    bag = tmp_path / "drive"
    _record(make_node, executor, bag)
    assert bag_scenario([bag]) == "driving" and bag_layout([bag], "driving") == (2, 1)
    sequences, counts = bag_sequences([bag], T, 2, 1, with_targets=False, scenario="driving")
    assert counts["missing"] == 0 and counts["malformed"] == 0 and counts["actions_rounded"] == 0, counts
    for car in ("car_0", "car_1"):
        feedback = {f.motion_period: f for f in _recorded(bag, f"/{car}/feedback")}
        end = min([p for p, f in feedback.items() if f.terminated or f.truncated])
        actions = {a.motion_period: a for a in _recorded(bag, f"/{car}/action")}
        mine = sorted((s for s in sequences if s.stream[1] == car), key=lambda s: s.index)
        assert len(mine) == (end - 1) // T                # steps: observations 0 .. end - 1
        for n, sequence in enumerate(mine):
            for t in range(T):
                recorded = actions[n * T + t + 1]         # the answer to observation n·T + t
                assert tuple(sequence.actions[t].tolist()) == (ACCELERATION[recorded.throttle],
                                                               round(recorded.steering / W) + 1)
                assert sequence.versions[t] == 0          # the scripted drivers' actions carry no learning fields

    for mode, agreement in (("discrete", "teacher_agreement"), ("continuous", "teacher_command_error")):
        run = tmp_path / f"bc_{mode}"
        status = train_main(["--from-bag", str(bag), "--config", "driving_quick", "--run-dir", str(run), "--epochs",
                             "8", "--batch-sequences", "4", "--set", f"rollout_length={T}", "--set", "feature_size=16",
                             "--set", "learning_rate=3e-3", "--set", f"action_mode={mode}"])
        out = capsys.readouterr().out
        assert status == 0, out
        assert f"{len(sequences)} sequences ({len(sequences) * T} car-periods)" in out and agreement in out, out
        summary = json.loads((run / "summary.json").read_text())
        assert summary["scenario"] == "driving" and summary["n_cars"] == 2
        first, last = summary["first_epoch"], summary["last_epoch"]
        assert last["imitation_loss"] < 0.8 * first["imitation_loss"], summary
        assert (last[agreement] > first[agreement]) if mode == "discrete" else (last[agreement] < first[agreement])
        agent, meta = load_policy(run / "policy.safetensors")
        assert agent.scenario == "driving" and agent.action_mode == mode and meta["source"] == "bags"

    for argv, refused in ((["--config", "quick"], "the bags record driving games and the config's scenario is "
                                                   "'robocup': use --config driving_quick"),
                          (["--config", "driving_quick", "--team", "a"], "--team applies to soccer bags")):
        assert train_main(["--from-bag", str(bag), "--run-dir", str(tmp_path / "refused"), *argv]) == 2
        assert refused in capsys.readouterr().err


def test_a_soccer_bag_with_a_driving_config_is_refused(tmp_path, capsys):
    from test_messages_bags import SAMPLE
    assert train_main(["--from-bag", str(SAMPLE), "--config", "driving_quick", "--run-dir", str(tmp_path / "x")]) == 2
    assert "the bags record soccer games and the config's scenario is 'driving'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()              # refused before anything was written
