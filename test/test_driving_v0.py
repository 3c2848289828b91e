"""driving_v0: the PettingZoo Parallel env over DrivingWorld, its full observation, rendering and dynenv-play."""
import math
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image
from pettingzoo.test import parallel_api_test, parallel_seed_test

from dynenv_ros.driving.scripted import ScriptedDriver
from dynenv_ros.envs.driving_observations import (CAR_COLUMNS, OBSTACLE_COLUMNS, PEDESTRIAN_COLUMNS, SELF_COLUMNS,
                                                  FullLayout)
from dynenv_ros.envs.driving_v0 import parallel_env
from dynenv_ros.render.driving import MapView, overlay_driving_detections, render_driving

SHORT = {"episode_seconds": 5.0, "pedestrians": {"count_min": 3, "count_max": 5},
         "obstacles": {"count_min": 2, "count_max": 4}}


def _col(columns, name):
    return columns.index(name)


@pytest.mark.parametrize("settings", [{"n_cars": 2, **SHORT}, {"n_cars": 3, "teams": 2, "action_mode": "continuous",
                                                               **SHORT}])
def test_passes_pettingzoo_parallel_api_test(settings):
    with pytest.warns(UserWarning, match="unknown option"):    # the API test passes a dummy reset option
        parallel_api_test(parallel_env(**settings), num_cycles=60)


def test_passes_pettingzoo_seed_test():
    parallel_seed_test(lambda: parallel_env(n_cars=3, **SHORT))


def _rollout(seed, **settings):
    env = parallel_env(**settings)
    obs, _ = env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    trace, rewards = [np.stack([obs[a] for a in env.possible_agents])], []
    while env.agents:
        obs, rew, term, trunc, info = env.step({a: env.action_space(a).sample() for a in env.agents})
        trace.append(np.concatenate([obs[a] for a in sorted(obs)]))
        rewards.append([rew.get(a, np.nan) for a in env.possible_agents])
    return trace, np.array(rewards), env


def test_same_seed_gives_the_same_episode_and_another_seed_does_not():
    a, ra, env = _rollout(3, n_cars=2, episode_seconds=4.0)
    b, rb, _ = _rollout(3, n_cars=2, episode_seconds=4.0)
    c, _, _ = _rollout(4, n_cars=2, episode_seconds=4.0)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    np.testing.assert_array_equal(ra, rb)
    assert not np.array_equal(a[0], c[0])
    assert env.world.period == len(ra)


def test_observations_and_state_lie_in_their_spaces_and_reward_terms_sum_to_the_reward():
    env = parallel_env(n_cars=4, teams=2, **SHORT)
    obs, infos = env.reset(seed=5)
    assert set(infos["car_0"]["reward_terms"]) == {"primary", "rule", "auxiliary", "observation"}
    rng = np.random.default_rng(0)
    while env.agents:
        for agent, o in obs.items():
            assert env.observation_space(agent).contains(o), agent
        assert env.state_space.contains(env.state())
        obs, rew, term, trunc, info = env.step({a: rng.integers(0, 3, 2) for a in env.agents})
        for agent, r in rew.items():
            assert r == pytest.approx(sum(info[agent]["reward_terms"].values()), abs=1e-12)


def test_full_observation_is_in_the_observers_frame():
    env = parallel_env(n_cars=2, **SHORT)
    obs, _ = env.reset(seed=2)
    world = env.world
    # Put car 1 5 m ahead and 2 m to the left of car 0, facing the other way, and send car 0 north.
    c0 = world.cars[0]
    x0, y0, yaw0 = c0.x, c0.y, c0.yaw
    fx, fy = math.cos(yaw0), math.sin(yaw0)
    lx, ly = -fy, fx
    world.place_car(1, x0 + 5 * fx + 2 * lx, y0 + 5 * fy + 2 * ly, yaw0 + math.pi)
    world.set_goal(0, 1)
    parts = env.observations.layout.split(env.observations.build()[0][0])
    me, other = parts["self"], parts["cars"][0]
    assert me[_col(SELF_COLUMNS, "x")] == pytest.approx(x0) and me[_col(SELF_COLUMNS, "cos_yaw")] == \
        pytest.approx(math.cos(yaw0), abs=1e-6)
    assert other[_col(CAR_COLUMNS, "present")] == 1.0
    assert other[_col(CAR_COLUMNS, "x")] == pytest.approx(5.0, abs=1e-4)
    assert other[_col(CAR_COLUMNS, "y")] == pytest.approx(2.0, abs=1e-4)
    assert other[_col(CAR_COLUMNS, "cos_yaw")] == pytest.approx(-1.0, abs=1e-6)
    gx, gy = world.map.destinations[1]
    dx, dy = gx - x0, gy - y0
    assert me[_col(SELF_COLUMNS, "goal_x")] == pytest.approx(math.cos(yaw0) * dx + math.sin(yaw0) * dy, abs=1e-3)
    assert me[_col(SELF_COLUMNS, "goal_y")] == pytest.approx(-math.sin(yaw0) * dx + math.cos(yaw0) * dy, abs=1e-3)
    # Pedestrians and obstacles: nearest first, every live one present, padding zero.
    peds, obstacles = parts["pedestrians"], parts["obstacles"]
    n_peds, n_obstacles = len(world.pedestrians), len(world.obstacles_xy)
    assert peds[:n_peds, 0].all() and not peds[n_peds:].any()
    assert obstacles[:n_obstacles, 0].all() and not obstacles[n_obstacles:].any()
    distances = np.hypot(peds[:n_peds, 1], peds[:n_peds, 2])
    assert np.all(np.diff(distances) >= 0)
    layout = FullLayout.for_config(env.config)
    assert env.observation_space("car_0").shape == (layout.size,)
    assert peds.shape == (5, len(PEDESTRIAN_COLUMNS)) and obstacles.shape == (4, len(OBSTACLE_COLUMNS))


def test_continuous_steering_left_turns_the_car_left_in_its_frame():
    env = parallel_env(n_cars=1, action_mode="continuous", pedestrians={"count_min": 0, "count_max": 0},
                       obstacles={"count_min": 0, "count_max": 0})
    env.reset(seed=0)
    world = env.world
    world.place_car(0, 87.5 + 1.75, 20.0, math.pi / 2, speed=5.0)      # northbound in its right lane
    w = env.config.cars.max_yaw_rate
    for _ in range(10):
        obs, *_ = env.step({"car_0": np.array([1.0, 0.0, w], np.float32)})
    me = env.observations.layout.split(obs["car_0"])["self"]
    yaw = math.atan2(me[_col(SELF_COLUMNS, "sin_yaw")], me[_col(SELF_COLUMNS, "cos_yaw")])
    assert yaw > math.pi / 2 + 0.2                                      # turned counter-clockwise (left)
    assert me[_col(SELF_COLUMNS, "x")] < 87.5 + 1.75                    # and drifted west, its left
    assert me[_col(SELF_COLUMNS, "speed")] > 5.0                        # throttle sped it up
    # No steering: straight on; full brake slows it.
    env.reset(seed=0)
    world.place_car(0, 87.5 + 1.75, 20.0, math.pi / 2, speed=5.0)
    for _ in range(5):
        obs, *_ = env.step({"car_0": np.array([0.0, 1.0, 0.0], np.float32)})
    me = env.observations.layout.split(obs["car_0"])["self"]
    assert me[_col(SELF_COLUMNS, "x")] == pytest.approx(87.5 + 1.75, abs=1e-3)
    assert me[_col(SELF_COLUMNS, "speed")] < 5.0 - 2.0                 # full brake


def test_crashed_car_leaves_the_agents_and_the_others_go_on():
    env = parallel_env(n_cars=2, **SHORT)
    env.reset(seed=1)
    # Drive car 0 into a building at speed: it crashes, terminates and leaves; car 1 stays.
    b = env.world.map.buildings[0]
    env.world.place_car(0, b.x + b.half_x + 1.5, b.y, math.pi, speed=8.0)
    stop = np.array([1, 1])
    for _ in range(5):
        obs, rew, term, trunc, info = env.step({a: stop for a in env.agents})
        if term.get("car_0"):
            break
    assert term["car_0"] and not trunc["car_0"] and info["car_0"]["crashed"]
    assert any(e.startswith("crash") for e in info["car_0"]["events"])
    assert info["car_0"]["reward_terms"]["rule"] < 0
    assert env.agents == ["car_1"]
    obs, rew, term, trunc, info = env.step({"car_1": stop, "car_0": np.array([2, 1])})   # a departed car: ignored
    assert set(obs) == {"car_1"}


def test_car_at_its_goal_waits_for_the_team_bonus_then_every_car_terminates():
    env = parallel_env(n_cars=2, **SHORT)
    env.reset(seed=0)
    driver = ScriptedDriver(env.config)
    world = env.world
    # Put both cars just before their destinations' road ends, driving out.
    for i in (0, 1):
        car = world.cars[i]
        gx, gy = car.goal_xy
        road, end = world.map.road_of_end(car.goal)
        r = world.map.roads[road]
        sign = 1 if end > 0 else -1
        ux, uy = r.direction
        d = r.lane_offset(sign, 0)
        s = (r.length - (6.0 + 10 * i)) if sign > 0 else 6.0 + 10 * i
        x, y = r.to_map(s, d)
        world.place_car(i, x, y, math.atan2(sign * uy, sign * ux), speed=6.0)
    arrived = None
    while env.agents:
        live = list(env.agents)
        actions = dict(zip(env.possible_agents, driver.actions(world)))
        obs, rew, term, trunc, info = env.step({a: actions[a] for a in live})
        if arrived is None and info["car_0"]["at_goal"]:
            arrived = world.period
            assert not term["car_0"] and "car_0" in env.agents    # the bonus is still to come
            assert info["car_0"]["reward_terms"]["primary"] > 0
    assert arrived is not None
    assert term == {"car_0": True, "car_1": True}
    assert info["car_0"]["reward_terms"]["primary"] > 0 and "team_bonus" in " ".join(info["car_0"]["events"])


def test_every_car_is_truncated_at_the_episode_end_and_stepping_on_is_refused():
    env = parallel_env(n_cars=2, episode_seconds=0.3)
    env.reset(seed=1)
    for expected in (False, False, True):
        _, _, term, trunc, info = env.step({a: np.array([1, 1]) for a in env.agents})
        assert set(trunc.values()) == {expected} and set(term.values()) == {False}
        assert "TimeLimit.truncated" not in info["car_0"]            # truncation is `trunc`, not a legacy info key
    assert env.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    assert parallel_env().config.episode_periods == 600


@pytest.mark.parametrize("bad,message", [
    (np.array([0, 0, 0]), r"car_1: discrete action must have shape \(2,\)"),
    (np.array([3, 1]), r"car_1: action field 'acceleration'=3 is out of range"),
    (np.array([1, -1]), r"car_1: action field 'steering'=-1"),
    (np.array([0.5, 1]), r"car_1: action field 'acceleration' must be an integer"),
    ("gas", r"car_1: action must be numeric"),
])
def test_bad_actions_name_the_car_and_field_and_do_not_advance_the_world(bad, message):
    env = parallel_env(n_cars=2, **SHORT)
    env.reset(seed=0)
    before = env.state()
    with pytest.raises(ValueError, match=message):
        env.step({"car_0": np.array([2, 1]), "car_1": bad})
    assert env.world.tick == 0
    np.testing.assert_array_equal(env.state(), before)


def test_continuous_actions_out_of_bounds_are_refused():
    env = parallel_env(n_cars=1, action_mode="continuous", **SHORT)
    env.reset(seed=0)
    for bad, field in (([2.0, 0.0, 0.0], "throttle"), ([0.0, -0.1, 0.0], "brake"), ([0.0, 0.0, 1.0], "steering"),
                       ([np.nan, 0.0, 0.0], "throttle")):
        with pytest.raises(ValueError, match=f"car_0: action field '{field}'"):
            env.step({"car_0": np.array(bad)})
    assert env.action_space("car_0").contains(np.array([1.0, 1.0, env.config.cars.max_yaw_rate], np.float32))


def test_unknown_or_missing_agents_are_refused():
    env = parallel_env(n_cars=2, **SHORT)
    env.reset(seed=0)
    a = np.array([1, 1])
    with pytest.raises(ValueError, match="unknown agent 'car_7'"):
        env.step({"car_0": a, "car_1": a, "car_7": a})
    with pytest.raises(ValueError, match="no action for car_1"):
        env.step({"car_0": a})
    with pytest.raises(ValueError, match="unknown agent"):
        env.action_space("team_a_0")


@pytest.mark.parametrize("settings,message", [
    ({"n_cars": 0}, "n_cars"), ({"n_cars": 11}, "n_cars"), ({"speed": 3}, "unknown driving setting"),
    ({"action_mode": "analog"}, "action_mode"), ({"cars": {"powers": [1.0]}}, "one value per car type"),
    ({"pedestrians": {"count_min": 5, "count_max": 2}}, "count_min"),
    ({"observation": "image"}, r"observation must be one of \('full', 'partial', 'padded'\)"),
    ({"observation": ["full"]}, "observation must be one of"),
    ({"perception": "realistic"}, "ground truth"), ({"observation_options": {"max_rows": 3}}, "does not take"),
    ({"render_mode": "human"}, "render_mode"), ({"pixels_per_metre": 0}, "pixels_per_metre")])
def test_bad_settings_are_refused_with_the_setting_named(settings, message):
    with pytest.raises(ValueError, match=message):
        parallel_env(**settings)


def test_bad_seeds_and_options_are_refused():
    env = parallel_env(n_cars=1, **SHORT)
    for seed in (-1, 1.5, "7", True):
        with pytest.raises(ValueError, match="seed"):
            env.reset(seed=seed)
    with pytest.raises(ValueError, match="options must be a mapping"):
        env.reset(options=["x"])


# -- rendering -------------------------------------------------------------------------------------------------------
def test_render_gives_an_rgb_frame_with_the_map_and_the_cars():
    env = parallel_env(n_cars=2, render_mode="rgb_array", pixels_per_metre=8.0, **SHORT)
    env.reset(seed=0)
    frame = env.render()
    view = MapView.of(env.world.map, 8.0)
    assert frame.shape == (view.size[1], view.size[0], 3) and frame.dtype == np.uint8
    from dynenv_ros.render import driving as r
    px, py = (round(v) for v in view.field_to_pixel(*env.world.map.crossing))
    assert tuple(frame[py, px - 5]) == r.ASPHALT                      # the crossing (away from its centre line)
    b = env.world.map.buildings[0]
    bx, by = (round(v) for v in view.field_to_pixel(b.x, b.y))
    assert tuple(frame[by, bx]) == r.BUILDING
    car = env.world.cars[0]
    cx, cy = (round(v) for v in view.field_to_pixel(car.x - 0.6 * car.type.half_length * math.cos(car.yaw),
                                                      car.y - 0.6 * car.type.half_length * math.sin(car.yaw)))
    assert tuple(frame[cy, cx]) == r.car_colour(0)                     # the car's rear half, its own colour
    with pytest.warns(UserWarning, match="render_mode"):
        assert parallel_env(n_cars=1, **SHORT).render() is None


def test_detection_overlay_draws_driving_classes_in_the_observer_frame():
    from dynenv_ros.core.object_classes import ObjectClass
    from dynenv_ros.perception.detections import empty
    from dynenv_ros.render import detections as d
    env = parallel_env(n_cars=1, **SHORT)
    env.reset(seed=0)
    world = env.world
    image = render_driving(world.snapshot(), world.map, pixels_per_metre=4.0)
    view = MapView.of(world.map, 4.0)
    rows = empty(4)
    rows["class_id"] = [ObjectClass.SELF, ObjectClass.PEDESTRIAN, ObjectClass.OBSTACLE, ObjectClass.LANE]
    rows["x"], rows["y"] = [20.0, 10.0, 0.0, 0.0], [0.0, 0.0, 10.0, 0.0]
    rows["true_id"] = [0, 5, 6, -2]
    rows["true_class"] = rows["class_id"]
    rows["line_start_x"], rows["line_end_x"] = [0, 0, 0, -5.0], [0, 0, 0, 5.0]
    rows["line_start_y"], rows["line_end_y"] = [0, 0, 0, -6.0], [0, 0, 0, -6.0]
    before = np.asarray(image).copy()
    car = world.cars[0]
    overlay_driving_detections(image, view, (car.x, car.y, car.yaw), rows, view_radius=68.0)
    pixels = np.asarray(image)
    c, s = math.cos(car.yaw), math.sin(car.yaw)
    for (x, y), colour in (((10.0, 0.0), d.class_colour(ObjectClass.PEDESTRIAN)),
                           ((0.0, 10.0), d.class_colour(ObjectClass.OBSTACLE)),
                           ((0.0, -6.0), d.LINE_DETECTION)):
        px, py = (round(v) for v in view.field_to_pixel(car.x + c * x - s * y, car.y + s * x + c * y))
        assert tuple(pixels[py, px]) == colour
    px, py = (round(v) for v in view.field_to_pixel(car.x + c * 20.0, car.y + s * 20.0))
    np.testing.assert_array_equal(pixels[py - 2:py + 3, px - 2:px + 3], before[py - 2:py + 3, px - 2:px + 3])  # SELF


def test_play_writes_a_driving_gif(tmp_path):
    gif = tmp_path / "drive.gif"
    result = subprocess.run([sys.executable, "-m", "dynenv_ros.envs.play", "--scenario", "driving", "--cars", "2",
                             "--seconds", "0.5", "--gif", str(gif), "--pixels-per-metre", "1.5", "--json"],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    import json
    summary = json.loads(result.stdout)
    assert summary["scenario"] == "driving" and summary["periods"] == 5 and summary["frames"] == 6
    with Image.open(gif) as image:
        assert image.format == "GIF" and image.n_frames >= 2
        assert image.size == MapView(170.0, 100.0, 1.5).size
    bad = subprocess.run([sys.executable, "-m", "dynenv_ros.envs.play", "--scenario", "driving", "--cars", "12",
                          "--seconds", "0.5"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "n_cars" in bad.stderr
