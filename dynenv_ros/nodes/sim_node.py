"""The simulator node: a scenario's world (``scenario``: robocup soccer or urban driving) and each agent's vision
pipeline on ROS 2 topics.

Publishes per robot (car) its detections at vision rate, the ground truth and ``/clock`` at vision rate, per-robot
step feedback at motion rate, diagnostics and RViz markers (with ``foxglove_port``, the same scene to the Foxglove
app: ``live_view/``); subscribes to each robot's actions. Stepped mode runs a motion period as soon as every
controlled robot has acted (or on ``/sim/step``); real-time mode is paced by a wall timer. The game — the session,
its action gate, what goes out when — is ROS-free (``envs/sim_game.py``, ``envs/action_gate.py``); this node wires
it to ROS: parameters (``ros/sim_parameters.py``), publishers (``ros/sim_outlet.py``), diagnostics
(``ros/sim_diagnostics.py``), graph queries (``ros/sim_graph.py``), services and timers here (docs/ros_graph.md).
Each feedback names the action its robot's period ran (``StepFeedback.action_digest``); with ``secrets_dir`` only
actions carrying their team's MAC, for a (robot, episode, period) not acted on before, are run, and the feedback is
tagged with the simulator's secret (``security.action_auth``).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from dynenv_msgs.msg import Action
from dynenv_msgs.srv import ResetSimulation, StepSimulation
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.envs.action_gate import ActionGate
from dynenv_ros.envs.session import MISSING_ACTION_RULES
from dynenv_ros.envs.sim_game import SimGame
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros import topics
from dynenv_ros.ros.action_inbox import ActionInbox
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.qos import action_queue
from dynenv_ros.ros.runtime_controls import lock_when_off
from dynenv_ros.ros.sim_diagnostics import SimDiagnostics
from dynenv_ros.ros.sim_graph import SimGraph
from dynenv_ros.ros.sim_outlet import SimOutlet
from dynenv_ros.ros.sim_parameters import declare_sim_parameters
from dynenv_ros.ros.topics import local

# Actions that passed the inbox's screen and wait for this node's thread, per robot: one legitimate action per
# period needs one slot; a flood of plausible actions cannot queue more than this.
ACTION_HANDOVER_DEPTH = 10
# Stepped mode: how often the simulator looks for volatile action publishers (a graph query per robot).
DURABILITY_CHECK_S = 0.2


class SimNode(Node):
    def __init__(self, **node_options: Any) -> None:
        """``node_options`` go to rclpy's Node (context, parameter_overrides, ...) for in-process tests."""
        super().__init__("sim_node", **node_options)
        settings = self.settings = declare_sim_parameters(self)
        self.scenario, self.mode, self.names, self.config = (settings.scenario, settings.mode, settings.names,
                                                             settings.config)
        self.real_time_factor, self.secrets = settings.real_time_factor, settings.secrets
        self.runtime_controls, self.frames_secret = settings.runtime_controls, settings.frames_secret
        self.session: Any = settings.game.make_session(settings.config, settings.perception, settings.seed,
                                                       settings.missing_action, settings.controlled,
                                                       settings.localization)
        self.session.missed_for = self.names.index(settings.marker_robot) if settings.marker_robot else None
        self.outlet = SimOutlet(self, settings, self.session.counts, self._finish)
        self.outlet.map = getattr(self.session.world, "map", None)     # driving's road map (soccer has a field)
        # In real time, actions arrive on a participant and thread of their own (ros/action_inbox.py): a flood on
        # one robot's topic cannot drop this node's service requests. Both modes queue a bounded number (qos.py).
        realtime = self.mode == "realtime"
        actions = [local(topics.action(n)) for n in self.names]
        # The topics the MACs and digests are bound to (fully qualified: the namespace is part of a robot's identity).
        self.gate = ActionGate(self.session, self.names, [self.resolve_topic_name(a) for a in actions],
                               [topics.action(n) for n in self.names], self.secrets,
                               settings.game.action_fields)
        self.game = SimGame(self.session, self.gate, self.outlet, self.scenario, self.mode, settings.seed,
                            settings.localization, settings.auto_reset, settings.exit_when_finished)
        self.action_inbox = ActionInbox(self, Action, actions, action_queue(realtime), ACTION_HANDOVER_DEPTH,
                                        self.gate.screen, self.game.admit, self.gate.count_refusals,
                                        own_participant=realtime)
        # Everything from here on runs with the inbox's thread and participant (and later the live view's server)
        # already started: a constructor that fails (a port in use, a signal during start-up) stops them.
        try:
            self.reporting = SimDiagnostics(self, self.gate)
            self.graph = SimGraph(self, settings, self.outlet, self.action_inbox, self.session.controlled,
                                  self.reporting.recorder_matched)
            # /sim/reset, /sim/step and the settable parameters change the game: off with runtime_controls false
            # (the deployment profile, the train graph; ros/runtime_controls.py).
            services = [self.resolve_service_name(local(n)) for n in (topics.RESET_SERVICE, topics.STEP_SERVICE)]
            lock_when_off(self, self.runtime_controls, " and ".join(services) + " are not offered")
            self.reset_srv = self.step_srv = None
            if self.runtime_controls:       # else every change is refused (lock_when_off)
                self.reset_srv = self.create_service(ResetSimulation, local(topics.RESET_SERVICE), self._on_reset)
                self.step_srv = self.create_service(StepSimulation, local(topics.STEP_SERVICE), self._on_step)
                self.add_on_set_parameters_callback(self._on_set_parameters)
            self.wall = Clock(clock_type=ClockType.STEADY_TIME)
            self.live_view = self.outlet.live_view = self._start_live_view(settings.foxglove_port,
                                                                           settings.foxglove_host)
            self.diagnostics_timer = self.create_timer(settings.diagnostics_period, self._publish_diagnostics,
                                                       clock=self.wall)
            self.vision_timer = self._vision_timer() if realtime else None
            # Stepped mode reads actions transient local, volatile on a topic with a volatile publisher (qos.py).
            self.durability_timer = (None if realtime else self.create_timer(
                DURABILITY_CHECK_S, self.graph.read_volatile_where_offered, clock=self.wall))
            if not realtime and (settings.wait_for_subscribers > 0 or settings.wait_for_recorder
                                 or settings.wait_for_truth_readers > 0):
                self.start_timer = self.create_timer(0.05, self._start_when_subscribed, clock=self.wall)
            else:
                self.game.start(settings.seed)
            self._log_start()
        except BaseException:
            self.destroy_node()
            raise

    @property
    def started(self) -> bool:
        """The first episode has started (stepped mode waits for its readers first)."""
        return self.game.started

    @property
    def periods_run(self) -> int:
        """Motion periods run so far, every episode's."""
        return self.game.periods_run

    def _log_start(self) -> None:
        settings, config, params = self.settings, self.config, self.settings.perception
        world = settings.game.describe(config)
        self.get_logger().info(
            f"{world} {self.mode} ({config.rates.vision_hz:g} Hz vision, {config.rates.motion_hz:g} Hz "
            f"motion), perception '{settings.perception_preset}' mode {params.mode} magnitude "
            f"{params.noise_magnitude:g}; {settings.game.agent}s {', '.join(self.names)}"
            f"{'; self-localization emulated' if settings.localization else ''}")

    def _start_live_view(self, port: int, host: str) -> Any:
        """The Foxglove live view (``live_view/``) on ``port``, or None when it is -1 (off). A port in use or a bad
        host is refused as a parameter error with the reason."""
        if port < 0:
            return None
        from dynenv_ros.live_view.server import LiveView, LiveViewError
        geometry = self.outlet.map if self.outlet.map is not None else self.config.field
        try:
            view = LiveView(geometry, self.names, port=port, host=host, server_name=self.get_fully_qualified_name())
        except LiveViewError as error:
            raise ParameterException(str(error), ["foxglove_port", "foxglove_host"]) from None
        self.get_logger().info(f"live view: open {view.url} in Foxglove (Open connection → Foxglove WebSocket; "
                               "layout config/foxglove/dynenv_layout.json)")
        return view

    # -- timers ------------------------------------------------------------------------------------------------
    def _start_when_subscribed(self) -> None:
        self.graph.read_volatile_where_offered()
        if self.graph.ready():
            self.start_timer.cancel()
            self.game.start(self.settings.seed)

    def _realtime_tick(self) -> None:
        self.game.realtime_tick()

    def _vision_period_ns(self) -> int:
        return round(self.config.rates.vision_period_ticks * self.game.tick_seconds / self.real_time_factor * 1e9)

    def _vision_timer(self) -> Any:
        """Realtime mode: one frame per vision period of sim time, on the wall clock scaled by the factor."""
        return self.create_timer(self._vision_period_ns() * 1e-9, self._realtime_tick, clock=self.wall)

    def _retime_vision_timer(self) -> None:
        """The new period applies from the next frame on, which keeps its phase (the timer is not restarted); only
        if that frame is further away than one new period is it brought forward to one new period from now."""
        period_ns = self._vision_period_ns()
        self.vision_timer.timer_period_ns = period_ns
        if self.vision_timer.time_until_next_call() > period_ns:
            self.vision_timer.reset()

    # -- services and parameters -------------------------------------------------------------------------------
    def _on_reset(self, request: ResetSimulation.Request, response: ResetSimulation.Response) -> Any:
        waiting = not self.game.started
        response.success, response.message = self.game.reset_request(request.options_yaml, request.use_seed,
                                                                      request.seed)
        if response.success and waiting:        # a reset starts a node still waiting for its readers
            self.start_timer.cancel()
        response.episode_id = self.session.episode_id
        return response

    def _on_step(self, request: StepSimulation.Request, response: StepSimulation.Response) -> Any:
        response.success, response.message = self.game.step_request(request.ticks)
        response.tick = self.session.world.tick
        response.stamp = cv.sim_time(self.game.now_tick(), self.game.tick_seconds)
        return response

    def _on_set_parameters(self, parameters: list) -> SetParametersResult:
        for p in parameters:
            if p.name == "missing_action" and p.value not in MISSING_ACTION_RULES:
                return SetParametersResult(successful=False,
                                           reason=f"missing_action must be one of {MISSING_ACTION_RULES}")
            if p.name == "marker_robot" and p.value and p.value not in self.names:
                return SetParametersResult(successful=False, reason=f"marker_robot must be one of {self.names}")
        for p in parameters:
            if p.name == "missing_action":
                self.session.missing_action = p.value
            elif p.name == "marker_robot":
                self.outlet.marker_robot = p.value
                self.session.missed_for = self.names.index(p.value) if p.value else None
            elif p.name == "publish_markers":
                self.outlet.publish_markers = bool(p.value)
            elif p.name == "auto_reset":
                self.game.auto_reset = bool(p.value)
            elif p.name == "real_time_factor" and float(p.value) != self.real_time_factor:
                # Change the period in place: re-creating the timer restarted its period, so setting the factor
                # faster than one vision period (even to the same value) starved the simulation.
                self.real_time_factor = float(p.value)
                if self.vision_timer is not None:
                    self._retime_vision_timer()
        return SetParametersResult(successful=True)

    # -- diagnostics, report, exit -----------------------------------------------------------------------------
    def diagnostics(self) -> dict[str, str]:
        """Achieved rates over the last diagnostics window and action counts, as strings (DiagnosticStatus)."""
        switches = {"action_authentication": self.secrets is not None,
                    "frame_authentication": self.frames_secret is not None, "runtime_controls": self.runtime_controls}
        values = self.game.diagnostics(switches, self.reporting.recorder_error)
        values.update(self.outlet.robot_io.diagnostics())
        return values

    def _publish_diagnostics(self) -> None:
        self.reporting.publish(self.diagnostics())

    def write_report(self, diagnostics: dict[str, str] | None = None) -> None:
        if self.settings.report_path:
            self.game.write_report(self.settings.report_path, diagnostics or self.diagnostics())

    def _finish(self) -> None:
        """Let every subscriber receive everything, write the report, and stop spinning with status 0."""
        from rclpy.duration import Duration

        from dynenv_ros.ros.node_runner import NodeExit
        final = self.diagnostics()     # before waiting: acknowledgements take a heartbeat period (≈ 3 s)
        for publisher in self.outlet.lossless():
            publisher.wait_for_all_acked(Duration(seconds=5.0))
        self.write_report(final)
        raise NodeExit(0)

    def destroy_node(self) -> None:
        inbox = getattr(self, "action_inbox", None)
        if inbox is not None:
            inbox.close()
        live_view = getattr(self, "live_view", None)
        if live_view is not None:
            live_view.stop()
        outlet = getattr(self, "outlet", None)
        if outlet is not None:
            outlet.robot_io.close()
        super().destroy_node()


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SimNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
