"""Ground truth in the shape of dynenv_msgs/WorldState, and the command-line tools over the soccer world."""
import dataclasses
import json
import math
import subprocess
import sys

import pytest

from dynenv_ros.bags.typestore import dynenv_typestore
from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.soccer.actions import SoccerAction, Walk
from dynenv_ros.soccer.referee import Phase
from soccer_helpers import IDLE, make_world


def _message_fields(name):
    return [field for field, _ in dynenv_typestore().fielddefs[f"dynenv_msgs/msg/{name}"][1]]


def test_snapshot_records_carry_exactly_the_fields_of_the_ground_truth_messages():
    body = [f.name for f in dataclasses.fields(BodyState)]
    assert body == _message_fields("ObjectState")
    world = [f.name for f in dataclasses.fields(WorldSnapshot)]
    assert world == [f for f in _message_fields("WorldState") if f != "header"]   # the stamp is the node's


def test_snapshot_reports_poses_velocities_flags_owner_score_phase_and_clock():
    world = make_world(players_per_team=2)
    world.place_robot(0, -1.0, 0.5, 0.3)
    world.set_ball_owner(-1, 12.0)
    world.state.chain[:] = [3, 0]
    world.step([SoccerAction(walk=Walk.FORWARD), IDLE, IDLE, IDLE])
    snap = world.snapshot()
    robots, balls = snap.of_class(ObjectClass.ROBOT), snap.of_class(ObjectClass.BALL)
    assert [r.id for r in robots] == [0, 1, 2, 3] and [r.team for r in robots] == [1, 1, -1, -1]
    assert len(balls) == 1 and balls[0].id == 4 and balls[0].size_x == pytest.approx(0.1)
    r0 = robots[0]
    assert (r0.x, r0.y, r0.yaw) == pytest.approx((-1.0 + 0.055 * math.cos(0.3), 0.5 + 0.055 * math.sin(0.3), 0.3),
                                                 abs=0.003)
    assert r0.vx > 0.05 and r0.status == ObjectStatus.NONE
    assert snap.tick == 50 and snap.tick_period == pytest.approx(0.01) and snap.game_time == pytest.approx(0.5)
    assert snap.time_remaining == pytest.approx(119.5)
    assert (snap.ball_owner_team, snap.phase) == (-1, int(Phase.KICK_IN))
    assert snap.ball_owner_remaining == pytest.approx(11.5)
    assert snap.last_touch_robot_ids == (3, 0)
    assert (snap.score_team_a, snap.score_team_b) == (0, 0)


def _run(*args):
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=120)


def test_play_tool_runs_a_scripted_game_and_records_it(tmp_path):
    gif = tmp_path / "game.gif"
    frames = tmp_path / "frames"
    frames.mkdir()
    result = _run("dynenv_ros.envs.play", "--players-per-team", "1", "--seconds", "3", "--gif", str(gif),
                  "--png-dir", str(frames), "--pixels-per-metre", "10", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["periods"] == 6 and summary["frames"] == 30
    assert gif.stat().st_size > 0 and len(list(frames.glob("frame_*.png"))) == 30
    assert set(summary["reward_per_robot"]) == {"primary", "rule", "auxiliary", "observation"}
    bad = _run("dynenv_ros.envs.play", "--players-per-team", "9", "--seconds", "1")
    assert bad.returncode == 2 and "players_per_team" in bad.stderr


def test_play_tool_draws_one_robots_detections(tmp_path):
    gif = tmp_path / "watch.gif"
    result = _run("dynenv_ros.envs.play", "--players-per-team", "1", "--seconds", "1", "--watch", "1",
                  "--perception", "realistic", "--noise-magnitude", "2", "--gif", str(gif),
                  "--pixels-per-metre", "10", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["frames"] == 10 and gif.stat().st_size > 0
    assert sum(summary["reward_per_robot"]["observation"]) > 0          # watching perceives: it earns the term
    bad = _run("dynenv_ros.envs.play", "--players-per-team", "1", "--watch", "7", "--seconds", "1")
    assert bad.returncode == 2 and "--watch" in bad.stderr


def test_sim_benchmark_prints_one_json_object_with_its_figures():
    result = _run("benchmarks", "sim", "--scenario", "robocup", "--players-per-team", "1", "--steps", "20",
                  "--repeat", "3", "--observation", "none", "--json")
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout)
    assert figures["peak_rss_mb"] > 0 and figures["torch_imported"] is False and figures["players_per_team"] == 1
    assert figures["observation"] == "none" and "physics and rules" in figures["measures"]
    # every rate: the median and [min, max] of the 3 runs, per wall second and per CPU second
    for key in ("env_steps_per_s", "env_steps_per_cpu_s", "wall_s", "cpu_s", "ms_per_env_step", "cpu_ms_per_env_step"):
        figure = figures[key]
        assert len(figure["runs"]) == 3 and 0 < figure["min"] <= figure["median"] <= figure["max"]
        assert figure["median"] == sorted(figure["runs"])[1]
    for steps, wall, cpu in zip(figures["env_steps_per_s"]["runs"], figures["wall_s"]["runs"], figures["cpu_s"]["runs"]):
        assert abs(steps - 20 / wall) <= 0.01 * steps
        # one process, one thread stepping: it cannot use more CPU than wall time
        assert cpu <= wall * 1.02 + 1e-3


def test_sim_benchmark_defaults_to_the_step_training_runs_and_says_so():
    single = _run("benchmarks", "sim", "--players-per-team", "1", "--steps", "5", "--repeat", "1", "--json")
    assert single.returncode == 0, single.stderr
    figures = json.loads(single.stdout)
    assert (figures["observation"], figures["noise"], figures["preset"]) == ("partial", "realistic", "realistic")
    assert figures["measures"].endswith("[the default observation]") and figures["robot_frames_per_s"]["min"] > 0
    batch = _run("benchmarks", "sim", "--players-per-team", "1", "--steps", "5", "--repeat", "1", "--envs", "2",
                 "--json")
    assert batch.returncode == 0, batch.stderr
    figures = json.loads(batch.stdout)
    assert figures["observation"] == "padded" and "2 worlds as one batch" in figures["measures"]
    # a batch always observes: physics alone is refused instead of measuring ground truth under its name
    refused = _run("benchmarks", "sim", "--envs", "2", "--observation", "none", "--steps", "5")
    assert refused.returncode == 2 and "'padded'" in refused.stderr
    table = _run("benchmarks", "sim", "--players-per-team", "1", "--steps", "5", "--repeat", "1")
    assert table.returncode == 0 and table.stdout.startswith("measures: robocup 1v1: the whole env step, partial")
