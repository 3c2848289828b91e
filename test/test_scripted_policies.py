"""Scripted policies: they must really play (score, guard, clear), stay legal, and be reproducible."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dynenv_ros.soccer.actions import IDLE, Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import MotionConfig, SoccerConfig
from dynenv_ros.soccer.scripted import (ChaserPolicy, GoalkeeperPolicy, RandomPolicy, ScriptedPolicy, act_all,
                                        find_robot, team_policies, to_robot_frame, wrap)
from dynenv_ros.soccer.world import TEAM_A, TEAM_B, GameEvent, SoccerWorld

MOTION = MotionConfig()
HALF_LENGTH, AREA_LENGTH, AREA_HALF_WIDTH = 4.5, 1.65, 2.0


def duel_world(team: int, robot_xy_yaw: tuple[float, float, float], ball_xy: tuple[float, float]
               ) -> tuple[SoccerWorld, int]:
    """One robot per side, no random falls; the other robot parked in a far corner, the ball free."""
    world = SoccerWorld(SoccerConfig.from_mapping({"players_per_team": 1, "falls": {"enabled": False}}), seed=5)
    me = 0 if team == TEAM_A else 1
    world.place_robot(1 - me, -team * 4.3, 2.8, 0.0)
    world.place_robot(me, *robot_xy_yaw)
    world.place_ball(*ball_xy)
    world.set_ball_owner(0, 0)
    return world, me


def run_alone(world: SoccerWorld, me: int, policy: ScriptedPolicy, periods: int,
              stop_on_goal: bool = True) -> tuple[list[GameEvent], list[tuple[float, float, float]]]:
    """Step with ``policy`` driving robot ``me`` and the other robot idle; events and the robot's poses."""
    events: list[GameEvent] = []
    poses = []
    for _ in range(periods):
        actions = [IDLE] * world.n_robots
        actions[me] = policy.act(world.snapshot(), me)
        result = world.step(actions)
        robot = world.robots[me]
        poses.append((robot.x, robot.y, robot.yaw))
        events += result.events
        if stop_on_goal and any(e.kind == "goal" for e in result.events):
            break
    return events, poses


def mirrored(team: int, x: float, y: float) -> tuple[float, float]:
    """A team-A situation as the same situation for ``team`` (team B's frame is the point reflection)."""
    return team * x, team * y


# -- chaser ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("team", [TEAM_A, TEAM_B], ids=["team_A", "team_B"])
@pytest.mark.parametrize("start", ["behind_ball_facing_sideways", "between_ball_and_goal_facing_it",
                                   "ball_resting_on_the_goal_line"])
def test_lone_chaser_scores_on_the_opponent_goal(team: int, start: str) -> None:
    if start == "behind_ball_facing_sideways":
        ball, robot, yaw = (2.0, -0.3), (0.0, -0.3), math.pi / 2
    elif start == "between_ball_and_goal_facing_it":   # must go round the ball, not push it to its own goal
        ball, robot, yaw = (1.5, 0.4), (3.5, 0.4), math.pi
    else:   # over the line but not wholly: still in play, and behind the goal centre's x
        ball, robot, yaw = (4.52, 0.3), (2.52, 0.3), 0.0
    rx, ry = mirrored(team, *robot)
    world, me = duel_world(team, (rx, ry, wrap(yaw + (0.0 if team == TEAM_A else math.pi))), mirrored(team, *ball))
    assert math.dist((rx, ry), world.ball_xy) == pytest.approx(2.0)

    events, _ = run_alone(world, me, ChaserPolicy(), periods=120)

    goals = [e for e in events if e.kind == "goal"]
    assert goals, f"no goal in 120 periods; events: {[(e.kind, e.robot, e.detail) for e in events]}"
    assert goals[0].team == team
    assert world.state.score[team] == 1 and world.state.score[-team] == 0
    touches = [e.robot for e in events if e.kind == "touch"]
    assert touches and set(touches) == {me}
    assert not [e for e in events if e.kind in ("penalty", "out")]


def test_chaser_keeps_off_the_ball_during_an_opponent_free_kick() -> None:
    world, me = duel_world(TEAM_A, (0.0, 0.45, -math.pi / 2), (0.5, 0.0))   # close beside the ball
    world.set_ball_owner(TEAM_B, 10.0)      # 20 periods
    events, poses = run_alone(world, me, ChaserPolicy(), periods=18, stop_on_goal=False)
    assert not [e for e in events if e.kind in ("touch", "penalty")]
    gaps = [math.dist(p[:2], world.ball_xy) for p in poses]
    assert 0.75 < gaps[-1] < 1.2, f"should wait close to, but off the ball; gap {gaps[-1]:.2f} m"
    events, _ = run_alone(world, me, ChaserPolicy(), periods=40)   # ownership ends: now it goes for the ball
    assert any(e.kind == "touch" and e.robot == me for e in events)


def test_chaser_head_turns_onto_the_ball_without_overshooting() -> None:
    world, me = duel_world(TEAM_A, (0.0, 0.0, 0.0), (0.0, 1.5))   # ball 90° to the left
    policy = ChaserPolicy()
    heads = []
    for _ in range(5):   # only the head moves, so the bearing stays 90°
        delta = policy.act(world.snapshot(), me).head_yaw_delta
        assert abs(delta) <= 3 * math.radians(12.5) + 1e-12
        world.step([SoccerAction(head_yaw_delta=delta), IDLE])
        heads.append(world.robots[me].head_yaw)
    assert heads[0] == pytest.approx(3 * math.radians(12.5))     # as far as one period allows
    assert heads[-2:] == pytest.approx([math.pi / 2] * 2)         # then on the ball, and it stays there
    world.place_ball(1.5, -0.2)                                   # now a small bearing to the right
    snapshot = world.snapshot()
    robot = snapshot.objects[me]
    bx, by = to_robot_frame(robot, 1.5, -0.2)
    delta = policy.act(snapshot, me).head_yaw_delta
    assert delta == pytest.approx(-3 * math.radians(12.5))
    world.step([SoccerAction(head_yaw_delta=delta), IDLE])
    for _ in range(3):
        world.step([policy.act(world.snapshot(), me), IDLE])
    robot = world.snapshot().objects[me]
    bx, by = to_robot_frame(robot, *world.ball_xy)
    assert abs(wrap(math.atan2(by, bx) - robot.head_yaw)) < math.radians(5)


# -- goalkeeper --------------------------------------------------------------------------------------------------
def in_own_penalty_area(team: int, x: float, y: float) -> bool:
    depth = HALF_LENGTH + team * x              # metres in front of the own goal line
    return 0.0 <= depth <= AREA_LENGTH and abs(y) <= AREA_HALF_WIDTH


@pytest.mark.parametrize("team", [TEAM_A, TEAM_B], ids=["team_A", "team_B"])
@pytest.mark.parametrize("ball_y", [1.5, -2.0])
def test_goalkeeper_guards_its_goal_and_follows_the_ball_sideways(team: int, ball_y: float) -> None:
    kx, ky = mirrored(team, -4.2, 0.0)
    world, me = duel_world(team, (kx, ky, 0.0 if team == TEAM_A else math.pi), mirrored(team, -2.5, ball_y))
    events, poses = run_alone(world, me, GoalkeeperPolicy(), periods=60, stop_on_goal=False)
    assert all(in_own_penalty_area(team, x, y) for x, y, _ in poses), "the keeper left its penalty area"
    field_yaw = 0.0 if team == TEAM_A else math.pi
    assert all(abs(wrap(yaw - field_yaw)) < 0.2 for _, _, yaw in poses), "the keeper should face the field"
    x, y, _ = poses[-1]
    ball_side = math.copysign(1.0, world.ball_xy[1])
    assert y * ball_side > 0.5, f"keeper ended at y={y:.2f}, ball at y={world.ball_xy[1]:.2f}"
    assert abs(y) < 0.8, "the keeper should stay in front of the goal mouth"
    assert HALF_LENGTH + team * x == pytest.approx(0.3, abs=0.1)
    assert not [e for e in events if e.kind in ("touch", "penalty")]


@pytest.mark.parametrize("team", [TEAM_A, TEAM_B], ids=["team_A", "team_B"])
def test_goalkeeper_clears_a_ball_close_in_front(team: int) -> None:
    kx, ky = mirrored(team, -4.2, 0.0)
    world, me = duel_world(team, (kx, ky, 0.0 if team == TEAM_A else math.pi), mirrored(team, -3.8, 0.3))
    events, poses = run_alone(world, me, GoalkeeperPolicy(), periods=40, stop_on_goal=False)
    assert any(e.kind == "touch" and e.robot == me for e in events)
    assert not [e for e in events if e.kind == "goal"]
    assert HALF_LENGTH + team * world.ball_xy[0] > 3.0, "the ball should be cleared well away from the goal"
    assert all(in_own_penalty_area(team, x, y) for x, y, _ in poses)


# -- random --------------------------------------------------------------------------------------------------------
def random_draws(seed: int, n: int, head_mode: str = "discrete") -> list[SoccerAction]:
    world = SoccerWorld(SoccerConfig.from_mapping({"players_per_team": 1}), seed=0)
    snapshot = world.snapshot()
    policy = RandomPolicy(np.random.default_rng(seed), head_mode=head_mode)  # type: ignore[arg-type]
    return [policy.act(snapshot, 0) for _ in range(n)]


def test_random_policy_is_reproducible_from_its_generator() -> None:
    assert random_draws(11, 50) == random_draws(11, 50)
    assert random_draws(11, 50) != random_draws(12, 50)
    assert random_draws(3, 50, "continuous") == random_draws(3, 50, "continuous")


def test_random_policy_covers_every_value() -> None:
    draws = random_draws(0, 200)
    assert {a.walk for a in draws} == set(Walk)
    assert {a.turn for a in draws} == set(Turn)
    assert {a.kick for a in draws} == set(Kick)
    heads = {round(a.head_yaw_delta / MOTION.head_step, 9) for a in draws}
    assert heads == {float(d) for d in range(-MOTION.head_units, MOTION.head_units + 1)}
    continuous = [a.head_yaw_delta for a in random_draws(0, 200, "continuous")]
    assert max(abs(h) for h in continuous) <= MOTION.head_max_delta
    assert min(continuous) < -0.8 * MOTION.head_max_delta and max(continuous) > 0.8 * MOTION.head_max_delta
    with pytest.raises(ValueError, match="head_mode"):
        RandomPolicy(np.random.default_rng(0), head_mode="analog")  # type: ignore[arg-type]


@pytest.mark.parametrize("team", [TEAM_A, TEAM_B], ids=["team_A", "team_B"])
def test_eager_chaser_kicks_a_ball_at_its_foot_without_lining_up(team: int) -> None:
    # Ball squarely in front of the left foot (robot frame x 0.20 m, y +0.05 m), the robot 0.5 rad off the aim
    # at the goal: the chaser lines up first (no kick), the eager chaser (tolerance 1.2 rad) kicks now, with the
    # left foot; 1.5 rad off the aim, beyond its tolerance, it lines up like the chaser.
    for yaw_off, eager_kicks in ((0.5, True), (1.5, False)):
        yaw = wrap(yaw_off + (0.0 if team == TEAM_A else math.pi))
        rx, ry = mirrored(team, -1.0, 0.0)
        c, s_ = math.cos(yaw), math.sin(yaw)
        ball = (rx + 0.20 * c - 0.05 * s_, ry + 0.20 * s_ + 0.05 * c)
        world, me = duel_world(team, (rx, ry, yaw), ball)
        snapshot = world.snapshot()
        assert to_robot_frame(find_robot(snapshot, me), *world.ball_xy) == pytest.approx((0.20, 0.05), abs=1e-6)
        assert ChaserPolicy().act(snapshot, me).kick == Kick.NONE
        eager = ChaserPolicy(eager_kick_tolerance=1.2).act(snapshot, me)
        assert eager.kick == (Kick.LEFT_FOOT if eager_kicks else Kick.NONE)
        if eager_kicks:
            assert (eager.walk, eager.turn) == (Walk.NONE, Turn.NONE)


# -- teams -----------------------------------------------------------------------------------------------------------
def test_team_policies_builds_one_policy_per_robot() -> None:
    chasers = team_policies(2, "chaser")
    assert len(chasers) == 4 and all(isinstance(p, ChaserPolicy) for p in chasers)
    mixed = team_policies(3, "keeper_and_chasers")
    assert [type(p) for p in mixed] == [GoalkeeperPolicy, ChaserPolicy, ChaserPolicy] * 2
    assert [type(p) for p in team_policies(1, "keeper_and_chasers")] == [ChaserPolicy] * 2
    eager = team_policies(2, "eager_chaser")
    assert [p.eager_kick_tolerance for p in eager] == [1.2] * 4 and chasers[0].eager_kick_tolerance is None
    randoms = team_policies(2, "random", np.random.default_rng(4))
    assert all(isinstance(p, RandomPolicy) for p in randoms)
    assert len({id(p.rng) for p in randoms}) == 4, "each robot needs its own generator"
    with pytest.raises(ValueError, match="kind"):
        team_policies(1, "striker")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_per_team"):
        team_policies(0)


@pytest.mark.parametrize("kind", ["chaser", "eager_chaser", "random", "keeper_and_chasers"])
def test_team_actions_are_valid_and_reproducible_in_a_full_game(kind: str) -> None:
    def play(seed: int) -> list[list[SoccerAction]]:
        world = SoccerWorld(SoccerConfig.from_mapping({"players_per_team": 2}), seed=seed)
        policies = team_policies(2, kind, np.random.default_rng(seed))  # type: ignore[arg-type]
        history = []
        for _ in range(40):
            actions = act_all(policies, world.snapshot())
            assert world.parse_actions(actions) == actions
            assert all(abs(a.head_yaw_delta) <= MOTION.head_max_delta + 1e-12 for a in actions)
            world.step(actions)
            history.append(actions)
        return history

    first = play(21)
    assert first == play(21)
    assert any(a.moves for actions in first for a in actions)
