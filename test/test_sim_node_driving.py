"""The simulator node with ``scenario: driving`` in one process with a test node: per-car detections, ground truth
and feedback, the driving fields of Action (discrete and continuous) accepted or refused with reasons, stepped
mode, reset with a seed, the preset and bad parameters. No launch files (test/ros_harness.py)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from dynenv_msgs.msg import Action, DetectionArray, StepFeedback, WorldState
from dynenv_msgs.srv import ResetSimulation, StepSimulation
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.ros import topics
from dynenv_ros.ros.qos import sim_stream
from dynenv_ros.ros.tf import tf_qos
from ros_harness import spin_until

CARS = ["car_0", "car_1"]
REPO = Path(__file__).resolve().parents[1]
W = 0.3490658503988659          # the default steering limit, rad/s (2° per 100 ms)


def _sim(make_node, **params):
    defaults = {"scenario": "driving", "n_cars": 2, "seed": 5, "perception_preset": "realistic"}
    defaults.update(params)
    return make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in defaults.items()])


class Probe:
    def __init__(self, make_node, executor):
        self.node = make_node("probe")
        self.detections = {c: [] for c in CARS}
        self.feedback = {c: [] for c in CARS}
        self.truth: list[WorldState] = []
        self.tf: list[TFMessage] = []
        self.markers: list[MarkerArray] = []
        qos = sim_stream()
        for c in CARS:
            self.node.create_subscription(DetectionArray, topics.detections(c), self.detections[c].append, qos)
            self.node.create_subscription(StepFeedback, topics.feedback(c), self.feedback[c].append, qos)
        self.node.create_subscription(WorldState, topics.WORLD_STATE, self.truth.append, qos)
        self.node.create_subscription(TFMessage, "/tf", self.tf.append, tf_qos())
        self.node.create_subscription(MarkerArray, topics.GROUND_TRUTH_MARKERS, self.markers.append, 5)
        self.actions = {c: self.node.create_publisher(Action, topics.action(c), qos) for c in CARS}
        self.executor = executor
        executor.add_node(self.node)

    def act(self, car: int, period: int, throttle=0.0, brake=0.0, steering=0.0, episode: int = 1,
            robot_id: int | None = None) -> None:
        self.actions[CARS[car]].publish(Action(robot_id=car if robot_id is None else robot_id, episode_id=episode,
                                               motion_period=period, throttle=throttle, brake=brake,
                                               steering=steering))

    def spin(self, condition, timeout=10.0) -> bool:
        return spin_until(self.executor, condition, timeout)

    def periods_received(self, periods: int) -> bool:
        return (len(self.truth) == periods and all(len(f) == periods for f in self.feedback.values())
                and all(len(d) == periods for d in self.detections.values()))


def _start(make_node, executor, **params):
    sim = _sim(make_node, **params)
    executor.add_node(sim)
    probe = Probe(make_node, executor)
    assert probe.spin(lambda: probe.periods_received(1)), "no first observation"
    assert probe.spin(lambda: all(sim.count_publishers(topics.action(c)) >= 1 for c in CARS))
    return sim, probe


def test_each_car_gets_its_detections_ground_truth_feedback_tf_and_markers(make_node, executor):
    sim, probe = _start(make_node, executor)
    truth = probe.truth[0]
    assert truth.scenario == WorldState.SCENARIO_DRIVING and truth.header.frame_id == "map"
    cars = [o for o in truth.objects if o.class_id == 20]
    assert [c.id for c in cars] == [0, 1] and all(math.isfinite(c.goal_x) for c in cars)
    assert all(0 <= c.x <= 170 and 0 <= c.y <= 100 for c in cars)     # origin at the map's lower-left corner
    for i, car in enumerate(CARS):
        frame = probe.detections[car][0]
        assert (frame.robot_id, frame.motion_period, frame.frame_index, frame.frames_per_period) == (i, 0, 0, 1)
        assert frame.header.frame_id == f"{car}/camera"
        assert frame.detections[0].class_id == 24                      # the SELF row first
        assert any(d.class_id == 23 for d in frame.detections)           # lanes
        assert frame.game_seconds_remaining == pytest.approx(60.0)
        fb = probe.feedback[car][0]
        assert fb.motion_period == 0 and fb.reward_total == 0.0 and not fb.terminated
    assert probe.spin(lambda: len(probe.tf) >= 1 and len(probe.markers) >= 1)
    frames = {t.child_frame_id: t for t in probe.tf[0].transforms}
    assert set(frames) == {"car_0/base_link", "car_0/camera", "car_1/base_link", "car_1/camera"}
    assert frames["car_0/base_link"].transform.translation.x == pytest.approx(cars[0].x)
    assert {m.ns for m in probe.markers[0].markers} == {"map", "ground_truth"}


def test_discrete_actions_drive_and_bad_ones_are_refused_without_crashing(make_node, executor):
    sim, probe = _start(make_node, executor)
    start = {o.id: (o.x, o.y) for o in probe.truth[-1].objects if o.id < 2}
    tick = sim.session.world.tick
    probe.act(0, 1, throttle=float("nan"))                # malformed
    probe.act(0, 1, throttle=2.0)                         # out of range
    probe.act(0, 1, throttle=0.5)                         # not a discrete command
    probe.act(0, 1, throttle=1.0, brake=1.0)              # gas and brake: not a discrete command
    probe.act(0, 1, steering=1.0, brake=1.0)              # beyond the steering limit
    probe.act(0, 1, throttle=1.0, episode=9)              # wrong episode
    probe.act(0, 3, throttle=1.0)                         # early
    probe.act(0, 1, throttle=1.0, robot_id=1)             # another car's id on car_0's topic
    probe.act(0, 1, throttle=1.0, steering=W)             # valid: gas, left
    probe.act(0, 1, throttle=1.0)                         # duplicate
    counts = sim.session.counts
    expected = {"rejected_malformed": 1, "rejected_out_of_range": 4, "rejected_wrong_episode": 1,
                "rejected_early": 1, "rejected_unknown_robot": 1, "rejected_duplicate": 1, "accepted": 1}
    assert probe.spin(lambda: all(counts[k] == v for k, v in expected.items())), dict(counts)
    assert sim.session.world.tick == tick                 # car_1 has not acted: nothing ran
    for period in range(1, 11):
        if period > 1:
            probe.act(0, period, throttle=1.0)
        probe.act(1, period, brake=1.0)                   # brake
        assert probe.spin(lambda: probe.periods_received(period + 1)), period
    end = {o.id: (o.x, o.y) for o in probe.truth[-1].objects if o.id < 2}
    assert math.dist(start[0], end[0]) > 0.5 and math.dist(start[1], end[1]) < 0.01
    assert probe.feedback["car_0"][-1].reward_auxiliary != 0.0 or probe.feedback["car_0"][-1].reward_rule != 0.0
    assert sim.diagnostics()["accepted"] == "20"


def test_continuous_actions_are_accepted_within_bounds(make_node, executor):
    sim, probe = _start(make_node, executor, action_mode="continuous")
    probe.act(0, 1, throttle=0.37, brake=0.0, steering=-0.2)
    probe.act(1, 1, throttle=0.0, brake=1.5)               # brake beyond 1: refused
    assert probe.spin(lambda: sim.session.counts["rejected_out_of_range"] == 1)
    probe.act(1, 1, throttle=-0.5, brake=0.25, steering=W)
    assert probe.spin(lambda: probe.periods_received(2))
    assert sim.session.world.last_actions[0].throttle == pytest.approx(0.37, abs=1e-6)


def _run(make_node, executor, seed):
    sim, probe = _start(make_node, executor, seed=seed)
    for period in range(1, 6):
        probe.act(0, period, throttle=1.0)
        probe.act(1, period, throttle=1.0, steering=-W)
        assert probe.spin(lambda: probe.periods_received(period + 1))
    trace = [tuple((o.id, round(o.x, 9), round(o.y, 9)) for o in m.objects) for m in probe.truth]
    rows = [tuple((d.class_id, round(d.position.x, 6)) for d in m.detections) for m in probe.detections["car_0"]]
    executor.remove_node(sim)
    executor.remove_node(probe.node)
    return trace, rows


def test_stepped_driving_is_deterministic_for_a_seed(make_node, executor):
    assert _run(make_node, executor, 21) == _run(make_node, executor, 21)


def test_reset_with_seed_reproduces_and_step_service_runs_periods(make_node, executor):
    sim, probe = _start(make_node, executor, seed=4)
    reset = probe.node.create_client(ResetSimulation, topics.RESET_SERVICE)
    stepper = probe.node.create_client(StepSimulation, topics.STEP_SERVICE)
    assert reset.wait_for_service(timeout_sec=5.0) and stepper.wait_for_service(timeout_sec=5.0)

    def call(client, request):
        future = client.call_async(request)
        assert probe.spin(future.done)
        return future.result()

    bad = call(reset, ResetSimulation.Request(options_yaml="kickoff_team: a"))
    assert not bad.success and "unknown reset option" in bad.message
    reply = call(stepper, StepSimulation.Request(ticks=30))          # 3 periods of 100 ms, nobody acting
    assert reply.success and reply.tick == 30 and sim.session.counts["missing"] == 6
    first = [(o.id, o.x, o.y) for o in probe.truth[0].objects]
    for episode in (2, 3):
        reply = call(reset, ResetSimulation.Request(use_seed=True, seed=4))
        assert reply.success and reply.episode_id == episode
    assert probe.spin(lambda: probe.truth[-1].episode_id == 3)
    replays = [[(o.id, o.x, o.y) for o in m.objects] for m in probe.truth if m.tick == 0 and m.episode_id > 1]
    assert replays == [first, first]                                 # same seed, same start


def test_the_driving_preset_starts_the_simulator(make_node):
    import yaml
    values = yaml.safe_load((REPO / "config" / "sim_driving.yaml").read_text())["/**"]["ros__parameters"]
    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
    assert sim.scenario == "driving" and sim.config.n_cars == values["n_cars"] and sim.names == CARS
    assert sim.config.episode_seconds == 60.0 and sim.config.rates.motion_period_ticks == 10


@pytest.mark.parametrize("params,message", [
    ({"scenario": "flying"}, "flying"),
    ({"n_cars": 11}, "n_cars"),
    ({"action_mode": "joystick"}, "joystick"),
    ({"players_per_team": 2}, "players_per_team: a parameter of scenario 'robocup'"),
    ({"marker_robot": "team_a_0"}, "team_a_0"),
    ({"controlled_robots": ["car_7"]}, "car_7"),
    ({"perception_preset": "exact"}, "exact")])
def test_bad_driving_parameters_are_refused_with_the_reason(make_node, params, message):
    with pytest.raises(ParameterException, match=message):
        _sim(make_node, **params)


def test_a_driving_parameter_is_refused_by_the_soccer_simulator(make_node):
    with pytest.raises(ParameterException, match="n_cars: a parameter of scenario 'driving'"):
        make_node(SimNode, parameter_overrides=[Parameter("n_cars", value=3)])


def test_scenario_is_read_only(make_node, executor):
    sim, probe = _start(make_node, executor)
    refused = sim.set_parameters([Parameter("scenario", value="robocup")])[0]
    assert not refused.successful and "read-only" in refused.reason


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_scripted_drivers_drive_every_car_without_a_refusal(make_node, executor, action_mode):
    from policy_node.scripted_driver import ScriptedDriverNode
    sim = _sim(make_node, action_mode=action_mode, episode_seconds=4.0, auto_reset=False,
               wait_for_ground_truth_subscribers=2)
    driver = make_node(ScriptedDriverNode, parameter_overrides=[Parameter("n_cars", value=2),
                                                                Parameter("action_mode", value=action_mode)])
    executor.add_node(sim)
    executor.add_node(driver)
    probe = Probe(make_node, executor)
    assert probe.spin(lambda: sim.session.finished, 30.0), dict(sim.session.counts)
    counts = sim.session.counts
    assert counts["accepted"] == 80 and counts["missing"] == 0
    assert not any(k.startswith("rejected_") and v for k, v in counts.items()), dict(counts)
    assert probe.spin(lambda: probe.periods_received(41))
    start, end = probe.truth[0].objects[:2], probe.truth[-1].objects[:2]
    assert all(math.hypot(b.x - a.x, b.y - a.y) > 5.0 for a, b in zip(start, end))   # both drove off


def test_scripted_driver_refuses_unknown_cars(make_node):
    from policy_node.scripted_driver import ScriptedDriverNode
    with pytest.raises(ParameterException, match="car_5"):
        make_node(ScriptedDriverNode, parameter_overrides=[Parameter("cars", value=["car_5"])])


def test_scripted_driver_keeps_only_a_driving_worlds_ground_truth(make_node):
    from policy_node.scripted_driver import ScriptedDriverNode
    driver = make_node(ScriptedDriverNode, parameter_overrides=[Parameter("n_cars", value=2)])
    driver._on_truth(WorldState(scenario=WorldState.SCENARIO_SOCCER, episode_id=1))
    assert len(driver._truth) == 0               # refused (logged): it is not a driving world's
    driver._on_truth(WorldState(scenario=WorldState.SCENARIO_DRIVING, episode_id=1))
    assert list(driver._truth) == [(1, 0, 0)]


def test_realtime_driving_publishes_one_frame_a_period_in_sim_time(make_node, executor):
    sim = _sim(make_node, mode="realtime", real_time_factor=10.0, missing_action="hold")
    executor.add_node(sim)
    probe = Probe(make_node, executor)
    assert probe.spin(lambda: len(probe.detections["car_0"]) >= 15, 20.0)
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in probe.detections["car_0"]]
    assert {round(b - a, 6) for a, b in zip(stamps, stamps[1:])} == {0.1}
    assert sim.session.counts["missing"] > 0                  # nobody acted: the cars kept braking
