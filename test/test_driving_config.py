"""The driving config: defaults are docs/original.md's numbers × 0.1 m/px, and bad values are refused by name."""
import math

import pytest

from dynenv_ros.driving.config import DrivingConfig, MapConfig


def test_defaults_are_the_original_numbers_in_metres():
    c = DrivingConfig()
    # World 1700 x 1000 px, lane width 35 px, roads at x = 875 px and y = 500 px (docs/original.md §3).
    assert (c.map.width, c.map.height, c.map.lane_width) == (170.0, 100.0, 3.5)
    assert (c.map.vertical_road_x, c.map.horizontal_road_y) == (87.5, 50.0)
    assert (c.map.vertical_lanes, c.map.horizontal_lanes) == (2, 1)
    # Car types: mass [1200, 1800, 3500, 5000] kg, half-width [5..8] px, half-length [10..25] px, power [3,4,3,4].
    assert c.cars.masses == (1200.0, 1800.0, 3500.0, 5000.0)
    assert c.cars.half_widths == pytest.approx((0.5, 0.6, 0.7, 0.8))
    assert c.cars.half_lengths == pytest.approx((1.0, 1.5, 2.0, 2.5))
    assert c.cars.powers == (3.0, 4.0, 3.0, 4.0)
    # Steering ±2° per 100 ms step.
    assert c.cars.max_yaw_rate == pytest.approx(math.radians(2.0) / 0.1)
    # Pedestrians 10–20, 90 kg, radius 5 px; obstacles 10–20 of 20 x 20 px.
    p, o = c.pedestrians, c.obstacles
    assert (p.count_min, p.count_max, p.mass, p.radius) == (10, 20, 90.0, pytest.approx(0.5))
    assert (o.count_min, o.count_max, o.size) == (10, 20, pytest.approx(2.0))
    # 10 ms ticks, one action and one frame per 100 ms, 60 s = 600 periods (docs/original.md §1).
    assert c.rates.tick_seconds == pytest.approx(0.01)
    assert (c.rates.motion_period_ticks, c.rates.frames_per_period, c.rates.vision_tick_offsets()) == (10, 1, (10,))
    assert (c.episode_periods, c.episode_ticks) == (600, 6000)
    assert (c.n_cars, c.action_mode, c.car_names) == (2, "discrete", ["car_0", "car_1"])


def test_reward_weights_keep_the_original_magnitudes():
    r = DrivingConfig().rewards
    assert r.progress_per_metre == pytest.approx(10 / 50)       # Δpx/50 → per metre (10 px)
    assert r.crash_per_speed == pytest.approx(10 / 5)           # |v|/5 with v in px/s → per m/s
    assert r.opposing_per_metre == pytest.approx(10 / 100)      # |v|/10000 per 10 ms tick → per metre
    assert (r.goal_per_second, r.team_bonus_per_second) == (1.0, 1.0)   # (6000 − ticks)/100 = seconds left


@pytest.mark.parametrize("settings,fragment", [
    ({"n_cars": 0}, "n_cars"),
    ({"n_cars": 11}, "n_cars"),
    ({"n_cars": "2"}, "n_cars"),
    ({"n_cars": True}, "n_cars"),
    ({"teams": 3}, "teams"),
    ({"action_mode": "analog"}, "action_mode"),
    ({"episode_seconds": 0.05}, "episode_seconds"),
    ({"episode_seconds": float("nan")}, "episode_seconds"),
    ({"cars": {"masses": [1200.0, -1.0, 3500.0, 5000.0]}}, "cars.masses[1]"),
    ({"cars": {"powers": [3.0, 4.0]}}, "cars.powers"),
    ({"cars": {"half_widths": [2.0, 0.6, 0.7, 0.8], "half_lengths": [2.5, 1.5, 2.0, 2.5]}}, "cars.half_widths[0]"),
    ({"cars": {"max_yaw_rate": 0.0}}, "cars.max_yaw_rate"),
    ({"cars": {"reverse_fraction": 1.5}}, "cars.reverse_fraction"),
    ({"pedestrians": {"count_min": 20, "count_max": 10}}, "pedestrians.count_min"),
    ({"pedestrians": {"cross_probability": 1.5}}, "pedestrians.cross_probability"),
    ({"pedestrians": {"count_max": 2.5}}, "pedestrians.count_max"),
    ({"pedestrians": {"radius": -0.5}}, "pedestrians.radius"),
    ({"obstacles": {"size": 4.0}}, "obstacles.size"),
    ({"map": {"lane_width": 0.0}}, "map.lane_width"),
    ({"map": {"vertical_road_x": 200.0}}, "map.vertical_road_x"),
    ({"map": {"building_centres": [[60.0, 20.0]]}}, "map.building_centres[0]"),
    ({"map": {"spawn_spacing": 12.0}}, "map.spawn_spacing"),
    ({"rewards": {"crash_per_speed": -2.0}}, "rewards.crash_per_speed"),
    ({"rewards": {"goal_per_second": float("inf")}}, "rewards.goal_per_second"),
    ({"rewards": {"blame_cos": 1.0}}, "rewards.blame_cos"),
    ({"speed_limit": 5.0}, "speed_limit"),
    ({"cars": {"top_speed": 5.0}}, "cars.top_speed"),
    ({"cars": 3}, "cars"),
])
def test_bad_values_are_refused_with_the_setting_named(settings, fragment):
    with pytest.raises(ValueError, match=fragment.replace("[", r"\[").replace("]", r"\]")):
        DrivingConfig.from_mapping(settings)


def test_from_mapping_takes_yaml_like_values():
    c = DrivingConfig.from_mapping({"n_cars": 4, "action_mode": "continuous", "cars": {"powers": [2, 2, 2, 2]},
                                    "map": {"building_half_size": [40, 22.5]},
                                    "rates": {"physics_hz": 100.0, "vision_period_ticks": 5,
                                              "motion_period_ticks": 10}})
    assert c.n_cars == 4 and c.cars.powers == (2.0, 2.0, 2.0, 2.0)
    assert c.map.building_half_size == (40.0, 22.5) and c.rates.frames_per_period == 2
    with pytest.raises(ValueError, match="rates"):
        DrivingConfig.from_mapping({"rates": {"physics": 100}})


def test_map_config_refuses_malformed_lists_directly():
    with pytest.raises(ValueError, match="map.building_half_size"):
        MapConfig(building_half_size=(40.0,))
    with pytest.raises(ValueError, match=r"map.building_centres\[1\]"):
        MapConfig(building_centres=((36.5, 20.0), (36.5, "north")))
