"""Walking, turning, head and kick motions of one motion period, against the configured step sizes."""
import math

import pytest

from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
from soccer_helpers import IDLE, idle_steps, make_world


def _body_frame_delta(world, index, before):
    x0, y0, yaw0 = before
    r = world.robots[index]
    dx, dy = r.x - x0, r.y - y0
    c, s = math.cos(yaw0), math.sin(yaw0)
    return c * dx + s * dy, -s * dx + c * dy, math.remainder(r.yaw - yaw0, math.tau)


@pytest.mark.parametrize("walk,forward,left", [
    (Walk.FORWARD, "forward_step", 0), (Walk.BACKWARD, "backward_step", 0),
    (Walk.LEFT, 0, "side_step"), (Walk.RIGHT, 0, "side_step")])
def test_walk_covers_the_configured_step_in_one_period(walk, forward, left):
    world = make_world()
    m = world.config.motion
    world.place_robot(0, -2.0, 0.5, 0.7)
    idle_steps(world, 1)
    r = world.robots[0]
    before = (r.x, r.y, r.yaw)
    world.step([SoccerAction(walk=walk), IDLE])
    along, side, turned = _body_frame_delta(world, 0, before)
    sign = -1 if walk in (Walk.BACKWARD, Walk.RIGHT) else 1
    want_along = sign * getattr(m, forward) if forward else 0.0
    want_side = sign * getattr(m, left) if left else 0.0
    assert along == pytest.approx(want_along, abs=0.003)
    assert side == pytest.approx(want_side, abs=0.003)
    assert turned == pytest.approx(0.0, abs=1e-3)


@pytest.mark.parametrize("turn,sign", [(Turn.LEFT, 1), (Turn.RIGHT, -1)])
def test_turn_rotates_by_the_configured_step_counter_clockwise_for_left(turn, sign):
    world = make_world()
    world.place_robot(0, -2.0, 0.5, 3.0)   # near ±π: the wrap must not matter
    idle_steps(world, 1)
    r = world.robots[0]
    before = (r.x, r.y, r.yaw)
    world.step([SoccerAction(turn=turn), IDLE])
    along, side, turned = _body_frame_delta(world, 0, before)
    assert turned == pytest.approx(sign * world.config.motion.turn_step, abs=0.004)
    assert math.hypot(along, side) < 0.003


def test_an_idle_robot_stays_put_and_a_walk_stops_with_its_period():
    world = make_world()
    world.place_robot(0, -2.0, 0.0, 0.0)
    world.step([SoccerAction(walk=Walk.FORWARD), IDLE])
    idle_steps(world, 1)
    x_after_walk = world.robots[0].x
    assert x_after_walk + 2.0 == pytest.approx(world.config.motion.forward_step, abs=1e-3)
    idle_steps(world, 3)
    assert world.robots[0].x == pytest.approx(x_after_walk, abs=1e-6)


def test_walking_and_turning_together_moves_and_turns():
    world = make_world()
    world.place_robot(0, -2.0, 0.0, 0.0)
    idle_steps(world, 1)
    world.step([SoccerAction(walk=Walk.FORWARD, turn=Turn.LEFT), IDLE])
    r = world.robots[0]
    assert r.x + 2.0 == pytest.approx(world.config.motion.forward_step, rel=0.1)
    assert r.y > 0.0            # the path bends toward the turn
    assert r.yaw == pytest.approx(world.config.motion.turn_step, abs=0.004)


def test_discrete_head_steps_and_clamps_at_the_limit():
    world = make_world()
    m = world.config.motion
    yaws = []
    for _ in range(5):
        world.step([[0, 0, 0, 2 * m.head_units], [0, 0, 0, m.head_units]])   # full left; centre index = no turn
        yaws.append(world.robots[0].head_yaw)
    per_period = m.head_step * m.head_units
    assert yaws[0] == pytest.approx(per_period)
    assert yaws[2] == pytest.approx(3 * per_period)
    assert yaws[-1] == pytest.approx(m.head_limit)
    assert world.robots[1].head_yaw == 0.0


def test_head_moves_within_the_period_so_each_vision_frame_sees_a_new_angle():
    world = make_world(head_mode="continuous")
    seen = []
    world.step([SoccerAction(head_yaw_delta=-0.5), IDLE], on_frame=lambda k: seen.append(world.robots[0].head_yaw))
    frames = world.config.rates.frames_per_period
    assert seen == pytest.approx([-0.5 * (k + 1) / frames for k in range(frames)])


def _kick_trial(ball_local, foot):
    world = make_world()
    world.place_robot(0, -2.0, 0.0, 0.0)
    world.place_ball(-2.0 + ball_local[0], ball_local[1])
    idle_steps(world, 1)
    start = world.ball_xy
    world.step([SoccerAction(kick=foot), IDLE])
    moved_during_windup = math.dist(start, world.ball_xy)
    world.step([IDLE, IDLE])
    speed = world.ball.velocity.length
    idle_steps(world, 14)
    return world, moved_during_windup, speed, math.dist(start, world.ball_xy)


@pytest.mark.parametrize("foot,side", [(Kick.LEFT_FOOT, 0.05), (Kick.RIGHT_FOOT, -0.05)])
def test_a_kick_strikes_the_ball_in_front_of_that_foot(foot, side):
    world, windup, speed, travel = _kick_trial((0.17, side), foot)
    assert windup < 1e-6                       # a kick takes two periods: nothing moves in the first
    assert 2.0 < speed < 3.6                   # ≈3.3 m/s at contact, less after the rest of the period rolling
    assert 3.8 < travel < 5.2                  # DynEnv: ≈4.6 m
    assert world.ball_xy[0] > -2.0 + 3.5       # forward along the robot's heading
    assert 0 in world.state.chain


@pytest.mark.parametrize("ball_local,foot", [((0.17, -0.05), Kick.LEFT_FOOT), ((0.17, 0.05), Kick.RIGHT_FOOT),
                                             ((0.45, 0.05), Kick.LEFT_FOOT), ((-0.2, 0.05), Kick.LEFT_FOOT)])
def test_a_kick_misses_a_ball_not_in_front_of_that_foot(ball_local, foot):
    world, windup, speed, travel = _kick_trial(ball_local, foot)
    assert travel < 0.05
    assert 0 not in world.state.chain


def test_kick_is_ignored_while_walking_and_robot_is_busy_during_a_kick():
    world = make_world()
    world.place_robot(0, -2.0, 0.0, 0.0)
    world.step([SoccerAction(walk=Walk.FORWARD, kick=Kick.LEFT_FOOT), IDLE])
    assert world.robots[0].kick is None
    world.step([SoccerAction(kick=Kick.LEFT_FOOT), IDLE])
    x = world.robots[0].x
    world.step([SoccerAction(walk=Walk.FORWARD), IDLE])      # second kick period: the walk is ignored
    assert world.robots[0].x == pytest.approx(x, abs=1e-3)
    world.step([SoccerAction(walk=Walk.FORWARD), IDLE])      # kick over: walks again
    assert world.robots[0].x > x + 0.04


def test_other_rates_keep_the_distance_per_action():
    world = make_world(rates={"physics_hz": 200.0, "vision_period_ticks": 20, "motion_period_ticks": 100})
    world.place_robot(0, -2.0, 0.0, 0.0)
    frames = []
    world.step([SoccerAction(walk=Walk.FORWARD), IDLE], on_frame=frames.append)
    assert frames == [0, 1, 2, 3, 4]
    assert world.tick == 100
    assert world.robots[0].x + 2.0 == pytest.approx(world.config.motion.forward_step, abs=0.003)


def test_the_ball_rolls_decelerates_and_stops():
    world = make_world()
    world.place_ball(-3.0, -1.0, 2.0, 0.0)
    idle_steps(world, 1)
    v_half_second = world.ball.velocity.x
    assert v_half_second == pytest.approx(2.0 - world.config.ball.deceleration * 0.5, abs=0.02)
    idle_steps(world, 6)
    assert world.ball.velocity.length == 0.0
    assert world.ball_xy[0] + 3.0 == pytest.approx(2.0 ** 2 / (2 * world.config.ball.deceleration), abs=0.03)


def test_the_ball_bounces_off_a_goalpost_and_off_a_robot():
    world = make_world()
    post_x, post_y = world.config.field.goalposts[3]
    world.place_ball(post_x - 0.5, post_y, 2.0, 0.0)
    idle_steps(world, 1)
    assert world.ball.velocity.x < -0.5 and world.ball_xy[0] < post_x - 0.1
    world.place_robot(0, 0.0, -2.0, 0.0)
    world.place_ball(0.6, -2.0, -2.0, 0.0)
    idle_steps(world, 1)
    assert world.ball.velocity.x > 0.1
    assert world.robots[0].x == pytest.approx(0.0, abs=0.02)   # the driven robot holds its place
