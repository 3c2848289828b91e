"""Reward terms: ball progress along the touch chain, approach shaping, teleports, the observation term, and the
mirror symmetry between the teams."""
import math

import numpy as np
import pytest

from dynenv_ros.envs.soccer_spaces import GroundTruthEncoder
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
from dynenv_ros.soccer.config import RewardConfig
from dynenv_ros.soccer.rewards import observation_reward
from soccer_helpers import IDLE, idle_steps, make_world

NO_APPROACH = {"approach_per_m": 0.0}


def test_ball_progress_is_shared_along_the_touch_chain_and_with_the_team():
    world = make_world(players_per_team=2, rewards=NO_APPROACH)
    w = world.config.rewards
    world.state.chain[:] = [1, 0]
    world.place_ball(0.0, 0.0, 1.0, 0.0)
    result = world.step([IDLE] * 4)
    dx = world.ball_xy[0]
    c = w.ball_progress_per_m * dx
    aux = result.rewards[RewardTerm.AUXILIARY]
    assert dx > 0.3
    assert aux[1] == pytest.approx(c * (1 + w.team_share))
    assert aux[0] == pytest.approx(c * (w.chain_decay + w.team_share))
    # Team B loses the team share; robots outside the chain that are closest to the ball share the loss too.
    assert aux[2] + aux[3] == pytest.approx(-2 * w.team_share * c - w.bystander_share * c)


def test_goal_reward_magnitudes_along_the_chain_and_for_bystanders():
    """docs/soccer.md primary term (docs/original.md §6.1, same weights): ±25 per goal; every robot 0.1 × its team's
    value; the i-th robot of the touch chain (newest first, either team) 25 × 0.5^i times its team's sign; robots
    of the losing side outside the chain that are their team's closest to the ball or within 1.5 m of it, half
    the loss."""
    world = make_world(players_per_team=3)          # team A: robots 0, 1, 2; team B: 3, 4, 5
    world.place_robot(0, 1.0, 1.0, 0.0)
    world.place_robot(1, 2.0, -1.0, 0.0)
    world.place_robot(2, -2.0, 0.0, 0.0)
    world.place_robot(3, 4.0, -0.5, math.pi)        # team B's closest to the ball, but in the chain
    world.place_robot(4, 3.8, 0.9, math.pi)         # ≈1.1 m from where the ball crosses the line (4.55, 0.1)
    world.place_robot(5, 0.0, -2.0, math.pi)        # far from the ball
    world.state.chain[:] = [3, 1, 0]                # B's robot 3 touched last (own goal), then A's 1, then A's 0
    world.place_ball(4.3, 0.1, 1.5, 0.0)
    result = world.step([IDLE] * 6)
    assert [g.team for g in result.events if g.kind == "goal"] == [1]
    primary = result.rewards[RewardTerm.PRIMARY].tolist()
    assert primary == pytest.approx([0.1 * 25 + 25 * 0.25,          # robot 0: third in the chain
                                     0.1 * 25 + 25 * 0.5,           # robot 1: second in the chain
                                     0.1 * 25,                      # robot 2: team share only
                                     -0.1 * 25 - 25 * 1.0,          # robot 3: first in the chain, on the losing side
                                     -0.1 * 25 - 0.5 * 25,          # robot 4: bystander within 1.5 m
                                     -0.1 * 25])                    # robot 5: team share only
    assert primary == pytest.approx([8.75, 15.0, 2.5, -27.5, -15.0, -2.5])


def test_a_ball_teleport_after_an_out_is_not_progress():
    world = make_world(rewards=NO_APPROACH)
    world.state.chain[:] = [0]
    world.place_ball(1.0, 2.96, 0.0, 1.0)          # rolls over the sideline: moved 0.5 m toward team A's goal
    result = world.step([IDLE, IDLE])
    assert world.ball_xy[0] == pytest.approx(0.5)
    assert result.rewards[RewardTerm.AUXILIARY] == pytest.approx([0.0, 0.0])


def test_the_closest_robot_is_paid_for_approaching_the_ball():
    world = make_world(players_per_team=2)
    world.place_robot(0, -1.0, 0.0, 0.0)           # team A's closest, walks toward the ball
    world.place_robot(2, 2.0, 0.0, math.pi)        # team B's closest, walks away from it
    idle_steps(world, 1)
    result = world.step([SoccerAction(walk=Walk.FORWARD), IDLE, SoccerAction(walk=Walk.BACKWARD), IDLE])
    aux = result.rewards[RewardTerm.AUXILIARY]
    w = world.config.rewards
    assert aux[0] == pytest.approx(w.approach_per_m * world.config.motion.forward_step, rel=0.05)
    assert aux[2] == pytest.approx(-w.approach_per_m * world.config.motion.backward_step, rel=0.05)
    assert aux[1] == 0.0 and aux[3] == 0.0


def test_observation_reward_caps_each_part():
    w = RewardConfig()
    assert observation_reward([5, 1, 0], [4, 4, 4, 4, 4], 5, w) == pytest.approx(
        w.observation_robot * 3 + w.observation_landmark * 3 + w.observation_ball * 3)
    assert observation_reward([], [1, 2], 0, w) == pytest.approx(w.observation_landmark * 1.5)
    assert observation_reward([0, 0, 0], [0] * 5, 0, w) == 0.0


def _mirror_index(world, i):
    n = world.config.players_per_team
    return i + n if i < n else i - n


def _set_situation(world, poses, ball, mirrored):
    s = -1.0 if mirrored else 1.0
    for i, (x, y, yaw) in enumerate(poses):
        j = _mirror_index(world, i) if mirrored else i
        world.place_robot(j, s * x, s * y, yaw + (math.pi if mirrored else 0.0))
    bx, by, vx, vy = ball
    world.place_ball(s * bx, s * by, s * vx, s * vy)


def test_a_situation_mirrored_between_the_teams_gives_mirrored_observations_and_rewards():
    worlds = [make_world(players_per_team=2), make_world(players_per_team=2)]
    poses = [(-0.6, 0.3, 0.0), (-2.0, -1.0, 0.0), (1.5, 0.5, 3.0), (3.5, -0.2, math.pi)]
    ball = (-0.43, 0.35, 0.0, 0.0)     # in front of robot 0's left foot
    plan = [{0: SoccerAction(kick=Kick.LEFT_FOOT), 2: SoccerAction(turn=Turn.LEFT, head_yaw_delta=0.2)},
            {1: SoccerAction(walk=Walk.LEFT)},
            {3: SoccerAction(walk=Walk.FORWARD)}, {}, {2: SoccerAction(walk=Walk.FORWARD)}, {}, {}, {}]
    for mirrored, world in enumerate(worlds):
        _set_situation(world, poses, ball, bool(mirrored))
    encoder = GroundTruthEncoder(worlds[0].config)
    for step in plan:
        results = []
        for mirrored, world in enumerate(worlds):
            actions = [IDLE] * 4
            for i, action in step.items():
                actions[_mirror_index(world, i) if mirrored else i] = action
            results.append(world.step(actions))
        obs = [encoder.observations(w) for w in worlds]
        for i in range(4):
            j = _mirror_index(worlds[0], i)
            np.testing.assert_allclose(obs[0][i], obs[1][j], atol=1e-5)
            np.testing.assert_allclose(results[0].rewards[:, i], results[1].rewards[:, j], atol=1e-6)
    assert worlds[0].ball_xy[0] > 1.0     # the kick happened, so the check covered a moving ball
