"""Soccer reward terms: how goals and ball progress are shared, approach shaping, and the observation term.

DynEnv computes these per tick; here the ball's path is split at every touch, out and goal, which gives the
same sums without Python work on every tick, and never counts a ball teleport as progress (docs/original.md §12.9).
"""
from __future__ import annotations

import math
from typing import Sequence

from dynenv_ros.sim.reward_terms import RewardLedger, RewardTerm
from dynenv_ros.soccer.config import RewardConfig
from dynenv_ros.soccer.robot import Robot


def share_ball_value(ledger: RewardLedger, term: RewardTerm, value_team_a: float, robots: Sequence[Robot],
                     chain: Sequence[int], ball_xy: tuple[float, float], weights: RewardConfig) -> None:
    """Share a ball event worth ``value_team_a`` to team A (and its negative to team B).

    Every robot in play gets ``team_share`` of its team's value; the i-th most recent toucher gets ``chain_decay**i`` of
    it; robots outside the chain that are their team's closest to the ball or within ``bystander_radius`` share
    only losses (``bystander_share`` of a negative value), as in DynEnv.
    """
    if value_team_a == 0.0:
        return
    for robot in robots:
        if not robot.rules.absent:         # out of play for the episode: no share of anything
            ledger.add(term, robot.index, weights.team_share * value_team_a * robot.team)
    in_chain = set()
    for i, index in enumerate(chain):
        robot = robots[index]
        ledger.add(term, index, value_team_a * robot.team * weights.chain_decay ** i)
        in_chain.add(index)
    bx, by = ball_xy
    closest = closest_to_ball(robots, ball_xy)
    for robot in robots:
        value = value_team_a * robot.team
        if value >= 0.0 or robot.index in in_chain or robot.rules.penalized:
            continue
        near = math.hypot(robot.x - bx, robot.y - by) < weights.bystander_radius
        if near or closest.get(robot.team) == robot.index:
            ledger.add(term, robot.index, weights.bystander_share * value)


def closest_to_ball(robots: Sequence[Robot], ball_xy: tuple[float, float]) -> dict[int, int]:
    """Team → index of its robot nearest the ball, penalized robots excluded."""
    best: dict[int, tuple[float, int]] = {}
    bx, by = ball_xy
    for robot in robots:
        if robot.rules.penalized:
            continue
        d = (robot.x - bx) ** 2 + (robot.y - by) ** 2
        if robot.team not in best or d < best[robot.team][0]:
            best[robot.team] = (d, robot.index)
    return {team: index for team, (_, index) in best.items()}


def observation_reward(frames_seen_per_robot: Sequence[int], landmarks_per_frame: Sequence[int],
                       ball_frames_seen: int, weights: RewardConfig) -> float:
    """DynEnv's reward for looking around, over one motion period's frames.

    ``frames_seen_per_robot``: for each other robot, in how many frames it was seen; ``landmarks_per_frame``:
    landmarks seen in each frame; ``ball_frames_seen``: frames in which the real ball was seen (false positives
    excluded).
    """
    robots = sum(min(weights.observation_robot_cap, n) for n in frames_seen_per_robot)
    landmarks = min(float(weights.observation_landmark_cap),
                    sum(landmarks_per_frame) / len(landmarks_per_frame)) if landmarks_per_frame else 0.0
    ball = min(weights.observation_ball_cap, ball_frames_seen)
    return (weights.observation_robot * robots + weights.observation_landmark * landmarks
            + weights.observation_ball * ball)
