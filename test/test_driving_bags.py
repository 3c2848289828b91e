"""A driving game recorded end to end in one process — the simulator (scenario driving), the scripted drivers and
the recorder — and the bag read back with ``dynenv-bag`` info, echo, render (with a car's detections) and export."""
from __future__ import annotations

import csv
import json

from PIL import Image
from rclpy.parameter import Parameter

from dynenv_ros.bags.inspect import bag_info, main as bag_main
from ros_harness import spin_until

PERIODS = 20          # 2 s of 100 ms periods


def test_a_recorded_driving_game_is_read_back_and_rendered(tmp_path, make_node, executor, capsys):
    from dynenv_ros.nodes.recorder import Recorder
    from dynenv_ros.nodes.sim_node import SimNode
    from policy_node.scripted_driver import ScriptedDriverNode

    bag = tmp_path / "drive"
    recorder = make_node(Recorder, exit_when_done=False,
                         parameter_overrides=[Parameter("output", Parameter.Type.STRING, str(bag))])
    driver = make_node(ScriptedDriverNode, parameter_overrides=[Parameter("n_cars", value=2)])
    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in {
        "scenario": "driving", "n_cars": 2, "seed": 3, "episode_seconds": PERIODS / 10, "auto_reset": False,
        "wait_for_subscribers": 2, "wait_for_ground_truth_subscribers": 2, "wait_for_recorder": True}.items()])
    for node in (recorder, driver, sim):
        executor.add_node(node)
    assert spin_until(executor, lambda: sim.session.finished, 30.0), dict(sim.session.counts)
    frames = PERIODS + 1                                   # period 0 (the reset state), then one frame a period
    assert spin_until(executor, lambda: recorder.counts.get("/world_state") == frames
                      and recorder.counts.get("/car_1/feedback") == frames, 10.0), recorder.counts
    recorder.finish()
    counts = {t["name"]: t["count"] for t in bag_info(bag)["topics"]}
    for topic in ("/world_state", "/clock", "/car_0/detections", "/car_1/detections", "/car_0/feedback"):
        assert counts[topic] == frames, topic
    assert counts["/car_0/action"] >= PERIODS and counts["/sim/markers/ground_truth"] == frames

    assert bag_main(["info", str(bag)]) == 0
    assert "/car_0/detections" in capsys.readouterr().out
    assert bag_main(["echo", str(bag), "--topic", "/world_state", "--limit", "1", "--format", "json"]) == 0
    first = json.loads(capsys.readouterr().out.splitlines()[0])["message"]
    assert first["scenario"] == 1 and first["objects"][0]["class_id"] == 20

    gif = tmp_path / "drive.gif"
    assert bag_main(["render", str(bag), "--out", str(gif), "--robot", "car_0"]) == 0
    assert f"{frames} frames" in capsys.readouterr().out
    with Image.open(gif) as image:
        assert image.n_frames == frames and image.size[0] == round((170 + 12) * 4)   # the map at 4 px/m
    assert bag_main(["render", str(bag), "--out", str(gif), "--pixels-per-metre", "40"]) == 2
    assert "at most 4096 px a side" in capsys.readouterr().err

    assert bag_main(["export", str(bag), "--out", str(tmp_path / "tables")]) == 0
    with open(tmp_path / "tables" / "actions.csv") as handle:
        actions = list(csv.DictReader(handle))
    assert {row["robot"] for row in actions} == {"car_0", "car_1"}
    assert all(float(row["throttle"]) in (-1.0, 0.0, 1.0) for row in actions)
