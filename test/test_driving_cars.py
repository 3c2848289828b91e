"""The vehicle model against the original's per-step figures, and strict action parsing in both action modes."""
import math

import numpy as np
import pytest

from dynenv_ros.driving.cars import DrivingAction, parse_action
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.world import DrivingWorld

REVERSE, BRAKE, GAS = 0, 1, 2
RIGHT, STRAIGHT, LEFT = 0, 1, 2
LIMIT = math.radians(2.0) / 0.1        # the original's ±2° per 100 ms step, rad/s


def one_car(mass=1800.0, power=4.0, half_width=0.6, half_length=1.5, mode="discrete"):
    """One car of a single type on an empty map, eastbound in its lane far from everything, going to the east end."""
    config = DrivingConfig.from_mapping({
        "n_cars": 1, "action_mode": mode, "pedestrians": {"count_min": 0, "count_max": 0},
        "obstacles": {"count_min": 0, "count_max": 0},
        "cars": {"masses": [mass], "half_widths": [half_width], "half_lengths": [half_length], "powers": [power]}})
    world = DrivingWorld(config, seed=0)
    world.set_goal(0, 3)
    world.place_car(0, 10.0, 48.25, 0.0)
    return world


def speeds(world, action, periods):
    out = []
    for _ in range(periods):
        world.step([action])
        out.append(world.cars[0].speed)
    return np.array(out)


@pytest.mark.parametrize("mass,power,gain", [
    (1800.0, 4.0, 0.31),      # measured: +3.1 px/s per step for type 1
    (1200.0, 3.0, 0.24),      # power 3 px/s minus friction 5e-5·1200 px/s per tick · 10 ticks = 0.6 px/s
    (5000.0, 4.0, 0.15),      # 4 − 2.5 px/s
])
def test_gas_adds_the_original_speed_per_period(mass, power, gain):
    world = one_car(mass, power)
    v = speeds(world, [GAS, STRAIGHT], 8)
    np.testing.assert_allclose(np.diff(np.concatenate([[0.0], v])), gain, atol=0.003)


def test_brake_takes_089_m_s_per_period_and_stops_at_zero():
    world = one_car()
    world.place_car(0, 10.0, 48.25, 0.0, speed=2.0)
    v = speeds(world, [BRAKE, STRAIGHT], 4)
    np.testing.assert_allclose(v, [1.11, 0.22, 0.0, 0.0], atol=0.003)    # measured: −8.9 px/s per step


def test_reverse_needs_a_stop_first_and_then_backs_up():
    world = one_car()
    world.place_car(0, 40.0, 48.25, 0.0, speed=1.0)
    v = speeds(world, [REVERSE, STRAIGHT], 3)
    # Rolling forward, reverse traction does nothing: only friction (0.09 m/s per period) slows the car.
    np.testing.assert_allclose(v, [0.91, 0.82, 0.73], atol=0.003)
    world.place_car(0, 40.0, 48.25, 0.0)
    v = speeds(world, [REVERSE, STRAIGHT], 3)
    np.testing.assert_allclose(v, [-0.21, -0.42, -0.63], atol=0.003)   # 0.75·4 px/s back, minus friction
    assert world.cars[0].x < 40.0


def test_steering_turns_2_degrees_per_period_left_and_right():
    world = one_car()
    world.place_car(0, 20.0, 48.25, 0.0, speed=3.0)
    world.step([[GAS, LEFT]])          # the gear joint needs ≈2 ticks to reach the yaw rate
    start = world.cars[0].body.angle
    for _ in range(5):
        world.step([[GAS, LEFT]])
    assert math.degrees(world.cars[0].body.angle - start) == pytest.approx(10.0, abs=0.05)
    world.step([[GAS, RIGHT]])
    start = world.cars[0].body.angle
    for _ in range(5):
        world.step([[GAS, RIGHT]])
    assert math.degrees(world.cars[0].body.angle - start) == pytest.approx(-10.0, abs=0.05)
    # Velocity follows the heading (no sideways slip).
    car = world.cars[0]
    v = car.body.velocity
    assert math.atan2(v.y, v.x) == pytest.approx(car.body.angle, abs=math.radians(1.1))


def test_no_turning_on_the_spot_and_a_minimum_turning_radius():
    world = one_car()
    speeds(world, [BRAKE, LEFT], 5)
    assert world.cars[0].body.angle == pytest.approx(0.0, abs=1e-9)
    world.place_car(0, 20.0, 48.25, 0.0, speed=1.0)
    world.step([[REVERSE, LEFT]])     # reverse while rolling forward: friction only, 0.91 m/s; |ω| ≤ 0.91 / 4 m
    assert world.cars[0].body.angular_velocity == pytest.approx(0.91 / 4.0, rel=0.01)


def test_continuous_commands_scale_the_same_figures():
    world = one_car(mode="continuous")
    v = speeds(world, [0.5, 0.0, 0.0], 3)           # half throttle: 0.2 − 0.09
    np.testing.assert_allclose(np.diff(np.concatenate([[0.0], v])), 0.11, atol=0.003)
    world.place_car(0, 10.0, 48.25, 0.0, speed=3.0)
    v = speeds(world, [0.0, 0.5, 0.0], 2)           # half brake: 0.4 + 0.09
    np.testing.assert_allclose(v, [2.51, 2.02], atol=0.003)
    world.place_car(0, 10.0, 48.25, 0.0, speed=3.0)
    v = speeds(world, [0.0, 0.0, 0.0], 2)           # coasting: rolling resistance only
    np.testing.assert_allclose(v, [2.91, 2.82], atol=0.003)
    world.place_car(0, 10.0, 48.25, 0.0, speed=3.0)
    world.step([[1.0, 0.0, 0.1]])
    world.step([[1.0, 0.0, 0.1]])                     # a yaw rate below the limit is held as commanded
    assert world.cars[0].body.angular_velocity == pytest.approx(0.1, abs=1e-6)
    world.step([{"throttle": 1.0, "brake": 0.0, "steering": -LIMIT}])
    assert world.cars[0].body.angular_velocity == pytest.approx(-LIMIT, abs=1e-3)


def test_discrete_and_continuous_forms_of_the_same_command_agree():
    a, b = one_car(), one_car(mode="continuous")
    for discrete, continuous in (([GAS, LEFT], [1.0, 0.0, LIMIT]), ([BRAKE, RIGHT], [0.0, 1.0, -LIMIT]),
                                 ([GAS, STRAIGHT], DrivingAction(1.0, 0.0, 0.0))):
        for _ in range(3):
            a.step([discrete])
            b.step([continuous])
    assert (a.cars[0].x, a.cars[0].y, a.cars[0].body.angle) == pytest.approx(
        (b.cars[0].x, b.cars[0].y, b.cars[0].body.angle), abs=1e-9)


@pytest.mark.parametrize("mode,raw,fragment", [
    ("continuous", [1.2, 0.0, 0.0], "throttle"),
    ("continuous", [-1.01, 0.0, 0.0], "throttle"),
    ("continuous", [0.0, -0.1, 0.0], "brake"),
    ("continuous", [0.0, 1.5, 0.0], "brake"),
    ("continuous", [0.0, 0.0, 0.5], "steering"),       # beyond ±0.349 rad/s
    ("continuous", [float("nan"), 0.0, 0.0], "throttle"),
    ("continuous", [0.0, 0.0], "shape"),
    ("continuous", {"throttle": 0.0, "brake": 0.0}, "keys"),
    ("continuous", {"throttle": "full", "brake": 0.0, "steering": 0.0}, "throttle"),
    ("discrete", [3, 1], "acceleration"),
    ("discrete", [1, -1], "steering"),
    ("discrete", [1.5, 1], "acceleration"),
    ("discrete", np.array([True, False]), "numeric"),
    ("discrete", [1, 1, 1], "shape"),
    ("discrete", DrivingAction(throttle=2.0), "throttle"),
])
def test_bad_actions_are_refused_naming_the_car_and_field(mode, raw, fragment):
    with pytest.raises(ValueError, match=fragment) as info:
        parse_action("car_3", raw, mode=mode, max_yaw_rate=LIMIT)
    assert "car_3" in str(info.value)


def test_round_off_at_a_bound_is_clamped_not_refused():
    action = parse_action("car_0", np.array([1.0000001, -1e-7, LIMIT + 1e-7], dtype=np.float64),
                          mode="continuous", max_yaw_rate=LIMIT)
    assert (action.throttle, action.brake, action.steering) == (1.0, 0.0, LIMIT)
    as_float32 = parse_action("car_0", np.float32([1, 0, LIMIT]), mode="continuous", max_yaw_rate=LIMIT)
    assert as_float32.steering == pytest.approx(LIMIT, rel=1e-6)
    assert parse_action("car_0", [2.0, 0.0], mode="discrete", max_yaw_rate=LIMIT) == DrivingAction(1.0, 0.0, -LIMIT)


def test_batched_and_per_car_actions_parse_alike_and_bad_batches_name_the_car():
    world = DrivingWorld(DrivingConfig(n_cars=3), seed=1)
    batch = np.array([[0, 0], [1, 1], [2, 2]])
    assert world.parse_actions(batch) == world.parse_actions([list(row) for row in batch])
    assert world.parse_actions(batch)[0] == DrivingAction(-1.0, 0.0, -LIMIT)
    with pytest.raises(ValueError, match="car_2.*acceleration"):
        world.parse_actions(np.array([[0, 0], [1, 1], [3, 2]]))
    with pytest.raises(ValueError, match="expected 3 actions"):
        world.parse_actions(np.array([[0, 0], [1, 1]]))
    continuous = DrivingWorld(DrivingConfig(n_cars=2, action_mode="continuous"), seed=1)
    ok = np.array([[0.5, 0.0, 0.1], [-1.0, 1.0, -LIMIT]])
    assert continuous.parse_actions(ok) == continuous.parse_actions([list(row) for row in ok])
    with pytest.raises(ValueError, match="car_1.*steering"):
        continuous.parse_actions(np.array([[0.5, 0.0, 0.1], [0.0, 0.0, 1.0]]))
