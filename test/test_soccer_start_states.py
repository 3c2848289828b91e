"""Start states of the soccer world (``SoccerConfig.start``, docs/soccer.md "Start states"): the kickoff start stays
the default and unchanged; an attack start puts the ball and the attackers where its settings say, reproducibly per
seed; defenders out of play (``defenders: absent``) neither act, collide, appear in anyone's perception nor earn;
a chaser walks the ball into the empty goal; the team that attacks alternates; a goal restarts with a kickoff;
``kickoff_share`` mixes kickoffs into attack starts in that share of episodes."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectStatus
from dynenv_ros.envs.learning_targets import other_robots
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.perception.params import load_preset
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.actions import SoccerAction, Walk
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.referee import Phase
from dynenv_ros.soccer.scripted import team_policies
from dynenv_ros.soccer.vision import SoccerVision
from dynenv_ros.soccer.world import TEAM_A, TEAM_B, SoccerWorld

# Documented numbers (docs/soccer.md, "Start states"; the SPL field of soccer/field.py)
HALF_LENGTH, HALF_WIDTH, BORDER = 4.5, 3.0, 0.7          # m
START_MARGIN = 0.3                                       # m: the ball this far inside every line
GOAL_AREA_DEPTH, GOAL_AREA_HALF_WIDTH = 0.6, 1.1         # m
YAW_JITTER = 0.35                                        # rad: attackers face the goal within this
FORWARD = SoccerAction(walk=Walk.FORWARD)


def attack(players: int = 2, seconds: float = 120.0, falls=None, **start) -> SoccerConfig:
    return SoccerConfig.from_mapping({"players_per_team": players, "episode_seconds": seconds,
                                      "start": {"kind": "attack", **start}, **({"falls": falls} if falls else {})})


def attacked_goal(team: int) -> tuple[float, float]:
    """The centre of the goal ``team`` attacks: team A attacks +x, team B -x."""
    return team * HALF_LENGTH, 0.0


def test_the_kickoff_stays_the_default_start_and_reset_without_a_team_is_team_as_kickoff():
    assert SoccerConfig().start.kind == "kickoff"
    worlds = [SoccerWorld(seed=4), SoccerWorld(SoccerConfig.from_mapping({"start": {"kind": "kickoff"}}), seed=4)]
    worlds[0].reset(seed=9)
    worlds[1].reset(seed=9, kickoff_team=TEAM_A)
    for world in worlds:
        assert world.state.phase == Phase.KICKOFF and world.state.ball_owner == TEAM_A
        assert world.ball_xy == (0.0, 0.0)
    assert worlds[0].snapshot() == worlds[1].snapshot()


@pytest.mark.parametrize("players", [1, 2, 5])
@pytest.mark.parametrize("low, high", [(1.0, 3.0), (2.0, 6.0)])
def test_an_attack_start_puts_the_ball_and_the_attackers_where_its_settings_say(players, low, high):
    config = attack(players, ball_distance_min=low, ball_distance_max=high, attacker_distance=1.0,
                    defenders="absent")
    world = SoccerWorld(config, seed=11)
    for episode in range(1, 41):
        world.reset()
        team = TEAM_B if episode % 2 else TEAM_A            # team A in even episodes, team B in odd ones
        assert world.state.kickoff_team == team
        gx, gy = attacked_goal(team)
        bx, by = world.ball_xy
        assert low - 1e-9 <= math.hypot(bx - gx, by - gy) <= high + 1e-9
        assert abs(bx) <= HALF_LENGTH - START_MARGIN + 1e-9 and abs(by) <= HALF_WIDTH - START_MARGIN + 1e-9
        assert abs(math.atan2(by, team * (gx - bx))) <= math.radians(60.0) + 1e-9   # within 60° of the goals' axis
        assert world.state.phase == Phase.PLAYING and world.state.ball_owner == 0 and not world.state.chain
        for robot in world.robots:
            if robot.team != team:
                continue
            assert 0.25 - 1e-9 <= math.hypot(robot.x - bx, robot.y - by) <= 1.0 + 1e-9
            assert abs(robot.x) <= HALF_LENGTH and abs(robot.y) <= HALF_WIDTH          # inside the field
            # behind the ball, seen from the goal: no nearer the goal's centre than the ball and a robot radius
            assert math.hypot(robot.x - gx, robot.y - gy) > math.hypot(bx - gx, by - gy) - 1.0
            facing = math.atan2(gy - robot.y, gx - robot.x)
            assert abs(math.remainder(robot.yaw - facing, math.tau)) <= YAW_JITTER + 1e-6


@pytest.mark.parametrize("low, high", [(0.5, 0.5), (8.7, 8.7), (0.5, 8.7)])
@pytest.mark.parametrize("defenders", ["present", "absent"])
def test_every_start_within_the_bounds_finds_room_for_five_a_side(low, high, defenders):
    """The bounds' corners (docs/soccer.md): the ball 0.5 m from the goal or 8.7 m (0.3 m before the own goal line),
    bearings up to 90°, five attackers within 0.75 m: 100 resets, each scene keeping its distances."""
    world = SoccerWorld(attack(5, ball_distance_min=low, ball_distance_max=high, ball_max_angle=math.pi / 2,
                               attacker_distance=0.75, defenders=defenders), seed=7)
    for _ in range(100):
        world.reset()
        bx, by = world.ball_xy
        on_field = [r for r in world.robots if not r.rules.absent]
        assert len(on_field) == (10 if defenders == "present" else 5)
        assert all(math.hypot(r.x - bx, r.y - by) >= 0.25 - 1e-9 for r in on_field)
        assert all(math.hypot(a.x - b.x, a.y - b.y) >= 0.3 - 1e-9 for a in on_field for b in on_field if a is not b)


def test_an_attack_start_is_reproducible_for_a_seed_and_differs_between_seeds():
    config = attack(2, ball_distance_min=1.0, ball_distance_max=3.0)
    first, again, other = (SoccerWorld(config, seed=s) for s in (5, 5, 6))
    for world in (first, again, other):
        world.reset()
    assert first.snapshot() == again.snapshot()
    assert first.ball_xy != other.ball_xy
    assert [(r.x, r.y) for r in first.robots] != [(r.x, r.y) for r in other.robots]


def test_defenders_present_stand_at_their_kickoff_defending_spots_keeper_in_its_goal_area():
    world = SoccerWorld(attack(2, defenders="present"), seed=2)
    for _ in range(20):
        world.reset()
        team = world.state.kickoff_team
        keeper, second = [r for r in world.robots if r.team == -team]     # slot 0 keeps goal, slot 1 defends
        own_x = team                                       # the defenders' own goal: the one team attacks
        assert keeper.x * own_x >= HALF_LENGTH - GOAL_AREA_DEPTH and abs(keeper.y) <= GOAL_AREA_HALF_WIDTH
        # "just outside the centre circle": x -1.7 .. -2.2 in its own frame, |y| at most 0.25 (placement.py)
        assert 1.7 - 1e-9 <= second.x * own_x <= 2.2 + 1e-9 and abs(second.y) <= 0.25 + 1e-9
        assert not (keeper.rules.penalized or second.rules.penalized)
        bx, by = world.ball_xy
        assert all(math.hypot(r.x - bx, r.y - by) >= 0.25 - 1e-9 for r in world.robots)


def test_reset_takes_the_next_settings_and_an_explicit_attacking_team():
    world = SoccerWorld(seed=1)
    world.reset(kickoff_team=TEAM_B, config=attack(2, defenders="absent"))
    assert world.config.start.kind == "attack" and world.state.kickoff_team == TEAM_B
    assert [r.rules.absent for r in world.robots] == [True, True, False, False]
    with pytest.raises(ValueError, match="players_per_team"):
        world.reset(config=attack(3))


def _chaser_game(world: SoccerWorld, periods: int, overrides=None):
    """Every robot a chaser (absent ones too: their actions must do nothing); the results of each period."""
    policies = team_policies(world.config.players_per_team, "chaser", field=world.config.field)
    results = []
    for _ in range(periods):
        snapshot = world.snapshot()
        actions = [policies[i].act(snapshot, i) for i in range(world.n_robots)]
        for i, action in (overrides or {}).items():
            actions[i] = action
        results.append(world.step(actions))
        if results[-1].truncated:
            break
    return results


@pytest.mark.parametrize("players", [1, 2])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_chaser_walks_the_ball_into_the_empty_goal_then_the_game_restarts_with_a_kickoff(players, seed):
    world = SoccerWorld(attack(players, seconds=20.0, ball_distance_min=1.0, ball_distance_max=3.0,
                               defenders="absent"), seed=seed)
    world.reset()
    team = world.state.kickoff_team
    results = _chaser_game(world, 40)                  # 20 s
    periods = [t for t, r in enumerate(results) if any(e.kind == "goal" for e in r.events)]
    assert periods, "no goal in 20 s"
    first = results[periods[0]]
    assert [e.team for e in first.events if e.kind == "goal"] == [team]
    attackers = [r.index for r in world.robots if r.team == team]
    # the goal's reward (25, shared): every attacker gets its team share at least
    assert all(first.rewards[RewardTerm.PRIMARY, i] >= 0.1 * 25.0 - 1e-9 for i in attackers)
    # after a goal the game goes on with a kickoff of the team that conceded; the episode ends only at its time
    assert not any(r.truncated for r in results[:-1]) and results[-1].truncated and len(results) == 40
    world2 = SoccerWorld(attack(players, seconds=20.0, ball_distance_min=1.0, ball_distance_max=3.0,
                                defenders="absent"), seed=seed)
    world2.reset()
    _chaser_game(world2, periods[0] + 1)                # the same game, up to the period of the goal
    assert math.hypot(*world2.ball_xy) < 1e-6 and world2.state.phase == Phase.KICKOFF
    assert world2.state.ball_owner == -team


def test_absent_defenders_neither_act_collide_nor_earn():
    world = SoccerWorld(attack(2, seconds=30.0, defenders="absent"), seed=3)
    world.reset()
    team = world.state.kickoff_team
    absent = [r for r in world.robots if r.team != team]
    spots = [(r.x, r.y, r.yaw) for r in absent]
    space_shapes = set(world.physics.space.shapes)
    for robot in absent:
        assert robot.rules.absent and robot.rules.penalized and not robot.can_act
        assert robot.shape not in space_shapes                         # nothing can touch it
        assert not world.config.field.is_inside_world(robot.x, robot.y)  # off the carpet
    # told to walk forward all game long while the attackers play (and score)
    results = _chaser_game(world, 60, {r.index: FORWARD for r in absent})
    assert any(e.kind == "goal" for r in results for e in r.events)
    for robot, spot in zip(absent, spots):
        assert (robot.x, robot.y, robot.yaw) == spot
        assert all(e.robot != robot.index for r in results for e in r.events)   # no touch, fall, penalty, return
        assert all(robot.index not in pair for pair in world._contacts)
        assert all(float(np.abs(r.rewards[:, robot.index]).sum()) == 0.0 for r in results)
        state = world.snapshot().objects[robot.index]
        assert state.status & ObjectStatus.PENALIZED and state.penalty_remaining > world.time_remaining


def test_absent_defenders_appear_in_no_detection_and_earn_no_observation_reward():
    """A robot at the sideline facing the spot where an absent defender stands, 1.8 m away, never detects it, under
    every perception preset (dynenv's has no range limit); the same robot facing a defender placed at that very spot
    does (so the check can fail). Perceived as placed: a step would penalize the present robot for being off the
    carpet."""
    spot = (-1.0, -(HALF_WIDTH + BORDER + 1.0))                 # team B slot 0's absent spot (placement.absent_spot)
    for preset in ("none", "dynenv", "realistic"):
        detected = {}
        for defenders in ("absent", "present"):
            world = SoccerWorld(attack(2, defenders=defenders, falls={"enabled": False}), seed=0)
            world.reset(kickoff_team=TEAM_A)
            if defenders == "present":
                world.place_robot(2, *spot, 0.0)
            world.place_robot(0, -1.0, -2.9, -math.pi / 2)
            vision = SoccerVision(world, load_preset(preset))
            hits = 0
            for _ in range(4):                 # the scene as placed (stepping would penalize a robot off the carpet)
                for k in range(world.config.rates.frames_per_period):
                    vision.frame(k)
                perception = vision.perceive()
                hits += int(perception.seen[:, 2].sum() + (perception.detections["true_id"] == 2).sum())
                rewards = vision.observation_rewards(perception)
                if defenders == "absent":
                    assert not perception.visible[:, 2].any() and not perception.visible[:, 3].any()
                    assert rewards[2] == 0.0 and rewards[3] == 0.0 and rewards[0] > 0.0
            detected[defenders] = hits
        assert detected["absent"] == 0, preset
        assert detected["present"] > 0, preset


def test_absent_defenders_are_left_out_of_the_ground_truth_and_the_learning_targets_of_a_vector_env():
    config = attack(2, seconds=10.0, defenders="absent")      # 20 periods: the 10 stepped are one episode
    with SoccerVectorEnv(2, backend="inprocess", config=config, targets=True, perception="none") as env:
        env.reset(seed=3)
        worlds = env._batch.worlds
        totals = np.zeros((2, 4))
        for _ in range(10):
            result = env.step(np.zeros((2, 4, 4), np.int64))
            totals += np.abs(result.reward_terms).sum(axis=1)
            for e, world in enumerate(worlds):
                absent = [r.index for r in world.robots if r.rules.absent]
                assert len(absent) == 2
                for i in absent:
                    assert not world.config.field.is_inside_world(world.robots[i].x, world.robots[i].y)
                present = [r.index for r in world.robots if not r.rules.absent]
                # nobody in play ever sees an absent robot (robots_seen: the rows of the other robots)
                rows = other_robots(2)
                for observer in present:
                    for column, other in enumerate(rows[observer]):
                        if other in absent:
                            assert result.targets["robots_seen"][e, observer, column] == 0.0
        for e, world in enumerate(worlds):
            for robot in world.robots:
                assert (totals[e, robot.index] == 0.0) == robot.rules.absent   # the others see and earn


@pytest.mark.parametrize("start, message", [
    ({"kind": "penalty"}, "start.kind"),
    ({"kind": "attack", "defenders": "some"}, "start.defenders"),
    ({"kind": "attack", "ball_distance_min": 4.0, "ball_distance_max": 2.0}, "start.ball_distance_min"),
    ({"kind": "attack", "ball_distance_max": 9.0}, "start.ball_distance_min/max"),    # beyond 9 - 0.3 m
    ({"kind": "attack", "ball_distance_min": 0.2}, "start.ball_distance_min/max"),    # below 0.5 m
    ({"kind": "attack", "ball_max_angle": 2.0}, "start.ball_max_angle"),
    ({"kind": "attack", "attacker_distance": 0.5}, "start.attacker_distance"),         # below 0.75 m
    ({"kind": "attack", "unknown": 1}, "start.unknown"),
    ({"kind": "attack", "kickoff_share": 1.5}, "start.kickoff_share must be in"),
    ({"kind": "attack", "kickoff_share": -0.1}, "start.kickoff_share must not be negative"),
    ({"kind": "attack", "kickoff_share": float("nan")}, "start.kickoff_share"),
    ({"kind": "kickoff", "kickoff_share": 0.5}, "start.kickoff_share mixes"),
    ({"kind": "attack", "kickoff_share": 0.5, "defenders": "absent"}, "start.kickoff_share needs"),
])
def test_start_settings_that_cannot_work_are_refused_naming_the_key(start, message):
    with pytest.raises(ValueError, match=message.replace(".", r"\.").replace("/", "/")):
        SoccerConfig.from_mapping({"start": start})


def test_a_kickoff_share_mixes_kickoffs_into_attack_starts_in_that_share_of_episodes():
    """kickoff_share 0.3 over 400 episodes: the kickoffs are Binomial(400, 0.3), mean 120, sd 9.2; 5 sd either side
    is 74..166. A kickoff episode is the game's own start (the ball on the centre spot, team A to kick off); an
    attack episode has the ball 2-6 m from the goal its team attacks."""
    world = SoccerWorld(attack(2, ball_distance_min=2.0, ball_distance_max=6.0, kickoff_share=0.3), seed=21)
    kinds = []
    for _ in range(400):
        world.reset()
        kinds.append(world.start_kind)
        if world.start_kind == "kickoff":
            assert world.ball_xy == (0.0, 0.0) and world.state.phase == Phase.KICKOFF
            assert world.state.ball_owner == TEAM_A
        else:
            team = TEAM_B if world.episode_id % 2 else TEAM_A
            gx, gy = attacked_goal(team)
            distance = math.hypot(world.ball_xy[0] - gx, world.ball_xy[1] - gy)
            assert 2.0 - 1e-9 <= distance <= 6.0 + 1e-9 and world.state.phase == Phase.PLAYING
    assert set(kinds) == {"attack", "kickoff"} and 74 <= kinds.count("kickoff") <= 166


def test_kickoff_shares_of_0_and_1_are_pure_attacks_and_pure_kickoffs_and_0_draws_nothing():
    plain = SoccerWorld(attack(2), seed=5)
    zero = SoccerWorld(attack(2, kickoff_share=0.0), seed=5)
    every = SoccerWorld(attack(2, kickoff_share=1.0), seed=5)
    for _ in range(20):
        for world in (plain, zero, every):
            world.reset()
        assert plain.start_kind == zero.start_kind == "attack" and every.start_kind == "kickoff"
        assert plain.snapshot() == zero.snapshot()           # the same random stream: no draw for a share of 0
