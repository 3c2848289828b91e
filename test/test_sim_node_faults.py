"""One bad call must not take the simulator down: ill-typed reset options and seeds are refused with a reason (in
the node, the session and the PettingZoo env alike), /sim/step runs a bounded amount per call, and re-setting a
parameter never starves the real-time timer (docs/ros_graph.md)."""
from __future__ import annotations

import time

import pytest
from dynenv_msgs.srv import ResetSimulation, StepSimulation
from rclpy.parameter import Parameter

from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.nodes.sim_node import SimNode
from dynenv_ros.perception.params import load_preset
from dynenv_ros.ros import sim_outlet as sim_outlet_module
from dynenv_ros.ros import topics
from dynenv_ros.soccer.config import SoccerConfig
from ros_harness import spin_until

MAX_STEP_PERIODS = 100      # docs/ros_graph.md: /sim/step runs at most 100 motion periods per call

BAD_OPTIONS = ["kickoff_team: [a]", "kickoff_team: {x: 1}", "kickoff_team: true", "kickoff_team: 2",
               "kickoff_team: null", "[kickoff_team]", "just text", "kickoff_team: [a", "{1: a}", "{1: a, x: b}",
               "[" * 2000 + "]" * 2000, "&a [*a]", "!!python/object/apply:os.system [ls]", "kickoff_team: .nan"]


def _sim(make_node, executor, **params):
    values = dict(players_per_team=1, seed=1, falls_enabled=False, publish_markers=False, wait_for_subscribers=0)
    values.update(params)
    sim = make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
    client = make_node("client")
    for node in (sim, client):
        executor.add_node(node)
    return sim, client


def _call(executor, cli, request):
    assert cli.wait_for_service(timeout_sec=5.0)
    future = cli.call_async(request)
    assert spin_until(executor, future.done, 10.0)
    return future.result()


def test_ill_typed_reset_options_and_seeds_are_refused_and_the_node_lives_on(make_node, executor):
    sim, client = _sim(make_node, executor)
    reset = client.create_client(ResetSimulation, topics.RESET_SERVICE)
    for options in BAD_OPTIONS:
        reply = _call(executor, reset, ResetSimulation.Request(options_yaml=options))
        assert not reply.success and reply.message.startswith("reset refused"), (options, reply.message)
    episodes = sim.game.episodes_started
    reply = _call(executor, reset, ResetSimulation.Request(use_seed=True, seed=5, options_yaml="{kickoff_team: b}"))
    assert reply.success and sim.game.episodes_started == episodes + 1      # the .srv comment's example works


def test_the_env_refuses_ill_typed_options_with_a_value_error():
    env = parallel_env(players_per_team=1)
    for options in ({"kickoff_team": ["a"]}, {"kickoff_team": {"x": 1}}, {"kickoff_team": True},
                    {"kickoff_team": None}, {"kickoff_team": 0.5}, {"kickoff_team": "A"}, ["kickoff_team"], "a"):
        with pytest.raises(ValueError, match="options|kickoff_team"):
            env.reset(seed=0, options=options)
    with pytest.warns(UserWarning, match="unknown option"):     # PettingZoo's API test passes a dummy option
        env.reset(seed=0, options={"options": 1})
    env.reset(seed=0, options={"kickoff_team": "b"})
    assert env.world.state.kickoff_team == -1


@pytest.mark.parametrize("seed", [1.5, True, "3", -1, 2 ** 64, [1]])
def test_the_env_and_the_session_refuse_bad_seeds_with_a_value_error(seed):
    with pytest.raises(ValueError, match="seed"):
        parallel_env(players_per_team=1).reset(seed=seed)
    session = SoccerSession(SoccerConfig.from_mapping({"players_per_team": 1}), load_preset("none"), seed=0)
    with pytest.raises(ValueError, match="seed"):
        session.reset(seed=seed)


def test_a_huge_step_is_refused_and_a_bounded_one_runs(make_node, executor):
    sim, client = _sim(make_node, executor)
    step = client.create_client(StepSimulation, topics.STEP_SERVICE)
    assert spin_until(executor, lambda: sim.started, 5.0)
    reply = _call(executor, step, StepSimulation.Request(ticks=4_294_967_250 // 50 * 50))
    assert not reply.success and f"at most {MAX_STEP_PERIODS}" in reply.message
    assert sim.periods_run == 0                                   # refused before running anything
    reply = _call(executor, step, StepSimulation.Request(ticks=(MAX_STEP_PERIODS + 1) * 50))
    assert not reply.success
    reply = _call(executor, step, StepSimulation.Request(ticks=3 * 50))
    assert reply.success and sim.periods_run == 3


def test_re_setting_the_real_time_factor_never_starves_the_timer(make_node, executor):
    """Factor 1: a frame is due every 0.1 s. Setting the factor at 20 Hz — to the same value, then for real
    (1.0 <-> 0.99) — restarted the timer each time, so it never fired. Then a speed-up from a 5 s frame period to
    10 ms must not wait for the old period."""
    sim, client = _sim(make_node, executor, mode="realtime", real_time_factor=1.0)
    assert spin_until(executor, lambda: sim.game.frames_published > 0, 5.0)
    for values in ((1.0, 1.0), (0.99, 1.0)):
        before, deadline, k = sim.game.frames_published, time.monotonic() + 2.0, 0
        while time.monotonic() < deadline:
            assert sim.set_parameters([Parameter("real_time_factor", value=values[k % 2])])[0].successful
            k += 1
            end = time.monotonic() + 0.05
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.01)
        assert sim.game.frames_published - before >= 10, (values, sim.game.frames_published - before)   # ~20 due
    assert sim.set_parameters([Parameter("real_time_factor", value=0.02)])[0].successful
    spin_until(executor, lambda: False, 0.2)
    assert sim.set_parameters([Parameter("real_time_factor", value=10.0)])[0].successful
    count = sim.game.frames_published
    assert spin_until(executor, lambda: sim.game.frames_published >= count + 5, 2.0)


def test_an_oversized_options_string_is_refused_before_parsing(make_node, executor):
    sim, client = _sim(make_node, executor)
    reset = client.create_client(ResetSimulation, topics.RESET_SERVICE)
    huge = "{kickoff_team: a, " + "x" * 5000 + ": 1}"                 # docs: options_yaml is at most 4096 characters
    reply = _call(executor, reset, ResetSimulation.Request(options_yaml=huge))
    assert not reply.success and "at most 4096" in reply.message
    for seed in (0, 2 ** 64 - 1):                     # the documented seed range (all of uint64), both ends
        assert _call(executor, reset, ResetSimulation.Request(use_seed=True, seed=seed)).success


def test_realtime_streams_are_bounded_and_stepped_streams_lossless(make_node, executor):
    """docs/ros_graph.md: real time keeps the last 25 frames / 5 feedbacks per reader; stepped mode keeps all; the
    action subscriptions keep the last 10 in both modes."""
    from rclpy.qos import HistoryPolicy, ReliabilityPolicy
    realtime, _ = _sim(make_node, executor, mode="realtime")
    stepped = make_node(SimNode, parameter_overrides=[Parameter("players_per_team", value=1),
                                                      Parameter("wait_for_subscribers", value=0)])
    for sim, frame_depth, feedback_depth in ((realtime, 25, 5), (stepped, None, None)):
        out = sim.outlet
        for publisher, depth in ([(p, frame_depth) for p in [out.clock_pub, out.world_pub] + out.detection_pubs]
                                 + [(p, feedback_depth) for p in out.feedback_pubs]):
            qos = publisher.qos_profile
            assert qos.reliability == ReliabilityPolicy.RELIABLE
            if depth is None:
                assert qos.history == HistoryPolicy.KEEP_ALL
            else:
                assert qos.history == HistoryPolicy.KEEP_LAST and qos.depth == depth, publisher.topic_name
        # Actions: stepped mode reads reliably, keep-last 10; real time best effort, keep-last 100 (docs/ros_graph.md).
        reliability, depth = ((ReliabilityPolicy.BEST_EFFORT, 100) if sim is realtime
                              else (ReliabilityPolicy.RELIABLE, 10))
        for subscription in sim.action_inbox.subscriptions:
            assert subscription.qos_profile.history == HistoryPolicy.KEEP_LAST
            assert subscription.qos_profile.depth == depth
            assert subscription.qos_profile.reliability == reliability


def test_realtime_actions_are_read_on_a_participant_of_their_own(make_node, executor):
    """docs/ros_graph.md: in real time the action readers live in their own context (DDS participant), a node named
    <sim>_actions, so a flood on an action topic does not share the transport that carries the simulator's
    services; in stepped mode they are the simulator node's own (a lost first action would stall the game)."""
    sim, _ = _sim(make_node, executor, mode="realtime")
    assert {s.topic_name for s in sim.action_inbox.subscriptions} == {"/team_a_0/action", "/team_b_0/action"}
    assert sim.action_inbox._node.context is not sim.context
    assert sim.action_inbox._node.get_name() == "sim_node_actions"
    assert spin_until(executor, lambda: "sim_node_actions" in sim.get_node_names(), 5.0)
    stepped = make_node(SimNode, parameter_overrides=[Parameter("players_per_team", value=1),
                                                      Parameter("wait_for_subscribers", value=0)])
    assert all(s in stepped.subscriptions for s in stepped.action_inbox.subscriptions)


class _RefusingPublisher:
    """Stands in for a publisher whose DDS writer refuses samples (a reader that stopped acknowledging): every one,
    or for the first ``refuse_s`` seconds only (a killed reader until DDS unmatches it)."""
    topic_name = "/stuck"

    def __init__(self, refuse_s: float = float("inf")) -> None:
        self.attempts, self.delivered = 0, []
        self.until = time.monotonic() + refuse_s

    def publish(self, message) -> None:
        from rclpy._rclpy_pybind11 import RCLError
        self.attempts += 1
        if time.monotonic() < self.until:
            raise RCLError("cannot publish data")
        self.delivered.append(message)


def test_a_refused_publish_costs_realtime_one_attempt_and_stepped_mode_retries(make_node, executor, monkeypatch):
    sim, _ = _sim(make_node, executor, mode="realtime")
    stuck = _RefusingPublisher()
    sim.outlet.publish(stuck, object())
    assert stuck.attempts == 1                                    # no retry loop in real time
    assert sim.session.counts["publish_failed"] == 1
    # stepped mode stays lossless past a killed reader: a writer refusing for 1.5 s (the old patience was 1 s)
    stepped, _ = _sim(make_node, executor)
    recovering, message = _RefusingPublisher(refuse_s=1.5), object()
    stepped.outlet.publish(recovering, message)
    assert recovering.delivered == [message] and recovering.attempts > 10
    assert stepped.session.counts["publish_failed"] == 0
    # a reader that never acknowledges: given up after the patience (shortened here), counted
    monkeypatch.setattr(sim_outlet_module, "STEPPED_PUBLISH_PATIENCE_S", 0.2)
    stuck = _RefusingPublisher()
    started = time.monotonic()
    stepped.outlet.publish(stuck, object())
    assert time.monotonic() - started >= 0.2 and stuck.attempts > 1 and not stuck.delivered
    assert stepped.session.counts["publish_failed"] == 1


def test_a_flood_of_refused_actions_is_counted_cheaply_and_logged_once_per_report(make_node, executor, capfd):
    """Each refusal used to go through the logger (97 % of its cost); now it is a count, and the diagnostics
    period logs one summary line."""
    from dynenv_msgs.msg import Action
    sim, _ = _sim(make_node, executor)
    assert spin_until(executor, lambda: sim.started, 5.0)
    bad = Action(robot_id=0, episode_id=1, motion_period=1, walk=99)
    capfd.readouterr()
    for _ in range(2001):
        sim.action_inbox.receive(0, bad)          # what the inbox's subscription callback does with each message
    assert spin_until(executor, lambda: sim.session.counts["rejected_out_of_range"] == 2001, 5.0), \
        sim.session.counts
    assert capfd.readouterr().err == ""                           # no log line per refusal
    sim._publish_diagnostics()
    sim._publish_diagnostics()                                    # nothing new: no second summary
    err = capfd.readouterr().err
    assert err.count("actions refused since the last report: 2001 out_of_range") == 1, err
    assert "walk=99" in err and err.count("rejected") <= 2        # the last reason; no line per refusal


def test_a_burst_of_plausible_actions_hands_at_most_the_documented_depth_to_the_game(make_node, executor):
    """200 actions for the current period sent while the simulator's own thread is not spinning: the real-time
    inbox thread reads them all but hands at most 10 to the game (ACTION_HANDOVER_DEPTH, docs/ros_graph.md); the
    first wins. (Real time at 1 % speed, so no period ends meanwhile.)"""
    from dynenv_msgs.msg import Action
    from dynenv_ros.ros.qos import sim_stream
    sim, client = _sim(make_node, executor, mode="realtime", real_time_factor=0.01)
    flooder = make_node("flooder")
    pub = flooder.create_publisher(Action, topics.action("team_a_0"), sim_stream())
    assert spin_until(executor, lambda: sim.started and pub.get_subscription_count() >= 1
                      and sim.action_inbox.subscriptions[0].get_publisher_count() >= 1, 5.0)   # matched both ways
    period = sim.session.period
    for walk in range(200):
        pub.publish(Action(robot_id=0, episode_id=1, motion_period=period, walk=walk % 3))
    time.sleep(1.0)                                                # the inbox thread screens all of it meanwhile
    spin_until(executor, lambda: False, 1.0)
    counts = sim.session.counts
    assert counts["accepted"] == 1, counts
    assert 1 <= counts["accepted"] + counts["rejected_duplicate"] <= 10, counts
def test_wait_for_recorder_also_waits_for_a_reader_of_every_action_topic(make_node, executor):
    """The recorder lost a policy's first actions when the simulator started before it had subscribed to them."""
    from dynenv_msgs.msg import Action, DetectionArray, StepFeedback
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rosgraph_msgs.msg import Clock
    from dynenv_ros.ros.qos import sim_stream
    sim, client = _sim(make_node, executor, wait_for_subscribers=1, wait_for_recorder=True)
    qos, names = sim_stream(), ("team_a_0", "team_b_0")
    for name in names:             # policies (detections readers, action writers) and a recorder without actions
        client.create_subscription(DetectionArray, topics.detections(name), lambda m: None, qos)
        client.create_subscription(StepFeedback, topics.feedback(name), lambda m: None, qos)
        client.create_subscription(PoseWithCovarianceStamped, topics.pose_estimate(name), lambda m: None, qos)
        client.create_publisher(Action, topics.action(name), qos)
    client.create_subscription(Clock, topics.CLOCK, lambda m: None, qos)
    assert spin_until(executor, lambda: all(sim.count_publishers(topics.action(n)) >= 1 for n in names), 5.0)
    spin_until(executor, lambda: sim.started, 1.5)
    assert not sim.started, "started although nobody records the actions"
    recorder = make_node("recorder_stand_in")
    for name in names:
        recorder.create_subscription(Action, topics.action(name), lambda m: None, qos)
    executor.add_node(recorder)
    assert spin_until(executor, lambda: sim.started, 5.0)


def test_wait_for_recorder_waits_until_a_dynenv_recorder_has_matched_every_action_publisher(make_node, executor):
    """Both endpoints visible to the simulator did not mean the recorder had matched the policy's writer: under load
    a 10-period game ended before it had, and all of one robot's actions went unrecorded."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from dynenv_msgs.msg import Action, DetectionArray, StepFeedback
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rosgraph_msgs.msg import Clock
    from dynenv_ros.ros.qos import latched, sim_stream
    sim, client = _sim(make_node, executor, wait_for_subscribers=1, wait_for_recorder=True)
    qos, names = sim_stream(), ("team_a_0", "team_b_0")
    for name in names:
        client.create_subscription(DetectionArray, topics.detections(name), lambda m: None, qos)
        client.create_subscription(StepFeedback, topics.feedback(name), lambda m: None, qos)
        client.create_subscription(PoseWithCovarianceStamped, topics.pose_estimate(name), lambda m: None, qos)
        client.create_publisher(Action, topics.action(name), qos)
    recorder = make_node("recorder_stand_in")
    recorder.create_subscription(Clock, topics.CLOCK, lambda m: None, qos)
    for name in names:
        recorder.create_subscription(Action, topics.action(name), lambda m: None, qos)
    report = recorder.create_publisher(DiagnosticArray, "/recorder/diagnostics", latched(1))
    executor.add_node(recorder)

    def matched(counts):
        report.publish(DiagnosticArray(status=[DiagnosticStatus(name="recorder", values=[
            KeyValue(key=f"matched_publishers:{topics.action(n)}", value=str(c)) for n, c in zip(names, counts)])]))

    matched((1, 0))                                  # the recorder has not matched team_b_0's policy yet
    assert spin_until(executor, lambda: sim.reporting.recorder_matched.get(topics.action("team_b_0")) == 0, 5.0)
    spin_until(executor, lambda: sim.started, 1.5)
    assert not sim.started, "started before the recorder had matched team_b_0's action publisher"
    matched((1, 1))
    assert spin_until(executor, lambda: sim.started, 5.0)


def test_sim_node_help_lists_its_parameters_and_exits_without_starting_ros():
    import subprocess
    import sys
    result = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.sim_node", "--help"], capture_output=True,
                            text=True, timeout=30)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "real_time_factor (default 1.0; 0.01..100.0): Realtime mode: sim seconds per wall second." in out
    assert "mode (default 'stepped'; one of: stepped, realtime; read-only)" in out
    assert "controlled_robots (default [];" in out
    assert "perception" not in result.stderr and "sim_node" not in result.stderr   # the node never started


@pytest.mark.parametrize("module", ["dynenv_ros.nodes.recorder", "dynenv_ros.nodes.bag_player",
                                    "dynenv_ros.nodes.vision_adapter", "dynenv_ros.nodes.selfcheck_talker",
                                    "dynenv_ros.nodes.selfcheck_listener", "policy_node.scripted_policy",
                                    "policy_node.policy_node"])
def test_every_node_run_through_the_node_runner_answers_help(module, tmp_path):
    """docs/ros_graph.md: every node of ros/node_runner.py lists its parameters on --help and exits 0, without
    starting (a recorder would have created its bag in the working directory)."""
    import subprocess
    import sys
    result = subprocess.run([sys.executable, "-m", module, "--help"], capture_output=True, text=True, timeout=60,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("parameters") and "(default " in result.stdout
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("module, typo, meant", [("dynenv_ros.nodes.sim_node", "player_per_team", "players_per_team"),
                                                 ("policy_node.policy_node", "runtim", "runtime")])
def test_a_mistyped_parameter_is_refused_naming_the_known_ones(module, typo, meant, tmp_path):
    """Issue 28: `-p player_per_team:=2` was silently ignored (the node ran with the default). The node runner now
    refuses a parameter the node never declared, exit 2, one line naming it and the node's parameters."""
    import subprocess
    import sys
    result = subprocess.run([sys.executable, "-m", module, "--ros-args", "-p", f"{typo}:=2"], capture_output=True,
                            text=True, timeout=90, cwd=tmp_path)
    assert result.returncode == 2, (result.stdout, result.stderr)
    line = next(line for line in result.stderr.splitlines() if line.startswith("parameter error:"))
    assert f"unknown parameter {typo} for node " in line and f" {meant}," in line, line
    assert "Traceback" not in result.stderr


def test_a_recorder_that_stops_writing_turns_the_simulator_diagnostics_to_error(make_node, executor, capfd):
    """The recorder's latched ERROR (disk full) is repeated where an operator watching the game looks."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    from dynenv_ros.ros.qos import latched
    sim, client = _sim(make_node, executor)
    seen: list[DiagnosticStatus] = []
    client.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, lambda m: seen.extend(m.status), 10)
    recorder = client.create_publisher(DiagnosticArray, "/recorder/diagnostics", latched(1))
    recorder.publish(DiagnosticArray(status=[DiagnosticStatus(level=DiagnosticStatus.OK, name="recorder",
                                                              message="recording 9 topics")]))
    assert spin_until(executor, lambda: sim.reporting.recorder_sub.get_publisher_count() == 1, 5.0)
    sim._publish_diagnostics()
    assert spin_until(executor, lambda: len(seen) >= 1, 5.0)
    assert seen[-1].level != DiagnosticStatus.ERROR and "recorder_error" not in sim.diagnostics()
    recorder.publish(DiagnosticArray(status=[DiagnosticStatus(
        level=DiagnosticStatus.ERROR, name="recorder", message="not recording: [Errno 28] No space left on device")]))
    assert spin_until(executor, lambda: sim.reporting.recorder_error != "", 5.0)
    sim._publish_diagnostics()
    assert spin_until(executor, lambda: len(seen) >= 2, 5.0)
    assert seen[-1].level == DiagnosticStatus.ERROR and "No space left" in seen[-1].message
    assert {v.key: v.value for v in seen[-1].values}["recorder_error"].endswith("No space left on device")
    assert capfd.readouterr().err.count("recorder: not recording") == 1


def test_the_action_inbox_takes_only_the_enclave_from_the_command_line():
    """docs/ros_graph.md: remappings and parameters stay the simulator's; the SROS2 enclave carries over."""
    from dynenv_ros.ros.action_inbox import enclave_arguments
    argv = ["sim_node", "--ros-args", "-r", "__node:=sim2", "-p", "seed:=3", "--enclave", "/dynenv/sim_node"]
    assert enclave_arguments(argv) == ["--ros-args", "--enclave", "/dynenv/sim_node"]
    assert enclave_arguments(["sim_node", "--ros-args", "-e", "/x"]) == ["--ros-args", "--enclave", "/x"]
    assert enclave_arguments(["sim_node", "--ros-args", "-p", "seed:=3"]) == []
    assert enclave_arguments(["sim_node", "--enclave", "/x"]) == []      # not a ROS argument


def test_closing_the_action_inbox_tears_down_only_after_its_thread_stopped(make_node, monkeypatch):
    """CI (28 Nov 2026, under load): Ctrl-C during start-up closed the inbox while its thread waited in rclpy, and
    the process died of SIGSEGV (exit -11, 3 runs in 20 here): rclpy's ``Executor.shutdown`` destroyed the guard
    conditions the other thread was waiting on. Closing now stops the thread first: the executor is shut down and the
    node destroyed only once it has exited, and nothing raises."""
    import threading
    from dynenv_msgs.msg import Action
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from dynenv_ros.ros import action_inbox as module

    alive_at_teardown = []

    class WatchedExecutor(SingleThreadedExecutor):
        def spin_once(self, timeout_sec=None) -> None:
            self.spinner = threading.current_thread()
            super().spin_once(timeout_sec=timeout_sec)

        def shutdown(self, timeout_sec=None) -> bool:
            alive_at_teardown.append(self.spinner.is_alive())
            return super().shutdown(timeout_sec=timeout_sec)

    failures = []
    monkeypatch.setattr(module, "SingleThreadedExecutor", WatchedExecutor)
    monkeypatch.setattr(threading, "excepthook", lambda args: failures.append(args.exc_value))
    owner = make_node("inbox_owner")
    for topic in ("robot_0/action", "robot_1/action", "robot_2/action"):
        inbox = module.ActionInbox(owner, Action, [topic], QoSProfile(depth=4), 4,
                                   screen=lambda robot, msg: ("", ""), deliver=lambda robot, msg: None,
                                   refused=lambda counts, reason: None)
        threading.Event().wait(0.2)                # the thread is inside a wait
        inbox.close()
        assert not inbox._thread.is_alive()
    assert alive_at_teardown == [False, False, False] and failures == []


def test_a_signal_shutting_the_inbox_context_down_under_a_wait_is_a_stop_and_other_failures_surface(make_node,
                                                                                                   monkeypatch):
    """rclpy's SIGINT handler shuts every context down, the inbox's too, possibly under a wait already past its
    check: rcl then refuses the wait set ("the given context is not valid"). That is a stop, quiet; a failure while
    the context is up is real and surfaces in the thread."""
    import threading
    from dynenv_msgs.msg import Action
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from dynenv_ros.ros import action_inbox as module
    from dynenv_ros.ros.node_runner import shutdown_quietly

    release = threading.Event()
    fail_with = []

    class HeldExecutor(SingleThreadedExecutor):
        def spin_once(self, timeout_sec=None) -> None:     # past the loop check, held until released
            release.wait(10.0)
            if fail_with:
                raise fail_with[0]
            super().spin_once(timeout_sec=timeout_sec)

    failures = []
    monkeypatch.setattr(module, "SingleThreadedExecutor", HeldExecutor)
    monkeypatch.setattr(threading, "excepthook", lambda args: failures.append(args.exc_value))
    owner = make_node("inbox_owner")

    def open_inbox(topic: str) -> module.ActionInbox:
        return module.ActionInbox(owner, Action, [topic], QoSProfile(depth=4), 4, screen=lambda robot, msg: ("", ""),
                                  deliver=lambda robot, msg: None, refused=lambda counts, reason: None)

    inbox = open_inbox("robot_0/action")
    shutdown_quietly(inbox._context)               # what the signal handler does, under the held wait
    release.set()
    inbox._thread.join(5.0)
    assert not inbox._thread.is_alive() and failures == []
    inbox.close()

    release.clear()
    fail_with.append(RuntimeError("a failure while the inbox is open"))
    inbox = open_inbox("robot_1/action")
    release.set()
    inbox._thread.join(5.0)
    assert len(failures) == 1 and "while the inbox is open" in str(failures[0])
    inbox.close()


def test_params_files_resolve_from_the_package_config_folder_anywhere(tmp_path, monkeypatch):
    """Issue 28: `--params-file config/…` worked only from the repository root (elsewhere a 16-line traceback).
    A relative path or bare name is now looked up in the working directory, then the package's config folder
    (source tree or installed share directory); a file found nowhere is refused in one line, exit 2."""
    import subprocess
    import sys
    from pathlib import Path
    from dynenv_ros.ros.node_runner import resolve_params_files
    repo_config = Path(__file__).resolve().parent.parent / "config"
    monkeypatch.chdir(tmp_path)
    args = ["sim_node", "--ros-args", "--params-file", "config/sim_2v2_realistic.yaml", "-p", "seed:=3"]
    resolved = resolve_params_files(args)
    assert Path(resolved[3]) in (repo_config / "sim_2v2_realistic.yaml",
                                 Path(sys.prefix) / "share" / "dynenv_ros" / "config" / "sim_2v2_realistic.yaml")
    assert resolved[:3] == args[:3] and resolved[4:] == args[4:]
    assert Path(resolve_params_files(["x", "--params-file", "sim_driving.yaml"])[2]).name == "sim_driving.yaml"
    (tmp_path / "config").mkdir()
    mine = tmp_path / "config" / "sim_2v2_realistic.yaml"
    mine.write_text("/**:\n  ros__parameters:\n    seed: 1\n")
    assert resolve_params_files(args)[3] == "config/sim_2v2_realistic.yaml"          # the user's own file first
    result = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.sim_node", "--ros-args", "--params-file",
                             "config/nope.yaml"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().startswith("parameter error: --params-file config/nope.yaml: no such file here")


SIGINT_DURING_START = """
import os, signal, sys, threading, time
from dynenv_ros.nodes import sim_node
point = sys.argv[1]
def interrupt():
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.5)                                  # the KeyboardInterrupt lands here
if point == "inbox_thread_started":                  # inside ActionInbox(), its thread and participant running
    start = threading.Thread.start
    def start_then_interrupt(self):
        start(self)
        if self.name == "action_inbox":
            interrupt()
    threading.Thread.start = start_then_interrupt
else:                                                # the constructor's next step after the inbox
    diagnostics = sim_node.SimDiagnostics
    def interrupt_then_diagnostics(*args, **kwargs):
        interrupt()
        return diagnostics(*args, **kwargs)
    sim_node.SimDiagnostics = interrupt_then_diagnostics
sys.exit(sim_node.main(["sim_node", "--ros-args", "-p", "mode:=realtime", "-p", "players_per_team:=1"]))
"""


@pytest.mark.parametrize("point", ["inbox_thread_started", "after_the_inbox"])
def test_a_sigint_while_the_realtime_simulator_starts_stops_it_cleanly(point, tmp_path):
    """CI saw `sim_node --params-file config/sim_2v2_deploy.yaml` abort on Ctrl-C ("terminate called without an
    active exception", exit -6): a SIGINT while the constructor ran left the action inbox's thread waiting in rcl,
    and the interpreter's finalization unwound it through C++. Ctrl-C at any point of start-up is a stop: exit 0."""
    import subprocess
    import sys
    result = subprocess.run([sys.executable, "-c", SIGINT_DURING_START, point], capture_output=True, text=True,
                            timeout=90, cwd=tmp_path)
    assert result.returncode == 0, (result.returncode, result.stderr[-2000:])
    assert "terminate called" not in result.stderr and "Traceback" not in result.stderr, result.stderr[-2000:]


def test_a_sigint_delivered_inside_the_runners_error_handling_is_a_clean_stop():
    """CI run of 30 Nov 2026: sim_node exited by SIGINT with a traceback. rclpy's signal thread had shut the context
    down (an RCLError in the executor), and Python raised the same signal's KeyboardInterrupt inside the handler
    that tells such a stop from a failure. That is still the stop asked for: exit status 0, the context shut down and
    rclpy's signal handlers given back. Played in a process of its own (the runner owns rclpy's default context)."""
    import subprocess
    import sys
    script = (
        "import rclpy, signal\n"
        "from rclpy.node import Node\n"
        "from dynenv_ros.ros import node_runner\n"
        "class RCLError(Exception):\n"
        "    pass\n"
        "class Stopped(Node):\n"
        "    def __init__(self):\n"
        "        super().__init__('stopped')\n"
        "        raise RCLError('the given context is not valid')\n"
        "real_ok = rclpy.ok\n"
        "calls = []\n"
        "def ok_then_signal(*a, **k):\n"
        "    calls.append(1)\n"
        "    if len(calls) == 1:\n"
        "        raise KeyboardInterrupt\n"
        "    return real_ok(*a, **k)\n"
        "node_runner.rclpy.ok = ok_then_signal\n"
        "before = signal.getsignal(signal.SIGINT)\n"       # Python's, or SIG_IGN where the parent ignores SIGINT
        "status = node_runner.run_node(Stopped, ['stopped'])\n"
        "node_runner.rclpy.ok = real_ok\n"
        "print('status', status, 'ok', rclpy.ok(), 'sigint', signal.getsignal(signal.SIGINT) is before)\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "status 0 ok False sigint True", (done.stdout, done.stderr[-2000:])
