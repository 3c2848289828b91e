"""The perceiving scripted team as a ROS node (policy_node/perceiving_policy.py): it acts on its robot's detections
and pose estimate only (never /world_state), exactly as ``PerceivingPolicy.act`` on the same padded observation and
pose; it waits for the period's last frame and the estimate of that instant whatever order they come in, so stepped
games are deterministic; malformed frames and estimates are counted, never a crash."""
from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from dynenv_msgs.msg import Action, Detection, DetectionArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter

from dynenv_ros.envs.padded_layout import GAME_COLUMNS, PROPRIOCEPTION_COLUMNS
from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.perception.detections import FEATURE_COLUMNS
from dynenv_ros.ros import topics
from dynenv_ros.ros.pose_estimates import pose_message
from dynenv_ros.ros.qos import sim_stream
from dynenv_ros.soccer.perceiving import perceiving_team
from policy_node.perceiving_policy import STAND_STILL, PerceivingPolicyNode
from ros_harness import spin_until

FRAMES = 5
ROBOT, ROBOT_ID = "team_b_1", 3           # 2v2: team B's slot 1, a chaser
HEAD = 0.2


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _ball(x: float, y: float) -> Detection:
    d = Detection(class_id=Detection.CLASS_BALL, yaw=float("nan"), size_x=0.1, size_y=0.1, confidence=0.9)
    d.position.x, d.position.y = x, y
    return d


def _stamp(period: int, frame: int) -> Time:
    """Period p's frames at p·0.5 s + frame·0.1 s; period 0's all at 0 (the reset state, as the simulator)."""
    ns = 0 if period == 0 else 500_000_000 * period + 100_000_000 * frame
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _period(period: int, ball_frame: int | None = 3, ball=(1.2, 0.3), robot_id: int = ROBOT_ID, episode: int = 1,
            frames: int = FRAMES) -> list[DetectionArray]:
    out = []
    for k in range(frames):
        msg = DetectionArray(robot_id=robot_id, episode_id=episode, motion_period=period, frame_index=k,
                             frames_per_period=frames, head_yaw=HEAD, ball_owner=1, ball_owner_seconds=2.0,
                             game_seconds_remaining=300.0,
                             detections=[_ball(*ball)] if k == ball_frame else [])
        msg.header.stamp = _stamp(period, k)
        out.append(msg)
    return out


def _estimate(pose, stamp: Time, frame: str = "map") -> PoseWithCovarianceStamped:
    return pose_message(pose, (0.01, 0.01, 0.005), stamp, frame)


def _observation(ball_frame: int | None = 3, ball=(1.2, 0.3)) -> dict[str, np.ndarray]:
    """The padded observation of ``_period``, written out by hand from the layout's columns."""
    objects = np.zeros((FRAMES, 1, len(FEATURE_COLUMNS)), np.float32)
    mask = np.zeros((FRAMES, 1), np.float32)
    if ball_frame is not None:
        row = dict(class_id=1, x=ball[0], y=ball[1], size_x=0.1, size_y=0.1, confidence=0.9)
        for column, value in row.items():
            objects[ball_frame, 0, FEATURE_COLUMNS.index(column)] = value
        mask[ball_frame, 0] = 1.0
    proprioception = np.zeros((FRAMES, len(PROPRIOCEPTION_COLUMNS)), np.float32)
    proprioception[:, PROPRIOCEPTION_COLUMNS.index("head_yaw")] = HEAD
    game = np.zeros(len(GAME_COLUMNS), np.float32)
    game[[GAME_COLUMNS.index(c) for c in ("ball_owner", "ball_owner_seconds", "game_seconds_remaining")]] = \
        (1, 2.0, 300.0)
    return {"objects": objects, "object_mask": mask, "proprioception": proprioception, "game": game}


def _as_tuple(action) -> tuple:
    return (int(action.walk), int(action.turn), int(action.kick), round(float(action.head_yaw_delta), 6))


class Captured:
    """A node whose published actions are kept in a list instead of going out (callbacks called directly)."""

    def __init__(self, make_node, **params):
        values = {"robot": ROBOT, **params}
        self.node = make_node(PerceivingPolicyNode, parameter_overrides=_params(**values))
        self.sent: list[Action] = []
        self.node.action_pub.publish = self.sent.append

    def frames(self, messages) -> None:
        for msg in messages:
            self.node._on_detections(msg)

    def pose(self, msg) -> None:
        self.node._on_pose(msg)


# -- over ROS: detections and pose in, the action out ------------------------------------------------------------------
def test_the_node_acts_on_detections_and_pose_as_the_perceiving_policy_does(make_node, executor):
    node = make_node(PerceivingPolicyNode, parameter_overrides=_params(robot=ROBOT))
    feeder = make_node("feeder")
    detections = feeder.create_publisher(DetectionArray, topics.detections(ROBOT), sim_stream())
    poses = feeder.create_publisher(PoseWithCovarianceStamped, topics.pose_estimate(ROBOT), sim_stream())
    received: list[Action] = []
    feeder.create_subscription(Action, topics.action(ROBOT), received.append, sim_stream())
    for n in (node, feeder):
        executor.add_node(n)
    assert spin_until(executor, lambda: detections.get_subscription_count() == 1
                      and poses.get_subscription_count() == 1 and feeder.count_publishers(topics.action(ROBOT)), 10.0)
    # what it reads: its robot's detections and estimate, nothing else (no ground truth)
    assert {s.topic_name for s in node.subscriptions} == {f"/{ROBOT}/detections", f"/{ROBOT}/pose_estimate"}
    assert feeder.count_subscribers(topics.WORLD_STATE) == 0
    reference = perceiving_team(2, 0.5)[ROBOT_ID]
    # period 1 shows the ball in frame 3; period 2 none (the policy's memory keeps it, the robot has turned away);
    # period 3 shows it again at its feet (team B attacks toward -x)
    plays = ((1, 3, (1.2, 0.3), (-1.0, 0.5, 2.8)), (2, None, (0.0, 0.0), (-1.0, 0.5, -2.0)),
             (3, 0, (0.15, -0.02), (-1.5, 0.4, 3.1)))
    for period, ball_frame, ball, pose in plays:
        frames = _period(period, ball_frame, ball)
        for msg in frames:
            detections.publish(msg)
        assert not spin_until(executor, lambda: len(received) == period, 0.3)     # no estimate yet: no action
        poses.publish(_estimate(pose, frames[-1].header.stamp))
        assert spin_until(executor, lambda: len(received) == period, 10.0)
        action = received[-1]
        expected = reference.act(_observation(ball_frame, ball), pose)
        assert _as_tuple(action) == _as_tuple(expected), period
        assert action.motion_period == period + 1 and action.robot_id == ROBOT_ID and action.episode_id == 1
        assert action.header.stamp == frames[-1].header.stamp and action.header.frame_id == f"{ROBOT}/base_link"
    assert reference.ball is not None            # the ball was believed throughout: no search action compared
    assert len({_as_tuple(a) for a in received}) == 3
    assert node.counts["pose_used"] == 3 and node.actions_sent == 3


def test_the_role_follows_keeper_and_chasers_and_a_robot_outside_the_game_is_refused(make_node):
    roles = {robot: make_node(PerceivingPolicyNode, parameter_overrides=_params(robot=robot, players_per_team=n)).role
             for robot, n in (("team_a_0", 2), ("team_a_1", 2), ("team_b_0", 3), ("team_b_0", 1))}
    assert roles == {"team_a_0": "GoalkeeperPolicy", "team_a_1": "ChaserPolicy", "team_b_0": "ChaserPolicy"}
    assert make_node(PerceivingPolicyNode, parameter_overrides=_params(robot="team_b_0", players_per_team=3)
                     ).role == "GoalkeeperPolicy"
    with pytest.raises(ParameterException, match="robot must be one of"):
        make_node(PerceivingPolicyNode, parameter_overrides=_params(robot="team_a_2", players_per_team=2))


# -- order and determinism ---------------------------------------------------------------------------------------------
def test_the_decision_does_not_depend_on_which_topic_arrives_first(make_node):
    pose = (0.5, -0.3, 3.0)
    frames = _period(1)
    first, second = Captured(make_node), Captured(make_node)
    first.frames(frames)
    assert not first.sent                                        # waiting for the estimate of the last frame
    first.pose(_estimate((9.0, 9.0, 0.0), frames[2].header.stamp))   # an earlier instant's: still waiting
    assert not first.sent
    first.pose(_estimate(pose, frames[-1].header.stamp))
    second.pose(_estimate((9.0, 9.0, 0.0), frames[2].header.stamp))
    second.pose(_estimate(pose, frames[-1].header.stamp))
    second.frames(frames[:-1])
    assert not second.sent                                       # the period is not complete yet
    second.frames(frames[-1:])
    assert len(first.sent) == len(second.sent) == 1
    assert _as_tuple(first.sent[0]) == _as_tuple(second.sent[0])
    assert _as_tuple(first.sent[0]) == _as_tuple(perceiving_team(2, 0.5)[ROBOT_ID].act(_observation(), pose))


def test_period_zero_waits_for_the_estimate_of_its_last_frame(make_node):
    """Period 0's frames share one stamp, and so do their five estimates: the last one is the period's end."""
    robot = Captured(make_node)
    frames = _period(0)
    robot.frames(frames)
    for k in range(FRAMES - 1):
        robot.pose(_estimate((9.0, 9.0, 0.0), frames[k].header.stamp))
    assert not robot.sent
    pose = (-2.0, 1.0, math.pi)
    robot.pose(_estimate(pose, frames[-1].header.stamp))
    assert len(robot.sent) == 1 and robot.sent[0].motion_period == 1
    assert _as_tuple(robot.sent[0]) == _as_tuple(perceiving_team(2, 0.5)[ROBOT_ID].act(_observation(), pose))


def _stepped_game(make_node, executor, seed: int, periods: int, namespace: str) -> tuple[list, list]:
    """A 1v1 stepped game (in its own namespace) of two perceiving nodes: their actions and the final truth."""
    sim = make_node(SimNode, namespace=namespace, parameter_overrides=_params(
        players_per_team=1, seed=seed, publish_markers=False, wait_for_subscribers=1))
    robots = [make_node(PerceivingPolicyNode, namespace=namespace,
                        parameter_overrides=_params(robot=r, players_per_team=1)) for r in ("team_a_0", "team_b_0")]
    for n in (sim, *robots):
        executor.add_node(n)
    assert spin_until(executor, lambda: sim.periods_run >= periods, 60.0), sim.session.counts
    assert sim.outlet.world_pub.get_subscription_count() == 0             # nobody reads the ground truth
    assert sim.session.counts["missing"] == 0
    actions = [[(a.walk, a.turn, a.kick, a.head_yaw_delta) for a in r.sent_log[:periods]] for r in robots]
    truth = [(o.id, round(o.x, 9), round(o.y, 9), round(o.yaw, 9)) for o in sim.session.world.snapshot().objects]
    for r in robots:
        assert r.counts["pose_used"] >= periods and not r.counts["pose_missing"] and not r.counts["frames_stale"]
    for n in (sim, *robots):
        executor.remove_node(n)
    return actions, truth


def test_a_stepped_game_of_perceiving_robots_is_deterministic(make_node, executor, monkeypatch):
    original = PerceivingPolicyNode._publish

    def logged(self, frames, pose):            # keep what each node sent, in order
        original(self, frames, pose)
        self.__dict__.setdefault("sent_log", []).append(self.previous)
    monkeypatch.setattr(PerceivingPolicyNode, "_publish", logged)
    first = _stepped_game(make_node, executor, 4, 12, "/first")
    second = _stepped_game(make_node, executor, 4, 12, "/second")
    assert first == second
    moves = {a[:3] for robot in first[0] for a in robot}
    assert len(moves) > 1                          # they played, not stood still


# -- malformed input ---------------------------------------------------------------------------------------------------
def test_malformed_frames_and_estimates_are_counted_and_the_node_plays_on(make_node):
    robot = Captured(make_node)
    node = robot.node
    frames = _period(1)
    bad = _period(1)
    bad[0].frame_index = 7                                                   # beyond frames_per_period
    other = _period(1, robot_id=0)                                           # another robot's frames
    odd = _period(1)
    odd[1].frames_per_period = 4                                             # disagrees with the period's others
    robot.frames([bad[0], other[0], frames[0], odd[1]])
    assert node.counts["frames_malformed"] == 3 and "frames_per_period 4" in node.refusal
    nan = _ball(float("nan"), 0.0)
    frames[1].detections = [nan]                                             # a NaN detection: left out
    frames[2].head_yaw = float("inf")                                        # read as 0
    robot.frames(frames[1:])
    stamp = frames[-1].header.stamp
    wrong_frame = _estimate((0.0, 0.0, 0.0), stamp, "odom")
    not_finite = _estimate((float("nan"), 0.0, 0.0), stamp)
    not_unit = _estimate((0.0, 0.0, 0.0), stamp)
    not_unit.pose.pose.orientation.w = 2.0
    negative = _estimate((0.0, 0.0, 0.0), stamp)
    negative.pose.covariance[0] = -1.0
    for msg in (wrong_frame, not_finite, not_unit, negative):
        robot.pose(msg)
    assert node.counts["pose_malformed"] == 4 and not robot.sent and "negative variance" in node.refusal
    robot.pose(_estimate((1.0, 0.0, 0.0), stamp))
    assert len(robot.sent) == 1
    assert node.counts["detections_malformed"] == 1 and node.counts["values_malformed"] == 1
    robot.frames(_period(1))                                                 # the period already acted on
    assert node.counts["frames_stale"] == FRAMES and len(robot.sent) == 1


def test_a_robot_without_a_recent_estimate_or_whose_decision_fails_stands_still(make_node):
    robot = Captured(make_node)
    node = robot.node
    robot.frames(_period(1))
    robot.pose(_estimate((1.0, 0.0, 0.0), _stamp(5, 0)))     # only a later instant's estimate: lost
    assert len(robot.sent) == 1 and _as_tuple(robot.sent[0]) == _as_tuple(STAND_STILL)
    assert node.counts["pose_missing"] == 1
    robot.frames(_period(6))
    robot.pose(_estimate((1.0, 0.0, 0.0), _stamp(9, 0)))     # the newest before the frame is 0.9 s older
    assert len(robot.sent) == 2 and node.counts["pose_stale"] == 1
    robot.frames(_period(9))
    robot.pose(_estimate((1.0, 0.0, 0.0), _stamp(9, 3)))     # 0.1 s before the frame, then a later one: used
    robot.pose(_estimate((1.0, 0.0, 0.0), _stamp(10, 0)))
    assert len(robot.sent) == 3 and node.counts["pose_used"] == 1

    def broken(observation, pose):
        raise RuntimeError("boom")
    node.policy.act = broken
    robot.frames(_period(11))
    robot.pose(_estimate((1.0, 0.0, 0.0), _period(11)[-1].header.stamp))
    assert len(robot.sent) == 4 and _as_tuple(robot.sent[-1]) == _as_tuple(STAND_STILL)
    assert node.counts["failed_decisions"] == 1
    node.policy.act = type(node.policy).act.__get__(node.policy)
    robot.frames(_period(1, episode=2))                         # a new episode (a restarted clock) starts afresh
    robot.pose(_estimate((1.0, 0.0, 0.0), _period(1)[-1].header.stamp))
    assert len(robot.sent) == 5 and robot.sent[-1].episode_id == 2 and robot.sent[-1].motion_period == 2
