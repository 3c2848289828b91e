"""Self-localization on ROS (docs/ros_graph.md, "Self-localization"): the simulator's pose estimates
(PoseWithCovarianceStamped) and REP 105 chain map → odom → base_link composing to the estimate while the ground truth
keeps frames of its own; the policy node turning estimates into its ``pose_estimate`` input, refusing malformed ones
and treating missing or stale ones as lost."""
from __future__ import annotations

import math
from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from dynenv_msgs.msg import Action, DetectionArray, WorldState
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from tf2_msgs.msg import TFMessage

from dynenv_ros.envs.pose_features import POSE_BOUND, POSE_KEY, pose_features
from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.ros import topics
from dynenv_ros.ros.pose_estimates import (LOST_ROW, EmulatedOdometry, PoseHistory, compose, inverse, message_pose,
                                           pose_batch, pose_message, pose_problem, stamp_ns)
from dynenv_ros.ros.qos import sim_stream
from dynenv_ros.ros.tf import robot_transforms, tf_qos
from policy_node.batch_policy import uses_pose
from policy_node.policy_node import PolicyNode
from ros_harness import spin_until

ROBOTS = ["team_a_0", "team_b_0"]


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def _pose(transform) -> tuple[float, float, float]:
    t, q = transform.transform.translation, transform.transform.rotation
    return t.x, t.y, 2.0 * math.atan2(q.z, q.w)


def _estimate(x, y, yaw, variances=(0.04, 0.09, 0.01), sec=10, nanosec=0, frame="map"):
    return pose_message((x, y, yaw), variances, Time(sec=sec, nanosec=nanosec), frame)


# -- the message and the frames ---------------------------------------------------------------------------------------
def test_the_message_puts_the_variances_in_rep_slots_and_marks_unused_dimensions():
    msg = _estimate(1.0, -2.0, 2.5, sec=3, nanosec=5)
    assert msg.header.frame_id == "map" and (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 5)
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z) == (1.0, -2.0, 0.0)
    q = msg.pose.pose.orientation
    assert (q.x, q.y) == (0.0, 0.0) and 2.0 * math.atan2(q.z, q.w) == pytest.approx(2.5)
    expected = np.zeros(36)
    expected[[0, 7, 35]] = 0.04, 0.09, 0.01              # x, y, yaw: row-major (x, y, z, roll, pitch, yaw)
    expected[[14, 21, 28]] = 1e6                          # z, roll, pitch: not estimated
    assert np.array_equal(np.asarray(msg.pose.covariance), expected)
    assert pose_problem(msg) == ""
    pose, variances = message_pose(msg)
    assert pose == pytest.approx((1.0, -2.0, 2.5)) and variances == pytest.approx((0.04, 0.09, 0.01))


def test_map_to_base_link_through_odom_is_the_estimate_and_the_truth_has_its_own_frame():
    rng = np.random.default_rng(0)
    names = ["team_a_0", "team_b_0", "team_a_1"]
    truth = [tuple(v) for v in rng.uniform(-3, 3, (3, 4))]
    estimates = rng.uniform(-3, 3, (3, 3)).tolist()
    odometry = rng.uniform(-3, 3, (3, 3)).tolist()
    frames = {(t.header.frame_id, t.child_frame_id): t
              for t in robot_transforms(names, truth, Time(sec=1), estimates, odometry).transforms}
    assert len(frames) == 4 * len(names)
    for i, name in enumerate(names):
        chain = compose(_pose(frames[("map", f"{name}/odom")]), _pose(frames[(f"{name}/odom", f"{name}/base_link")]))
        assert chain[:2] == pytest.approx(estimates[i][:2], abs=1e-9)
        assert math.remainder(chain[2] - estimates[i][2], 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        assert _pose(frames[(f"{name}/odom", f"{name}/base_link")]) == pytest.approx(odometry[i], abs=1e-12)
        x, y, yaw = _pose(frames[("map", f"{name}/ground_truth/base_link")])
        assert (x, y) == pytest.approx(truth[i][:2]) and math.remainder(yaw - truth[i][2], 2 * math.pi) == \
            pytest.approx(0.0, abs=1e-12)
        assert _pose(frames[(f"{name}/base_link", f"{name}/camera")])[2] == pytest.approx(truth[i][3])


def test_odometry_integrates_the_walk_and_skips_a_robot_carried_elsewhere():
    odometry = EmulatedOdometry(0.1)
    start = (1.0, 2.0, 0.5)
    odometry.reset([start])
    poses = [start]
    for _k in range(1, 30):                         # walk a curve: 2 cm and 0.03 rad per frame
        poses.append(compose(poses[-1], (0.02, 0.0, 0.03)))
        odometry.step([poses[-1]])
    assert odometry.pose[0] == pytest.approx(compose(inverse(start), poses[-1]), abs=1e-12)
    before = odometry.pose[0]
    odometry.step([(-4.0, 3.0, -1.5)])              # placed on the touchline: not odometry
    assert odometry.pose[0] == before and odometry.carried == 1
    odometry.step([compose((-4.0, 3.0, -1.5), (0.02, 0.0, 0.0))])
    assert odometry.pose[0] == pytest.approx(compose(before, (0.02, 0.0, 0.0)), abs=1e-12)


# -- the simulator node -----------------------------------------------------------------------------------------------
class Probe:
    def __init__(self, make_node, executor):
        self.node = make_node("localization_probe")
        self.poses = {r: [] for r in ROBOTS}
        self.detections = {r: [] for r in ROBOTS}
        self.truth: list[WorldState] = []
        self.tf: list[TFMessage] = []
        self.pose_subs = {}
        for r in ROBOTS:
            self.pose_subs[r] = self.node.create_subscription(PoseWithCovarianceStamped, topics.pose_estimate(r),
                                                              self.poses[r].append, sim_stream())
            self.node.create_subscription(DetectionArray, topics.detections(r), self.detections[r].append,
                                          sim_stream())
        self.node.create_subscription(WorldState, topics.WORLD_STATE, self.truth.append, sim_stream())
        self.node.create_subscription(TFMessage, "/tf", self.tf.append, tf_qos())
        self.actions = {r: self.node.create_publisher(Action, topics.action(r), sim_stream()) for r in ROBOTS}
        executor.add_node(self.node)


def test_the_simulator_publishes_estimates_and_a_tf_chain_that_composes_to_them(make_node, executor):
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=5, falls_enabled=False,
                                                         publish_markers=False))
    executor.add_node(sim)
    probe = Probe(make_node, executor)
    assert spin_until(executor, lambda: len(probe.detections["team_a_0"]) == 5, 20.0)
    assert spin_until(executor, lambda: all(sim.count_publishers(topics.action(r)) >= 1 for r in ROBOTS), 10.0)
    periods = 6
    for period in range(1, periods + 1):             # walk and turn, so odometry and estimate move
        for i, r in enumerate(ROBOTS):
            probe.actions[r].publish(Action(robot_id=i, episode_id=1, motion_period=period, walk=Action.WALK_FORWARD,
                                            turn=Action.TURN_LEFT if i else Action.TURN_RIGHT))
        assert spin_until(executor, lambda: all(len(p) == 5 * (period + 1) for p in probe.poses.values())
                          and len(probe.tf) == 1 + 5 * period and len(probe.truth) == 5 * (period + 1), 20.0)
    trees = {stamp_ns(m.transforms[0].header.stamp): {(t.header.frame_id, t.child_frame_id): t for t in m.transforms}
             for m in probe.tf}
    truth = {stamp_ns(w.header.stamp): w for w in probe.truth}        # period 0's instant: its last frame
    errors = []
    for i, robot in enumerate(ROBOTS):
        latest = {stamp_ns(m.header.stamp): m for m in probe.poses[robot]}   # the last estimate of each instant
        assert set(latest) == set(trees) and len(trees) == 1 + 5 * periods      # one tree per instant
        for stamp, msg in latest.items():
            assert msg.header.frame_id == "map" and pose_problem(msg) == ""
            cov = np.asarray(msg.pose.covariance)
            assert (cov[[0, 7, 35]] > 0).all() and (cov[[14, 21, 28]] == 1e6).all()
            frames = trees[stamp]
            chain = compose(_pose(frames[("map", f"{robot}/odom")]),
                            _pose(frames[(f"{robot}/odom", f"{robot}/base_link")]))
            estimate, _ = message_pose(msg)
            assert chain[:2] == pytest.approx(estimate[:2], abs=1e-6)
            assert math.remainder(chain[2] - estimate[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-6)
            me = next(o for o in truth[stamp].objects if o.id == i)
            gx, gy, gyaw = _pose(frames[("map", f"{robot}/ground_truth/base_link")])
            assert (gx, gy) == pytest.approx((me.x, me.y), abs=1e-9)
            assert math.remainder(gyaw - me.yaw, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
            errors.append(math.hypot(estimate[0] - me.x, estimate[1] - me.y))
    assert max(errors) > 1e-4                           # the estimate is not the truth (realistic localization)
    assert max(errors) < 1.0
    # every frame's estimate was published, with the detections' count (what the recorder must hold)
    assert all(len(probe.poses[r]) == len(probe.detections[r]) for r in ROBOTS)
    assert sim.diagnostics()["periods_run"] == str(periods)


def test_without_localization_base_link_is_the_truth_and_no_estimate_is_published(make_node, executor):
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=5, localization=False,
                                                         mode="realtime", real_time_factor=10.0,
                                                         publish_markers=False))
    listener = make_node("tf_listener")
    tf: list[TFMessage] = []
    listener.create_subscription(TFMessage, "/tf", tf.append, tf_qos())
    for node in (sim, listener):
        executor.add_node(node)
    assert spin_until(executor, lambda: tf, 20.0)
    assert {t.child_frame_id: t.header.frame_id for t in tf[-1].transforms} == {
        "team_a_0/base_link": "map", "team_a_0/camera": "team_a_0/base_link",
        "team_b_0/base_link": "map", "team_b_0/camera": "team_b_0/base_link"}
    assert sim.count_publishers(topics.pose_estimate("team_a_0")) == 0


def test_localization_is_a_robocup_parameter(make_node):
    with pytest.raises(ParameterException, match="localization"):
        make_node(SimNode, parameter_overrides=_params(scenario="driving", localization=True))


# -- the policy node --------------------------------------------------------------------------------------------------
def test_estimates_become_the_documented_features_in_each_robots_team_frame():
    histories = [PoseHistory(), PoseHistory()]
    for history in histories:                          # the same field-frame estimate for a robot of each team
        history.add(_estimate(1.0, -2.0, math.pi / 2, variances=(0.04, 0.09, 0.01), sec=10))
    counts: Counter[str] = Counter()
    rows = pose_batch(histories, [10 * 10**9] * 2, [1, -1], 500_000_000, counts)
    assert rows.dtype == np.float32 and rows.shape == (2, 7)
    # x, y, cos yaw, sin yaw, std x, std y, std yaw; team B's frame is the field turned by π
    assert rows[0] == pytest.approx([1.0, -2.0, 0.0, 1.0, 0.2, 0.3, 0.1], abs=1e-6)
    assert rows[1] == pytest.approx([-1.0, 2.0, 0.0, -1.0, 0.2, 0.3, 0.1], abs=1e-6)
    assert counts == {"pose_used": 2}


def test_the_newest_estimate_at_or_before_the_frame_is_taken_and_old_or_none_is_lost():
    history = PoseHistory()
    history.add(_estimate(1.0, 0.0, 0.0, sec=10))
    history.add(_estimate(2.0, 0.0, 0.0, sec=10, nanosec=400_000_000))
    history.add(_estimate(3.0, 0.0, 0.0, sec=11))       # after the frame: not yet
    counts: Counter[str] = Counter()
    rows = pose_batch([history, PoseHistory()], [10_500_000_000] * 2, [1, 1], 500_000_000, counts)
    assert rows[0][0] == pytest.approx(2.0)
    assert rows[1] == pytest.approx(LOST_ROW) and list(LOST_ROW) == [0, 0, 0, 0, POSE_BOUND, POSE_BOUND, POSE_BOUND]
    assert counts == {"pose_used": 1, "pose_missing": 1}
    rows = pose_batch([history], [10_950_000_000], [1], 500_000_000, counts)   # 0.55 s after the newest usable
    assert rows[0] == pytest.approx(LOST_ROW) and counts["pose_stale"] == 1
    history.add(_estimate(9.0, 0.0, 0.0, sec=1))        # the clock went back (a restarted simulator): start again
    assert history.restarts == 1 and len(history.entries) == 1


def _policy(make_node, **params):
    return make_node(PolicyNode, parameter_overrides=_params(players_per_team=1, seed=1, **params))


def test_the_policy_node_refuses_malformed_estimates_and_counts_them(make_node):
    node = _policy(make_node)
    assert not node.pose_wanted and not node.pose_subs            # an older policy: no pose input, no subscription
    nan = _estimate(float("nan"), 0.0, 0.0)
    odom = _estimate(0.0, 0.0, 0.0, frame="team_a_0/odom")
    negative = _estimate(0.0, 0.0, 0.0, variances=(0.01, -0.01, 0.01))
    no_rotation = _estimate(0.0, 0.0, 0.0)
    no_rotation.pose.pose.orientation.w = 0.0
    infinite = _estimate(0.0, 0.0, 0.0)
    infinite.pose.covariance[35] = float("inf")
    reasons = [pose_problem(m) for m in (nan, odom, negative, no_rotation, infinite)]
    assert reasons == ["non-finite pose", "frame_id 'team_a_0/odom', expected 'map'",
                       "negative variance (x, y, yaw: 0.01, -0.01, 0.01)",
                       "orientation is not a unit quaternion (|q| = 0)", "non-finite covariance in x, y or yaw"]
    for msg in (nan, odom, negative, no_rotation, infinite):
        assert not node.store_pose("team_a_0", msg)
    unused = _estimate(0.5, 0.0, 0.0)
    unused.pose.covariance[14] = -1.0                  # an unused dimension: whatever a stack puts there
    assert node.store_pose("team_a_0", unused)
    assert node.counts["pose_malformed"] == 5 and len(node.pose_histories["team_a_0"].entries) == 1
    values = node.diagnostics()
    assert values["pose_malformed"] == "5" and values["pose_refusal"].startswith("team_a_0: non-finite covariance")


def test_uses_pose_reads_the_model_attribute_or_the_onnx_inputs():
    assert not uses_pose(SimpleNamespace(model=SimpleNamespace()))               # an older checkpoint
    assert uses_pose(SimpleNamespace(model=SimpleNamespace(uses_pose=True)))
    assert not uses_pose(SimpleNamespace(uses_pose=False, model=SimpleNamespace(uses_pose=True)))  # the policy's own
    inputs = [SimpleNamespace(name="landmark_features"), SimpleNamespace(name=POSE_KEY)]
    assert uses_pose(SimpleNamespace(session=SimpleNamespace(get_inputs=lambda: inputs)))
    assert not uses_pose(SimpleNamespace(session=SimpleNamespace(get_inputs=lambda: inputs[:1])))


def test_a_policy_taking_the_pose_gets_the_simulators_estimate_of_each_periods_last_frame(make_node, executor):
    """A policy marked ``uses_pose`` makes the node subscribe and put the rows into the padded batch; the rows are
    checked against the estimates the simulator published. (The network that reads them is another change: this
    untrained one, only marked, cannot take them, and its robots get the fallback action.)"""
    probe = Probe(make_node, executor)              # the sim waits for it and the policy node (2 readers)
    sim = make_node(SimNode, parameter_overrides=_params(players_per_team=1, seed=3, falls_enabled=False,
                                                         publish_markers=False, wait_for_subscribers=2))
    policy = _policy(make_node)
    policy.policy.uses_pose = True                      # (its decisions fail and fall back: no pose layers)
    policy._subscribe_poses()
    assert policy.pose_wanted and set(policy.pose_subs) == set(ROBOTS)
    batches = []
    padded = policy.batch.padded

    def record(memories, periods):
        observation = padded(memories, periods)
        batches.append(([stamp_ns(p[-1].header.stamp) for p in periods], observation[POSE_KEY].copy()))
        return observation

    policy.batch.padded = record
    # The simulator waits for detection readers only (a policy may not read poses): the first estimates must not go
    # out before the probe's and the policy's pose readers have matched the writers, both ways.
    assert spin_until(executor, lambda: all(p.get_subscription_count() >= 2 for p in sim.outlet.pose_pubs)
                      and all(s.get_publisher_count() >= 1 for s in probe.pose_subs.values())
                      and all(s.get_publisher_count() >= 1 for s in policy.pose_subs.values()), 10.0)
    for node in (sim, policy):
        executor.add_node(node)
    assert spin_until(executor, lambda: sim.periods_run >= 4, 30.0), sim.session.counts
    executor.remove_node(policy)                        # the game stops; the probe catches up
    # (a decision already scheduled still runs after the removal: the newest stamp is read at every look)
    assert spin_until(executor, lambda: all(p and stamp_ns(p[-1].header.stamp) >= max(max(s) for s, _ in batches)
                                            for p in probe.poses.values()), 10.0)
    assert policy.counts["pose_used"] == 2 * len(batches) and not policy.counts["pose_malformed"]
    for stamps, rows in batches:
        for b, (robot, team) in enumerate(zip(ROBOTS, (1, -1))):
            # the newest estimate at or before the last frame the robot's period had (BatchPolicy.pose_rows; the
            # period's own last frame's unless the period was left short of it), waited for when it was still on
            # its way (a loaded machine can deliver the frame first)
            msg = [m for m in probe.poses[robot] if stamp_ns(m.header.stamp) <= stamps[b]][-1]
            estimate, variances = message_pose(msg)
            expected = pose_features(estimate[None], np.diag(variances)[None], np.array([team]))[0]
            assert rows[b] == pytest.approx(expected, abs=1e-6)
