"""The main job runs the soccer graph and the self-check graph end to end, refuses bad settings, and reports
failures honestly."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest

from dynenv_ros.graph.process_graph import NodeLaunch, run_graph
from dynenv_ros.main_job import ConfigError, MainJobConfig, load_config, main


def _run_main(tmp_path, capsys, *settings: str) -> str:
    """Run the main job into tmp_path on this test worker's domain; return its output (it must succeed)."""
    arguments = ["--output-dir", str(tmp_path), "--set", f"domain_id={os.environ['ROS_DOMAIN_ID']}"]
    for setting in settings:
        arguments += ["--set", setting]
    status = main(arguments)
    output = capsys.readouterr().out
    assert status == 0, output
    return output


def test_main_job_verifies_every_interface_across_processes(tmp_path, capsys):
    output = _run_main(tmp_path, capsys, "graph=selfcheck", "samples_per_type=3")
    report = json.loads((tmp_path / "selfcheck.json").read_text())
    assert report["ok"] and not report["hash_problems"]
    assert len(report["interfaces"]) == 13          # 8 messages (docs/interfaces.md) and 5 services
    assert all(entry["received"] == 3 for entry in report["interfaces"].values())
    assert "interfaces verified: 13/13" in output and "dynenv-run: OK" in output


def test_main_job_plays_records_and_replays_a_soccer_game(tmp_path, capsys):
    """The README's run command: simulator, the shipped policy for team A, scripted team B, recorder; lossless bag,
    GIF."""
    output = _run_main(tmp_path, capsys, "duration_s=5", "players_per_team=1")
    report = json.loads((tmp_path / "sim_report.json").read_text())
    assert report["diagnostics"]["periods_run"] == "10" and report["diagnostics"]["missing"] == "0"
    assert "every published message recorded" in output and "dynenv-run: OK" in output
    assert (tmp_path / "game.gif").stat().st_size > 0 and (tmp_path / "bag").is_dir()


def test_main_job_plays_records_and_replays_a_driving_game(tmp_path, capsys):
    """`make run ARGS="--set scenario=driving"`: simulator (driving), scripted drivers, recorder; lossless bag,
    GIF, and the summary's cars home, crashes, reward per car and action counts."""
    output = _run_main(tmp_path, capsys, "scenario=driving", "duration_s=3", "n_cars=3", "action_mode=continuous",
                       "car_0=scripted")
    report = json.loads((tmp_path / "sim_report.json").read_text())
    assert report["scenario"] == "driving" and report["robots"] == ["car_0", "car_1", "car_2"]
    assert report["diagnostics"]["periods_run"] == "30" and report["diagnostics"]["missing"] == "0"
    assert report["diagnostics"]["accepted"] == "90"
    episode = report["episodes"][-1]
    assert episode["periods"] == 30 and set(episode["reward_per_car"]) == {"car_0", "car_1", "car_2"}
    assert "cars home 0/3, crashed 0" in output and "reward per car: car_0 +" in output
    assert "actions accepted 90, missing 0, rejected 0" in output
    assert "every published message recorded" in output and "dynenv-run: OK" in output
    assert (tmp_path / "game.gif").stat().st_size > 0


def test_scenario_settings_are_checked_and_refused_for_the_other_scenario():
    from dynenv_ros.main_job import REPO_CONFIG, soccer_graph
    from pathlib import Path
    with pytest.raises(ConfigError, match="scenario must be one of"):
        MainJobConfig.from_mapping({"scenario": "flying"})
    with pytest.raises(ConfigError, match="n_cars must be in"):
        MainJobConfig.from_mapping({"n_cars": 11})
    with pytest.raises(ConfigError, match="action_mode must be one of"):
        MainJobConfig.from_mapping({"action_mode": "joystick"})
    with pytest.raises(ConfigError, match="players_per_team: not used by scenario 'driving'"):
        load_config(REPO_CONFIG, {"scenario": "driving", "players_per_team": 3})
    with pytest.raises(ConfigError, match="n_cars: not used by scenario 'robocup'"):
        load_config(REPO_CONFIG, {"n_cars": 3})
    with pytest.raises(ConfigError, match="scenario: not used by graph 'train'"):
        load_config(REPO_CONFIG, {"graph": "train", "scenario": "driving"})
    config = load_config(REPO_CONFIG, {"scenario": "driving", "n_cars": 4})
    nodes = {n.name: n for n in soccer_graph(config, Path("/tmp/run"))}
    assert set(nodes) == {"recorder", "policy_car_0", "scripted_driver", "sim_node"}
    assert nodes["sim_node"].parameters["scenario"] == "driving" and nodes["sim_node"].parameters["n_cars"] == 4
    assert nodes["scripted_driver"].parameters == {"n_cars": 4, "action_mode": "discrete",
                                                   "cars": ["car_1", "car_2", "car_3"]}
    shipped = nodes["policy_car_0"].parameters        # the shipped driving policy drives car_0 (issue 26)
    assert shipped["cars"] == ["car_0"] and shipped["runtime"] == "onnxruntime"
    assert shipped["checkpoint"].endswith("policy_node/pretrained/driving/policy.onnx")
    scripted = load_config(REPO_CONFIG, {"scenario": "driving", "n_cars": 1, "car_0": "scripted"})
    assert {n.name for n in soccer_graph(scripted, Path("/tmp/run"))} == {"recorder", "scripted_driver", "sim_node"}
    with pytest.raises(ConfigError, match="car_0: the shipped driving policy takes discrete actions"):
        load_config(REPO_CONFIG, {"scenario": "driving", "action_mode": "continuous"})
    with pytest.raises(ConfigError, match="car_0: not used by scenario 'robocup'"):
        load_config(REPO_CONFIG, {"car_0": "scripted"})


def test_main_job_plays_a_trained_policy_for_team_a(tmp_path, capsys):
    """team_a=<policy file>: one policy node (onnxruntime) drives team A against the scripted team B."""
    import torch
    from dynenv_ros.agent.export import export_onnx
    from dynenv_ros.agent.network import DynEnvAgent
    torch.manual_seed(0)
    policy = tmp_path / "policy.onnx"
    export_onnx(DynEnvAgent(), policy)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    output = _run_main(run_dir, capsys, "duration_s=3", "players_per_team=1", f"team_a={policy}", "gif=false")
    report = json.loads((run_dir / "sim_report.json").read_text())
    assert report["diagnostics"]["periods_run"] == "6" and report["diagnostics"]["missing"] == "0"
    assert f"teams: A {policy} (policy node, greedy actions)" in output and "dynenv-run: OK" in output


def test_main_job_plays_the_shipped_policy_through_ros_sports_messages(tmp_path, capsys):
    """interfaces=ros_sports (issue 41): team A's policy node on soccer_vision_3d_msgs, RCGCD15 and joint states,
    the motion emulator acting for its robots; every period's actions accepted, none missing, the bag complete."""
    output = _run_main(tmp_path, capsys, "duration_s=3", "players_per_team=1", "interfaces=ros_sports",
                       "policy=perceiving", "gif=false")
    report = json.loads((tmp_path / "sim_report.json").read_text())
    diagnostics = report["diagnostics"]
    assert diagnostics["periods_run"] == "6" and diagnostics["missing"] == "0" and diagnostics["accepted"] == "12"
    assert "through ros-sports messages and the motion emulator" in output
    assert "every published message recorded" in output and "dynenv-run: OK" in output


def test_main_job_plays_the_perceiving_team_on_detections_and_pose_estimates(tmp_path, capsys):
    """policy=perceiving, team_a=scripted: both teams keeper_and_chasers on their own detections and pose estimates
    (perceiving_policy nodes), none reading /world_state; the simulator's localization stays on."""
    output = _run_main(tmp_path, capsys, "duration_s=3", "policy=perceiving", "team_a=scripted", "gif=false")
    report = json.loads((tmp_path / "sim_report.json").read_text())
    assert report["diagnostics"]["periods_run"] == "6" and report["diagnostics"]["missing"] == "0"
    assert report["published"]["pose_estimates_per_robot"] > 0
    assert "teams: A perceiving, B perceiving (scripted, on its detections and pose estimates)" in output
    assert "every published message recorded" in output and "dynenv-run: OK" in output


def test_the_ros_sports_graph_puts_the_motion_emulator_between_team_as_policy_and_its_robots():
    """interfaces=ros_sports (issue 41): the simulator publishes the ros-sports messages, team A's policy node reads
    them (its grid from the first frame after the simulator's repeated instant) and its own Action goes aside; the
    motion emulator acts for team A's robots; team B and the rest of the graph are as on the native route."""
    from pathlib import Path
    from dynenv_ros.main_job import REPO_CONFIG, soccer_graph
    native = {n.name: n for n in soccer_graph(load_config(REPO_CONFIG, {"policy": "perceiving"}), Path("/r"))}
    nodes = {n.name: n for n in soccer_graph(load_config(REPO_CONFIG, {"policy": "perceiving",
                                                                       "interfaces": "ros_sports"}), Path("/r"))}
    assert set(nodes) == set(native) | {"motion_emulator"}
    assert nodes["sim_node"].parameters == {**native["sim_node"].parameters, "ros_sports": True,
                                            "wait_for_subscribers": 1}
    policy = nodes["policy_team_a"]
    assert policy.parameters == {**native["policy_team_a"].parameters, "interfaces": "ros_sports",
                                 "frame_epoch": 0.1, "class_wait": 0.5}
    assert policy.parameters["decision_deadline"] == -1.0          # a stepped game: complete periods
    assert policy.remaps == {"/team_a_0/action": "/team_a_0/policy_action",
                             "/team_a_1/action": "/team_a_1/policy_action"}
    assert native["policy_team_a"].remaps == {}
    assert nodes["motion_emulator"].parameters == {"players_per_team": 2, "team": "a"}
    assert nodes["policy_team_b_0"].parameters == native["policy_team_b_0"].parameters
    assert "-r" in policy.command() and "/team_a_0/action:=/team_a_0/policy_action" in policy.command()
    with pytest.raises(ConfigError, match="interfaces: not used by scenario 'driving'"):
        load_config(REPO_CONFIG, {"scenario": "driving", "interfaces": "ros_sports"})


def test_the_perceiving_graph_and_its_need_for_localization():
    from pathlib import Path
    from dynenv_ros.main_job import REPO_CONFIG, soccer_graph
    config = load_config(REPO_CONFIG, {"policy": "perceiving", "players_per_team": 3})
    nodes = {n.name: n for n in soccer_graph(config, Path("/tmp/run"))}
    assert nodes["policy_team_b_0"].module == "policy_node.perceiving_policy"
    assert nodes["policy_team_b_2"].parameters == {"robot": "team_b_2", "players_per_team": 3}
    assert "policy_team_a" in nodes and "policy_team_a_0" not in nodes          # team A: the shipped policy
    assert nodes["policy_team_a"].parameters["greedy"] is True       # as docs/results.md chose and evaluated it
    sampled = {n.name: n for n in soccer_graph(load_config(REPO_CONFIG, {"greedy": False}), Path("/r"))}
    assert sampled["policy_team_a"].parameters["greedy"] is False
    with pytest.raises(ConfigError, match="greedy: not used by scenario 'driving'"):
        load_config(REPO_CONFIG, {"scenario": "driving", "greedy": False})
    sim = nodes["sim_node"].parameters
    assert sim["localization"] is True and sim["wait_for_ground_truth_subscribers"] == 1     # the recorder only
    scripted = {n.name: n for n in soccer_graph(load_config(REPO_CONFIG, {"team_a": "scripted"}), Path("/r"))}
    assert scripted["sim_node"].parameters["wait_for_ground_truth_subscribers"] == 5         # 4 robots + recorder
    with pytest.raises(ConfigError, match="needs localization=true"):
        load_config(REPO_CONFIG, {"policy": "perceiving", "localization": False})
    assert not load_config(REPO_CONFIG, {"localization": False}).localization
    with pytest.raises(ConfigError, match="localization: not used by scenario 'driving'"):
        load_config(REPO_CONFIG, {"scenario": "driving", "localization": False})


def test_graph_reports_a_listener_that_does_not_get_what_it_expects(tmp_path):
    domain = int(os.environ["ROS_DOMAIN_ID"])
    nodes = [NodeLaunch("talker", "dynenv_ros.nodes.selfcheck_talker", {"seed": 1, "samples_per_type": 2}),
             NodeLaunch("listener", "dynenv_ros.nodes.selfcheck_listener",
                        {"seed": 2, "samples_per_type": 2, "timeout_s": 10.0,
                         "report_path": str(tmp_path / "report.json")}, ends_run=True)]
    outcome = run_graph(nodes, tmp_path, domain, timeout_s=30.0)
    assert not outcome.ok
    listener = next(n for n in outcome.nodes if n.name == "listener")
    assert listener.exit_code == 1
    report = json.loads((tmp_path / "report.json").read_text())
    # Different seeds: every message differs field by field (service answers depend on the request only).
    messages = {name: entry for name, entry in report["interfaces"].items() if "/msg/" in name}
    assert len(messages) == 8
    assert all(entry["problems"] and not entry["ok"] for entry in messages.values())


def test_graph_times_out_and_stops_every_process(tmp_path):
    domain = int(os.environ["ROS_DOMAIN_ID"])
    nodes = [NodeLaunch("lonely_listener", "dynenv_ros.nodes.selfcheck_listener", {"timeout_s": 600.0},
                        ends_run=True)]
    outcome = run_graph(nodes, tmp_path, domain, timeout_s=2.0)
    assert outcome.timed_out and not outcome.ok
    assert outcome.nodes[0].exit_code is None  # had to be stopped


@pytest.mark.parametrize("settings, message", [
    ({"graph": "nonexistent"}, "graph must be one of"),
    ({"samples_per_type": 0}, "samples_per_type must be in"),
    ({"timeout_s": "long"}, "timeout_s must be float"),
    ({"domain_id": 500}, "domain_id must be"),
    ({"sample_per_type": 3}, "unknown key"),
    ({"duration_s": 0.0}, "duration_s must be in"),
    ({"players_per_team": 6}, "players_per_team must be in"),
    ({"perception": "perfect"}, "perception must be one of"),
    ({"policy": "genius"}, "policy must be one of"),
    ({"team_a": "no/such/policy.onnx"}, "does not exist"),
    ({"team_a": "README.md"}, "team_a must be 'scripted' or a .onnx"),
    ({"interfaces": "ros2"}, "interfaces must be one of"),
    ({"interfaces": "ros_sports", "team_a": "scripted"}, "team_a must be a policy file"),
])
def test_bad_settings_are_refused_with_a_reason(settings, message):
    with pytest.raises(ConfigError, match=message):
        MainJobConfig.from_mapping(settings)


def test_malformed_config_file_is_refused(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("main_job: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad, {})
    result = subprocess.run([sys.executable, "-m", "dynenv_ros.main_job", "--config", str(bad)],
                            capture_output=True, text=True)
    assert result.returncode == 2 and "configuration error" in result.stderr


def test_missing_config_file_is_an_error_not_a_silent_default(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.yaml", {})


def test_repository_config_is_valid():
    from dynenv_ros.main_job import REPO_CONFIG
    assert load_config(REPO_CONFIG, {}) == MainJobConfig()


@pytest.mark.parametrize("value, reason", [("0", "out of range"), ("abc", "expecting type 'INTEGER'")])
def test_node_refuses_bad_parameter_with_reason(value, reason):
    result = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.selfcheck_talker", "--ros-args", "-p",
                             f"samples_per_type:={value}"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert "parameter error" in result.stderr and reason in result.stderr


def test_a_setting_the_chosen_graph_does_not_use_is_refused(tmp_path, capsys):
    from dynenv_ros.main_job import REPO_CONFIG
    with pytest.raises(ConfigError, match="samples_per_type: not used by graph 'soccer'"):
        load_config(REPO_CONFIG, {"samples_per_type": 3})
    with pytest.raises(ConfigError, match="duration_s, gif: not used by graph 'selfcheck'"):
        load_config(REPO_CONFIG, {"graph": "selfcheck", "duration_s": 5.0, "gif": False})
    assert load_config(REPO_CONFIG, {"graph": "selfcheck", "samples_per_type": 3}).samples_per_type == 3
    assert main(["--set", "samples_per_type=3", "--output-dir", str(tmp_path)]) == 2
    assert "not used by graph 'soccer'" in capsys.readouterr().err


def test_help_lists_every_setting_with_its_default(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    for name, value in vars(MainJobConfig()).items():
        assert f"  {name} (default {value!r};" in out, name


def _bag_with_actions(path, counts: dict[str, list[int]]) -> None:
    """A bag holding, per robot, actions for the given motion periods (episode 1)."""
    from dynenv_msgs.msg import Action
    from rclpy.serialization import serialize_message
    from dynenv_ros.bags.typestore import dynenv_typestore
    from dynenv_ros.bags.writer import BagWriter
    bag = BagWriter(str(path), dynenv_typestore())
    t = 1
    for robot, periods in counts.items():
        topic = f"/{robot}/action"
        bag.add_topic(topic, "dynenv_msgs/msg/Action")
        for period in periods:
            bag.write(topic, t, serialize_message(Action(episode_id=1, motion_period=period)))
            t += 1
    bag.close()


def test_the_recorded_actions_must_match_what_the_simulator_accepted(tmp_path):
    """The recorder once lost a policy's first 12 actions while the simulator counted them accepted; the main job
    now compares the two. An answer to the last frames (a period that never ran) does not count."""
    from dynenv_ros.main_job import actions_not_recorded
    report = {"diagnostics": {"periods_run": "4"}, "accepted_actions": {"team_a_0": 4, "team_b_0": 4}}
    _bag_with_actions(tmp_path / "complete", {"team_a_0": [1, 2, 3, 4, 5], "team_b_0": [1, 2, 3, 4]})
    assert actions_not_recorded(report, tmp_path / "complete") == {}
    _bag_with_actions(tmp_path / "lossy", {"team_a_0": [3, 4, 5]})
    assert actions_not_recorded(report, tmp_path / "lossy") == {"/team_a_0/action": (4, 2),
                                                                "/team_b_0/action": (4, 0)}


def test_the_train_graph_runs_games_policies_and_the_trainer_and_summarises(tmp_path, capsys, monkeypatch):
    """A short run: the machinery (games in their namespaces, experience reaching the trainer, weights back, the
    run directory, the curve) for a budget of 3 updates, too few to learn, so the exit status is not checked here; the comparison's rule is checked on fixed numbers below.
    The held-out verdict plays 4 episodes per policy here, not 80: that it plays the trainer's two policies and
    prints the verdict is what this run shows; the 80 episodes are played by the verdict's own test below."""
    from dynenv_ros.graph import train_graph
    monkeypatch.setattr(train_graph, "HELD_OUT_EPISODES", 4)
    arguments = ["--output-dir", str(tmp_path), "--set", f"domain_id={os.environ['ROS_DOMAIN_ID']}",
                 "--set", "graph=train", "--set", "train_updates=3", "--set", "games=2",
                 "--set", "players_per_team=1", "--set", "episode_seconds=2"]
    main(arguments)
    output = capsys.readouterr().out
    summary = json.loads((tmp_path / "trainer" / "summary.json").read_text())
    assert summary["updates"] >= 3 and summary["diagnostics"]["games"] == "2", output   # the update budget ran out
    assert summary["diagnostics"]["malformed"] == "0" and not summary["diagnostics"]["learner_error"]
    assert (tmp_path / "trainer" / "policy.safetensors").is_file() and (tmp_path / "bag").is_dir()
    assert "robot-periods learnt" in output and "reward learnt (auxiliary term) per episode" in output, output
    assert "held-out episodes (4 against the random team, same seeds)" in output, output
    # authenticated actions on: run-local secrets (owner-only), every node given them, nothing refused
    assert sorted(p.name for p in (tmp_path / "secrets").iterdir()) == ["frames.secret", "simulator.secret",
                                                                        "team_a.secret", "team_b.secret"]
    assert all(p.stat().st_mode & 0o077 == 0 for p in (tmp_path / "secrets").iterdir())
    assert summary["diagnostics"]["action_authentication"] == "on" and "authenticated actions: on" in output
    assert summary["diagnostics"]["action_mac_invalid"] == summary["diagnostics"]["feedback_mac_invalid"] == "0"


def _summary_with(tmp_path, returns):
    (tmp_path / "trainer").mkdir(parents=True)
    diagnostics = {k: "0" for k in ("games", "robots", "sequences", "late", "duplicate", "missing", "malformed",
                                    "cuts", "lag_versions_mean", "lag_seconds_mean")}
    diagnostics["learner_error"] = ""
    (tmp_path / "trainer" / "summary.json").write_text(json.dumps({
        "version": 31, "updates": 30, "env_steps": 600, "wall_seconds": 60.0, "diagnostics": diagnostics,
        "episodes": [[1 + i, r] for i, r in enumerate(returns)]}))


def test_the_train_summary_prints_the_curve_and_fails_a_run_stopped_by_its_wall_time_cap(tmp_path, capsys):
    from dynenv_ros.graph.train_graph import summarise_train
    # first third 0.0 ± 0.1-ish, last third 1.0: the curve's comparison is printed (information only)
    _summary_with(tmp_path / "up", [0.0, 0.2, -0.2, 0.1, -0.1, 0.0, 0.5, 0.5, 0.5, 1.0, 1.2, 0.8, 1.1, 0.9, 1.0])
    assert summarise_train(None, tmp_path / "up", None)
    assert "last third of the training episodes vs the first: +1.000 vs +0.000" in capsys.readouterr().out
    # the wall-time cap stopped the trainer before its update budget (30 of 40): a failure
    assert not summarise_train(None, tmp_path / "up", SimpleNamespace(train_updates=40))
    assert "only 30 of 40 updates before the wall-time cap" in capsys.readouterr().out


def test_the_held_out_verdict_needs_the_paired_gain_beyond_two_standard_errors():
    from dynenv_ros.graph.train_graph import held_out_verdict
    start = [0.5, 1.0, 0.0, 1.5, 0.8, 0.2]
    # gains 1.0, 1.1, 0.9, 1.0, 1.2, 0.8: mean 1.0, sd 0.1414, se 0.0577 -> far beyond 2 se
    ok, line = held_out_verdict(start, [1.5, 2.1, 0.9, 2.5, 2.0, 1.0])
    assert ok and "gain +1.000 ± 0.058 — learnt" in line
    # gains 1, -1, 1, -1, 1, -1: mean 0 -> not learnt
    ok, line = held_out_verdict(start, [1.5, 0.0, 1.0, 0.5, 1.8, -0.8])
    assert not ok and "NOT clearly learnt" in line
    # gains 0.3, 0.0, 0.3, 0.0, 0.3, 0.0: mean 0.15, sd 0.1643, se 0.0671 -> 2 se = 0.134 < 0.15: learnt, barely
    assert held_out_verdict(start, [0.8, 1.0, 0.3, 1.5, 1.1, 0.2])[0]
    with pytest.raises(ValueError, match="two equal lists"):
        held_out_verdict(start, start[:3])


def test_the_train_graph_verdict_plays_the_start_and_end_policies_on_held_out_episodes(tmp_path, capsys):
    """With config given, summarise_train plays the trainer's start and end policies (here: the same untrained
    network twice, so no gain) and decides on the held-out comparison."""
    from dynenv_ros.agent.checkpoint import save_policy
    from dynenv_ros.agent.network import DynEnvAgent
    from dynenv_ros.graph.train_graph import summarise_train
    _summary_with(tmp_path, [0.0, 0.2, -0.2, 0.1, -0.1, 0.0, 0.5, 0.5, 0.5, 1.0, 1.2, 0.8, 1.1, 0.9, 1.0])
    agent = DynEnvAgent(feature_size=16)
    for name in ("policy_start.safetensors", "policy.safetensors"):
        save_policy(agent, str(tmp_path / "trainer" / name))
    config = SimpleNamespace(train_updates=30, players_per_team=1, perception="realistic", episode_seconds=2.0)
    assert not summarise_train(None, tmp_path, config)      # the same policy twice, same seeds: every gain is 0
    assert ("held-out episodes (80 against the random team, same seeds): auxiliary reward" in
            (out := capsys.readouterr().out)) and "gain +0.000 ± 0.000 — NOT clearly learnt" in out, out
def test_the_users_ros_domain_id_is_respected_and_isolation_only_without_one_or_on_request():
    """Issue 28: dynenv-run ignored a ROS_DOMAIN_ID the user set, so their own tools could not see the graph. Now
    domain_id -1 takes the user's (discovery as the user has it), isolates (a domain from the process id,
    discovery on this host only) only when none is set, -2 isolates always, an explicit id is used as given, and a
    bad ROS_DOMAIN_ID is refused in one line."""
    from dynenv_ros.graph.process_graph import graph_environment, isolated_environment
    from dynenv_ros.main_job import choose_domain
    picked = 1 + os.getpid() % 100
    assert choose_domain(-1, {"ROS_DOMAIN_ID": "42"})[:2] == (42, False)
    assert choose_domain(-1, {})[:2] == (picked, True)
    assert choose_domain(-1, {"ROS_DOMAIN_ID": " "})[:2] == (picked, True)
    assert choose_domain(-2, {"ROS_DOMAIN_ID": "42"})[:2] == (picked, True)
    assert choose_domain(7, {"ROS_DOMAIN_ID": "42"})[:2] == (7, False)
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID='300' in your environment"):
        choose_domain(-1, {"ROS_DOMAIN_ID": "300"})
    assert isolated_environment(5)["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert graph_environment(5)["ROS_DOMAIN_ID"] == "5"
    assert graph_environment(5).get("ROS_AUTOMATIC_DISCOVERY_RANGE") == os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
    with pytest.raises(ConfigError, match="domain_id must be -1"):
        MainJobConfig.from_mapping({"domain_id": -3})


def test_shipped_policies_resolve_in_the_repository_and_else_in_the_installed_share(tmp_path, monkeypatch):
    """A colcon / pip install has no policy_node/pretrained/ beside the package: setup.py installs the shipped
    policies (soccer and driving) under share/dynenv_ros/pretrained/, and the config's repository-relative names
    must find them there."""
    from pathlib import Path

    import dynenv_ros.main_job as main_job
    repo = Path(main_job.__file__).resolve().parent.parent
    assert main_job.policy_file(main_job.SHIPPED_DRIVING_POLICY) == repo / "policy_node/pretrained/driving/policy.onnx"
    assert main_job.policy_file(main_job.SHIPPED_DRIVING_POLICY).is_file()
    share = tmp_path / "share" / "dynenv_ros" / "pretrained"
    (share / "driving").mkdir(parents=True)
    (share / "driving" / "elsewhere.onnx").write_bytes(b"onnx")
    monkeypatch.setattr(main_job, "INSTALLED_SHIPPED", share)
    assert main_job.policy_file("policy_node/pretrained/driving/elsewhere.onnx") == share / "driving/elsewhere.onnx"
    # anything else stays repository-relative (and absent: the caller's missing-file error names that path)
    assert main_job.policy_file("runs/elsewhere.onnx") == repo / "runs/elsewhere.onnx"
    assert main_job.policy_file("policy_node/pretrained/missing.onnx") == repo / "policy_node/pretrained/missing.onnx"
    assert main_job.policy_file(str(tmp_path / "abs.onnx")) == tmp_path / "abs.onnx"
