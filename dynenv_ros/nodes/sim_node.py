"""The simulator node: a scenario's world (``scenario``: robocup soccer or urban driving) and each agent's vision
pipeline on ROS 2 topics.

Publishes per robot (car) its detections at vision rate, the ground truth and ``/clock`` at vision rate, per-robot
step feedback at motion rate, diagnostics and RViz markers (with ``foxglove_port``, the same scene to the Foxglove
app: ``live_view/``); subscribes to each robot's actions. Stepped mode runs a motion period as soon as every
controlled robot has acted (or on ``/sim/step``); real-time mode is paced by a wall timer. All game logic is in the
sessions (``envs/soccer_session.py``, ``envs/driving_session.py``); this file only converts and publishes
(docs/ros_graph.md). Each feedback names the action its robot's period ran
(``StepFeedback.action_digest``); with ``secrets_dir`` only actions carrying their team's MAC, for a (robot, episode,
period) not acted on before, are run, and the feedback is tagged with the simulator's secret (``security.action_auth``).
"""
from __future__ import annotations

import time
from collections import Counter, deque
from collections.abc import Sequence
from typing import Any

import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dynenv_msgs.msg import Action
from dynenv_msgs.srv import ResetSimulation, StepSimulation
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from game_controller_spl_interfaces.msg import RCGCD15
from geometry_msgs.msg import PoseWithCovarianceStamped
from soccer_vision_3d_msgs.msg import BallArray, GoalpostArray, MarkingArray, RobotArray
from std_msgs.msg import Header, UInt8MultiArray
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from dynenv_ros.driving.config import DrivingConfig, car_names
from dynenv_ros.envs.driving_session import DrivingSession
from dynenv_ros.envs.session import MISSING_ACTION_RULES, PeriodOutput, refusal_key
from dynenv_ros.envs.soccer_session import SoccerSession, kickoff_team
from dynenv_ros.gamecontroller.game_state import game_control_data, penalty_code
from dynenv_ros.perception.soccer_vision_3d import soccer_vision_3d
from dynenv_ros.perception.driving_params import load_driving_preset
from dynenv_ros.perception.params import MODES, PRESETS, load_preset
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros import driving_markers, markers, topics
from dynenv_ros.ros.cdr import detection_array_cdr
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.topics import local
from dynenv_ros.ros.action_inbox import ActionInbox
from dynenv_ros.ros.authentication import secrets_for
from dynenv_ros.ros.runtime_controls import declare_runtime_controls, lock_when_off
from dynenv_ros.ros.frame_tags import frames_secret, tag_message, tag_topic
from dynenv_ros.security.frame_auth import detection_rows_bytes, world_state_bytes
from dynenv_ros.security.action_auth import ReplayGuard, action_digest, check_action, tag_feedback
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.pose_estimates import EmulatedOdometry, pose_message, stamp_ns
from dynenv_ros.ros.ros_sports_conversion import rcgcd15, soccer_vision_messages
from dynenv_ros.ros.sim_ros_sports import SimRobotIO
from dynenv_ros.ros.parameters import (declare_bool, declare_float, declare_int, declare_str, declare_str_list,
                                       refuse_other_scenario)
from dynenv_ros.ros.qos import (REALTIME_FEEDBACK_DEPTH, REALTIME_FRAME_DEPTH, action_queue, latched,
                                realtime_stream, sim_stream)
from dynenv_ros.ros.tf import TF_STATIC_TOPIC, TF_TOPIC, static_transforms, tf_message, tf_qos, tf_static_qos
from dynenv_ros.sim.frames import base_frame, robot_frames
from dynenv_ros.sim.seeding import checked_seed
from dynenv_ros.soccer.config import SoccerConfig, robot_names

# Actions that passed the inbox's screen and wait for this node's thread, per robot: one legitimate action per
# period needs one slot; a flood of plausible actions cannot queue more than this.
ACTION_HANDOVER_DEPTH = 10

MODES_OF_RUNNING = ("stepped", "realtime")
# Stepped mode: how often the simulator looks for volatile action publishers (a graph query per robot).
DURABILITY_CHECK_S = 0.2
SCENARIOS = ("robocup", "driving")
RESET_OPTIONS = ("kickoff_team",)                    # robocup; driving takes none
# Parameters only one scenario has: giving one to the other scenario is refused (it would change nothing).
SCENARIO_PARAMETERS = {"robocup": ("players_per_team", "falls_enabled", "localization", "ros_sports",
                                   "gc_team_number_a", "gc_team_number_b"),
                       "driving": ("n_cars", "action_mode", "teams")}
# Defaults that differ: rates (physics Hz, ticks per vision frame, ticks per motion period), episode seconds, the
# agent whose detections the markers show.
SCENARIO_DEFAULTS = {"robocup": dict(rates=(100.0, 10, 50), episode_seconds=120.0, marker_robot="team_a_0"),
                     "driving": dict(rates=(100.0, 10, 10), episode_seconds=60.0, marker_robot="car_0")}
MAX_STEP_PERIODS = 100   # /sim/step: at most this many motion periods per call, so services stay answered
MAX_OPTIONS_CHARS = 4096  # /sim/reset: options_yaml longer than this is refused before parsing

# Stepped mode's patience with a refused publish: longer than Fast DDS's default participant lease (20 s), after
# which a killed reader is unmatched and the writer accepts samples again (``SimNode._publish``).
STEPPED_PUBLISH_PATIENCE_S = 30.0


class SimNode(Node):
    def __init__(self, **node_options: Any) -> None:
        """``node_options`` go to rclpy's Node (context, parameter_overrides, ...) for in-process tests."""
        super().__init__("sim_node", **node_options)
        fixed = dict(read_only=True)   # these shape the world: set them at start (YAML preset, --ros-args -p)
        self.scenario = declare_str(self, "scenario", "robocup", "Which world: robocup (soccer) or driving (urban "
                                    "driving); read-only.", choices=SCENARIOS, **fixed)
        driving = self.scenario == "driving"
        refuse_other_scenario(self, self.scenario, SCENARIO_PARAMETERS)
        defaults = SCENARIO_DEFAULTS[self.scenario]
        # Both scenarios' parameters are declared (so --help and `ros2 param` list them all); a value given for the
        # other scenario's was refused above.
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team (robocup only).", **fixed)
        n_cars = declare_int(self, "n_cars", 2, 1, 10, "Cars (driving only).", **fixed)
        action_mode = declare_str(self, "action_mode", "discrete", "Driving only: discrete (the original's 3x3 "
                                  "commands) or continuous (throttle, brake, steering).",
                                  choices=("discrete", "continuous"), **fixed)
        teams = declare_int(self, "teams", 1, 1, 2, "Driving only: 1 team (every car shares the bonus) or 2.",
                            **fixed)
        self.mode = declare_str(self, "mode", "stepped", "stepped: a period runs when every controlled robot has "
                                "acted (or on /sim/step); realtime: paced by the wall clock.", choices=MODES_OF_RUNNING,
                                **fixed)
        self.real_time_factor = declare_float(self, "real_time_factor", 1.0, 0.01, 100.0,
                                              "Realtime mode: sim seconds per wall second.")
        self.missing_action = declare_str(self, "missing_action", "none", "A robot without an action for a "
                                          "period: 'hold' repeats its last action, 'none' stands still.",
                                          choices=MISSING_ACTION_RULES)
        preset = declare_str(self, "perception_preset", "realistic", "Perception parameter preset.",
                             choices=PRESETS, **fixed)
        noise_mode = declare_str(self, "noise_mode", "", "Error mode (realistic|random|none); empty: the preset's.",
                                 choices=("",) + MODES, **fixed)
        magnitude = declare_float(self, "noise_magnitude", -1.0, -1.0, 5.0,
                                  "Noise magnitude 0..5; -1: the preset's.", **fixed)
        # Defaults by scenario (robocup / driving): 100 Hz physics, a vision frame every 10 ticks, a motion period
        # of 50 / 10 ticks, episodes of 120 / 60 s.
        hz, vision_default, motion_default = defaults["rates"]
        physics_hz = declare_float(self, "physics_hz", hz, 10.0, 1000.0, "Physics ticks per second.", **fixed)
        vision_ticks = declare_int(self, "vision_period_ticks", vision_default, 1, 1000, "Ticks per vision frame.",
                                   **fixed)
        motion_ticks = declare_int(self, "motion_period_ticks", motion_default, 1, 10000,
                                   "Ticks per motion period (default robocup 50, driving 10).", **fixed)
        episode_s = declare_float(self, "episode_seconds", defaults["episode_seconds"], 0.5, 86400.0,
                                  "Episode length, s (default robocup 120, driving 60).", **fixed)
        falls = declare_bool(self, "falls_enabled", True, "Random and contact falls (robocup only).", **fixed)
        seed = declare_int(self, "seed", -1, -1, 2**62, "World seed; -1 draws one.", **fixed)
        localization = declare_bool(self, "localization", True, "Robocup only: emulate every robot's "
                                    "self-localization, publish <robot>/pose_estimate and TF map -> <robot>/odom -> "
                                    "<robot>/base_link at the estimate (the truth on <robot>/ground_truth/base_link); "
                                    "off: base_link is the truth.", **fixed)
        ros_sports = declare_bool(self, "ros_sports", False, "Robocup only: also publish, per robot, its "
                                  "detections as soccer_vision_3d_msgs (<robot>/soccer_vision_3d/balls, robots, "
                                  "goalposts, markings; frame <robot>/base_link) and the game as "
                                  "game_controller_spl's RCGCD15 on <robot>/gc/data once per motion period "
                                  "(docs/interfaces.md).", **fixed)
        gc_team_numbers = [declare_int(self, f"gc_team_number_{team}", default, 1, 254, "Robocup with ros_sports: "
                                       f"the SPL team number of team {team.upper()} in gc/data.", **fixed)
                           for team, default in (("a", 1), ("b", 2))]
        controlled = declare_str_list(self, "controlled_robots", [], "Robots whose actions a period waits for "
                                      "(names like team_a_0); empty: all.", **fixed)
        self.auto_reset = declare_bool(self, "auto_reset", True, "Start a new episode when one ends.")
        self.publish_markers = declare_bool(self, "publish_markers", True, "RViz/Foxglove markers.")
        self.marker_robot = declare_str(self, "marker_robot", defaults["marker_robot"],
                                        "Robot (car) whose detections are drawn (default robocup team_a_0, "
                                        "driving car_0).")
        diag_s = declare_float(self, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.", **fixed)
        self.wait_for_subscribers = declare_int(
            self, "wait_for_subscribers", 1, 0, 100, "Stepped mode: hold the first observation until every robot's "
            "detections topic has this many subscribers (policies, recorder).", **fixed)
        self.wait_for_truth_readers = declare_int(
            self, "wait_for_ground_truth_subscribers", 0, 0, 100, "Stepped mode: also hold the first observation "
            "until /world_state has this many subscribers (scripted policies read it).", **fixed)
        self.wait_for_recorder = declare_bool(
            self, "wait_for_recorder", False, "Stepped mode: also hold the first observation until /clock and every "
            "feedback topic have a subscriber, and every action topic one besides this node (a dynenv recorder: "
            "that has matched every action publisher), so a recorder misses nothing.", **fixed)
        self.exit_when_finished = declare_bool(self, "exit_when_finished", False, "Exit (status 0) when an episode "
                                               "ends and auto_reset is off, after every subscriber has it.", **fixed)
        self.report_path = declare_str(self, "report_path", "", "Write a JSON summary here on exit.", **fixed)
        foxglove_port = declare_int(self, "foxglove_port", -1, -1, 65535, "Live view in the Foxglove app "
                                    "(docs/ros_graph.md): the port of its WebSocket server; -1 off, 0 any free "
                                    "port (logged).", **fixed)
        foxglove_host = declare_str(self, "foxglove_host", "127.0.0.1", "The interface the live view listens on "
                                    "(127.0.0.1: this machine only; 0.0.0.0: every interface, unauthenticated).",
                                    **fixed)
        rates = {"physics_hz": physics_hz, "vision_period_ticks": vision_ticks, "motion_period_ticks": motion_ticks}
        overrides: dict[str, Any] = {}
        if noise_mode:
            overrides["mode"] = noise_mode
        if magnitude >= 0:
            overrides["noise_magnitude"] = magnitude
        try:
            if driving:
                config: Any = DrivingConfig.from_mapping({"n_cars": n_cars, "action_mode": action_mode,
                                                          "teams": teams, "episode_seconds": episode_s,
                                                          "rates": rates})
                params: Any = load_driving_preset(preset, **overrides)
            else:
                config = SoccerConfig.from_mapping({
                    "players_per_team": players, "episode_seconds": episode_s, "falls": {"enabled": falls},
                    "rates": rates})
                params = load_preset(preset, **overrides)
        except ValueError as error:
            raise ParameterException(str(error), ["n_cars" if driving else "players_per_team"]) from None
        self.config = config
        names = car_names(n_cars) if driving else robot_names(players)
        unknown = [c for c in controlled if c not in names]
        if unknown:
            raise ParameterException(f"unknown robots {unknown}; robots are {names}", ["controlled_robots"])
        if self.marker_robot and self.marker_robot not in names:
            raise ParameterException(f"'{self.marker_robot}' is not one of {names}", ["marker_robot"])
        self.localization = localization and not driving
        session_options: dict[str, Any] = {} if driving else {"localization": self.localization}
        session_type: Any = DrivingSession if driving else SoccerSession
        self.session = session_type(config, params, seed=None if seed < 0 else seed,
                                    missing_action=self.missing_action,
                                    controlled=[names.index(c) for c in controlled] if controlled else None,
                                    **session_options)
        self.map = self.session.world.map if driving else None
        self.names = names
        # Authenticated actions (issue 27, security/action_auth.py): with secrets_dir, an action counts only with its
        # team's MAC and a nonce not used before, and the feedback carries the simulator's MAC. Either way the
        # feedback names the action each robot's period ran (StepFeedback.action_digest).
        self.secrets = secrets_for(self, names, simulator=True)
        # /sim/reset, /sim/step and the settable parameters change the game (issue 43, ros/runtime_controls.py).
        self.runtime_controls = declare_runtime_controls(self, "/sim/reset, /sim/step")
        # Authenticated frames (issue 43, security/frame_auth.py): each frame's tag on <topic>_mac.
        self.frames_secret = frames_secret(self, self.get_parameter("secrets_dir").value, "Tag each DetectionArray "
                                           "and WorldState on <topic>_mac")
        self.replay_guard = ReplayGuard()
        self._accepted_digests: dict[int, bytes] = {}          # robot -> digest, for the period being collected
        self._executed_digests: dict[tuple[int, int], dict[int, bytes]] = {}   # (episode, period) run -> digests
        self._seed = None if seed < 0 else seed
        self.session.missed_for = names.index(self.marker_robot) if self.marker_robot else None
        # Stepped mode is lossless (KEEP_ALL: a slow reader slows the simulation down); real time cannot wait, so
        # its publishers keep a bounded history (docs/ros_graph.md, "Real time, QoS and security").
        if self.mode == "stepped":
            frame_qos = feedback_qos = sim_stream()
        else:
            frame_qos, feedback_qos = realtime_stream(REALTIME_FRAME_DEPTH), realtime_stream(REALTIME_FEEDBACK_DEPTH)
        # Joints, fall flags, GameController UDP (issue 41); its parameters declared before the first publisher.
        self.robot_io = SimRobotIO(self, names, ros_sports and not driving, not driving, self._publish, frame_qos)
        self.clock_pub = self.create_publisher(ClockMsg, local(topics.CLOCK), frame_qos)
        self.world_pub = self.create_publisher(cv.WorldState, local(topics.WORLD_STATE), frame_qos)
        self.detection_pubs = [self.create_publisher(cv.DetectionArray, local(topics.detections(n)),
                                                     frame_qos) for n in names]
        self.frame_tag_pubs: list[Any] = []            # world_state's, then each robot's detections'
        if self.frames_secret is not None:
            self.frame_tag_pubs = [self.create_publisher(UInt8MultiArray, tag_topic(p.topic_name), frame_qos)
                                   for p in [self.world_pub] + self.detection_pubs]
        self.feedback_pubs = [self.create_publisher(cv.StepFeedback, local(topics.feedback(n)), feedback_qos)
                              for n in names]
        # Self-localization (ros/pose_estimates.py): each robot's estimate per frame, with the detections' QoS.
        self.pose_pubs = [self.create_publisher(PoseWithCovarianceStamped, local(topics.pose_estimate(n)),
                                                frame_qos) for n in names] if self.localization else []
        # ros-sports (issue 41, docs/interfaces.md): the same frames in the messages a team's stack reads.
        self.ros_sports = ros_sports and not driving
        if self.ros_sports and (len(gc_team_numbers) != 2 or gc_team_numbers[0] == gc_team_numbers[1]):
            raise ParameterException(f"the teams need distinct numbers, got {gc_team_numbers}",
                                     ["gc_team_number_a", "gc_team_number_b"])
        self.gc_team_numbers = (gc_team_numbers[0], gc_team_numbers[1]) if self.ros_sports else (1, 2)
        self.gc_packet_number = 0
        self.penalty_codes: dict[int, int] = {}      # robot id -> SPL penalty of its latest penalty
        self.ros_sports_pubs = [tuple(self.create_publisher(t, local(name), frame_qos) for t, name in (
            (BallArray, topics.soccer_vision_3d(n, "balls")), (RobotArray, topics.soccer_vision_3d(n, "robots")),
            (GoalpostArray, topics.soccer_vision_3d(n, "goalposts")),
            (MarkingArray, topics.soccer_vision_3d(n, "markings")))) for n in names] if self.ros_sports else []
        self.gc_pubs = [self.create_publisher(RCGCD15, local(topics.gc_data(n)), frame_qos)
                        for n in names] if self.ros_sports else []
        self.odometry = EmulatedOdometry(config.rates.vision_period_ticks * config.rates.tick_seconds)
        # In real time, actions arrive on a participant and thread of their own (ros/action_inbox.py): a flood on
        # one robot's topic cannot drop this node's service requests. Both modes queue a bounded number (qos.py).
        realtime = self.mode == "realtime"
        # The topics the MACs and digests are bound to (fully qualified: the namespace is part of a robot's identity).
        self.action_topics = [self.resolve_topic_name(local(topics.action(n))) for n in names]
        self.feedback_topics = [p.topic_name for p in self.feedback_pubs]
        self.action_inbox = ActionInbox(self, Action, [local(topics.action(n)) for n in names],
                                        action_queue(realtime), ACTION_HANDOVER_DEPTH, self._screen_action,
                                        self._receive_action, self._count_refusals, own_participant=realtime)
        # Everything from here on runs with the inbox's thread and participant (and later the live view's server)
        # already started: a constructor that fails (a port in use, a signal during start-up) stops them.
        try:
            self._refused_since_log: Counter[str] = Counter()   # refusals not yet summarised in the log
            self._last_refusal = ""
            self.diagnostics_pub = Diagnostics(self, local(topics.DIAGNOSTICS))     # and /diagnostics
            # A recorder that stopped writing (disk full, I/O error) says so, latched; the simulator repeats it in its
            # own diagnostics and log, where an operator watching the game looks.
            self.recorder_error = ""
            self.recorder_matched: dict[str, int] = {}      # topic -> publishers the recorder has matched
            self.recorder_sub = self.create_subscription(DiagnosticArray, local(topics.RECORDER_DIAGNOSTICS),
                                                         self._on_recorder_diagnostics, latched(1))
            # TF (ros/tf.py): the robots and their heads per frame; the team frames once, latched.
            self.tf_pub = self.create_publisher(TFMessage, local(TF_TOPIC), tf_qos())
            self.tf_static_pub = self.create_publisher(TFMessage, local(TF_STATIC_TOPIC), tf_static_qos())
            if not driving:               # the team frames of soccer's localization outputs
                self.tf_static_pub.publish(static_transforms(cv.sim_time(0, config.rates.tick_seconds)))
            self._last_tf_ns = -1
            self.truth_marker_pub = self.create_publisher(MarkerArray, local(topics.GROUND_TRUTH_MARKERS),
                                                          QoSProfile(depth=5))
            self.detection_marker_pub = self.create_publisher(MarkerArray, local(topics.DETECTION_MARKERS),
                                                              QoSProfile(depth=5))
            # /sim/reset, /sim/step and the settable parameters change the game: off with runtime_controls false
            # (the deployment profile, the train graph; ros/runtime_controls.py).
            services = [self.resolve_service_name(local(n)) for n in (topics.RESET_SERVICE, topics.STEP_SERVICE)]
            lock_when_off(self, self.runtime_controls, " and ".join(services) + " are not offered")
            self.reset_srv = self.step_srv = None
            if self.runtime_controls:
                self.reset_srv = self.create_service(ResetSimulation, local(topics.RESET_SERVICE), self._on_reset)
                self.step_srv = self.create_service(StepSimulation, local(topics.STEP_SERVICE), self._on_step)
            if self.runtime_controls:       # else every change is refused (lock_when_off)
                self.add_on_set_parameters_callback(self._on_set_parameters)
            self.wall = Clock(clock_type=ClockType.STEADY_TIME)
            self.frames_published = 0
            self.periods_run = 0
            self.episodes_started = 0
            self._diagnostics_sent = 0
            self._tick_offset = 0
            self._first_period_wall = self._last_period_wall = 0.0
            self.episode_scores: list[tuple[int, int]] = []
            self._window = deque(maxlen=2)   # (wall time, sim time, frames) samples for achieved rates
            self._buffer: deque = deque()    # realtime: frames of the current period waiting for their instant
            self._tick_s = config.rates.tick_seconds
            self.live_view = self._start_live_view(foxglove_port, foxglove_host)
            self.diagnostics_timer = self.create_timer(diag_s, self._publish_diagnostics, clock=self.wall)
            self.vision_timer = self._vision_timer() if self.mode == "realtime" else None
            self.started = False
            self._started_wall = time.monotonic()
            # Stepped mode reads actions transient local, volatile on a topic with a volatile publisher (qos.py).
            self.durability_timer = (self.create_timer(DURABILITY_CHECK_S, self._read_volatile_where_offered,
                                                       clock=self.wall) if self.mode == "stepped" else None)
            if self.mode == "stepped" and (self.wait_for_subscribers > 0 or self.wait_for_recorder
                                           or self.wait_for_truth_readers > 0):
                self.start_timer = self.create_timer(0.05, self._start_when_subscribed, clock=self.wall)
            else:
                self._start()
            world = (f"driving, {n_cars} cars ({config.action_mode} actions)" if driving
                     else f"{players}v{players}")
            self.get_logger().info(
                f"{world} {self.mode} ({config.rates.vision_hz:g} Hz vision, {config.rates.motion_hz:g} Hz "
                f"motion), perception '{preset}' mode {params.mode} magnitude {params.noise_magnitude:g}; "
                f"{'cars' if driving else 'robots'} {', '.join(names)}"
                f"{'; self-localization emulated' if self.localization else ''}")
        except BaseException:
            self.destroy_node()
            raise

    def _start_live_view(self, port: int, host: str) -> Any:
        """The Foxglove live view (``live_view/``) on ``port``, or None when it is -1 (off). A port in use or a bad
        host is refused as a parameter error with the reason."""
        if port < 0:
            return None
        from dynenv_ros.live_view.server import LiveView, LiveViewError
        geometry = self.map if self.scenario == "driving" else self.config.field
        try:
            view = LiveView(geometry, self.names, port=port, host=host, server_name=self.get_fully_qualified_name())
        except LiveViewError as error:
            raise ParameterException(str(error), ["foxglove_port", "foxglove_host"]) from None
        self.get_logger().info(f"live view: open {view.url} in Foxglove (Open connection → Foxglove WebSocket; "
                               "layout config/foxglove/dynenv_layout.json)")
        return view

    # -- episodes --------------------------------------------------------------------------------------------------
    def _start(self) -> None:
        self.started = True
        self._started_wall = time.monotonic()
        self._reset(self._seed, 1)

    def _read_volatile_where_offered(self) -> None:
        """Stepped mode: read a robot's actions volatile once a publisher there offers only volatile durability (a
        transient-local reader does not match it; its actions would never arrive), and say so once."""
        for robot, subscription in enumerate(self.action_inbox.subscriptions):
            if subscription.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL:
                continue
            topic = subscription.topic_name
            volatile = [info for info in self.get_publishers_info_by_topic(topic)
                        if info.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL]
            if volatile:
                self.action_inbox.resubscribe(robot, action_queue(realtime=False, latched_offers=False))
                # A writer can be discovered before its participant's node names are ("_NODE_NAME_UNKNOWN_").
                names = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in volatile
                                if "_UNKNOWN_" not in i.node_name + i.node_namespace})
                who = ", ".join(names) if names else "a publisher whose node is not known yet"
                self.get_logger().warning(
                    f"{topic}: volatile actions from {who}; "
                    "reading this topic volatile from now on (an action sent before its writer matches this reader "
                    "is lost: publish with dynenv_ros.ros.qos.action_stream(), transient local)")

    def _start_when_subscribed(self) -> None:
        self._read_volatile_where_offered()
        wanted = self.wait_for_subscribers
        ready = all(p.get_subscription_count() >= wanted for p in self.detection_pubs)
        ready = ready and self.world_pub.get_subscription_count() >= self.wait_for_truth_readers
        # ... and every controlled robot has someone to act for it, matched by the action inbox's own participant
        # (it discovers writers on its own schedule), so no first action is sent into the void.
        ready = ready and all(self.action_inbox.subscriptions[i].get_publisher_count()
                              >= max(1, self.count_publishers(local(topics.action(self.names[i]))))
                              for i in self.session.controlled)
        if self.wait_for_recorder:
            ready = ready and all(p.get_subscription_count() >= 1
                                  for p in self.feedback_pubs + self.pose_pubs + [self.clock_pub])
            # ... and every action topic has a reader besides this node (the recorder), or the first actions a
            # policy sends are accepted here but never recorded.
            ready = ready and all(self.count_subscribers(local(topics.action(n))) >= 2 for n in self.names)
            # Seeing both the recorder's reader and a policy's writer does not mean they have matched each other;
            # a dynenv recorder says which publishers it has matched (another recorder: the check above only).
            if self.count_publishers(local(topics.RECORDER_DIAGNOSTICS)) > 0:
                actions = [local(topics.action(n)) for n in self.names]
                ready = ready and all(self.recorder_matched.get(self.resolve_topic_name(a), 0)
                                      >= self.count_publishers(a) for a in actions)
        if ready:
            self.start_timer.cancel()
            self._start()

    def _reset(self, seed: int | None, kickoff: int) -> None:
        # Sim time (/clock and every stamp) runs on across episodes, so use_sim_time nodes never see it jump
        # back; WorldState.tick and game_time restart with each episode. One vision period separates episodes.
        if self.episodes_started:
            self._tick_offset += self.session.world.tick + self.config.rates.vision_period_ticks
        if self.scenario == "driving":
            self.session.reset(seed=seed)
        else:
            self.session.reset(seed=seed, kickoff_team=kickoff)
            self.penalty_codes.clear()
        self.odometry.restart()                 # a new episode, a new odometry (odom: the kickoff pose)
        self.episodes_started += 1
        if self.live_view is not None:
            self.live_view.log_event(f"episode {self.session.episode_id} started", self._now_ns())
        self._buffer.clear()
        self._accepted_digests.clear()
        self._executed_digests.clear()
        self._emit(self.session.initial())

    def _on_reset(self, request: ResetSimulation.Request, response: ResetSimulation.Response):
        try:
            if len(request.options_yaml) > MAX_OPTIONS_CHARS:
                raise ValueError(f"options_yaml is {len(request.options_yaml)} characters; at most "
                                 f"{MAX_OPTIONS_CHARS}")
            try:
                options = yaml.safe_load(request.options_yaml) if request.options_yaml.strip() else {}
            except RecursionError:              # "[[[[…" parses recursively: deep nesting exhausts the stack
                raise ValueError("options_yaml is nested too deeply") from None
            if not isinstance(options, dict):
                raise ValueError(f"options_yaml must be a mapping such as {{kickoff_team: b}}, got "
                                 f"{type(options).__name__}")
            known = RESET_OPTIONS if self.scenario == "robocup" else ()
            unknown = sorted(set(options) - set(known), key=repr)
            if unknown:
                raise ValueError(f"unknown reset option(s) {unknown}; known: {list(known)}")
            kickoff = kickoff_team(options.get("kickoff_team", "a"))
            seed = checked_seed(int(request.seed)) if request.use_seed else None
        except (ValueError, yaml.YAMLError) as error:
            response.success, response.message = False, f"reset refused: {error}"
            response.episode_id = self.session.episode_id
            return response
        if not self.started:                    # a reset starts a node still waiting for its readers
            self.start_timer.cancel()
            self.started = True
            self._started_wall = time.monotonic()
        self._reset(seed, kickoff)
        response.success, response.episode_id = True, self.session.episode_id
        response.message = f"episode {self.session.episode_id} started"
        return response

    def _on_step(self, request: StepSimulation.Request, response: StepSimulation.Response):
        period_ticks = self.config.rates.motion_period_ticks
        if not self.started:
            response.success = False
            response.message = "not started yet: waiting for subscribers (wait_for_subscribers & co.)"
        elif self.mode != "stepped":
            response.success, response.message = False, "/sim/step works in stepped mode only"
        elif request.ticks % period_ticks:
            response.success = False
            response.message = f"ticks must be a multiple of the motion period ({period_ticks}), or 0 for one period"
        elif request.ticks // period_ticks > MAX_STEP_PERIODS:
            response.success = False
            response.message = (f"ticks {request.ticks} is {request.ticks // period_ticks} periods; one call runs "
                                f"at most {MAX_STEP_PERIODS} ({MAX_STEP_PERIODS * period_ticks} ticks): call again "
                                "for more")
        else:
            for _ in range(max(1, request.ticks // period_ticks)):
                if self.session.finished and not self.auto_reset:
                    break
                self._run_period()
            response.success = not (self.session.finished and not self.auto_reset)
            response.message = "stepped" if response.success else "the episode has finished; call /sim/reset"
        response.tick = self.session.world.tick
        response.stamp = cv.sim_time(self._tick_offset + self.session.world.tick, self._tick_s)
        return response

    # -- actions ---------------------------------------------------------------------------------------------------
    def _screen_action(self, robot: int, msg: Action) -> tuple[str, str]:
        """On the inbox thread: ("", "") for an action the session may accept now, else its counter key and
        reason. Reads the session only; the owner's thread submits (and re-checks) what passes."""
        if msg.robot_id != robot:
            return "rejected_unknown_robot", (f"unknown_robot: robot_id {msg.robot_id} on "
                                              f"{topics.action(self.names[robot])} (expected {robot})")
        if self.secrets is not None:
            problem = self._authentication_problem(robot, msg)
            if problem:
                return refusal_key(problem), f"{self.names[robot]}: {problem}"
        reason = self.session.check(msg.robot_id, msg.episode_id, msg.motion_period, *self._action_fields(msg))
        return (refusal_key(reason), f"{self.names[robot]}: {reason}") if reason else ("", "")

    def _action_fields(self, msg: Action) -> tuple:
        """The scenario's fields of an Action (the other scenario's are ignored, as Action.msg says)."""
        if self.scenario == "driving":
            return float(msg.throttle), float(msg.brake), float(msg.steering)
        return msg.walk, msg.turn, msg.kick, float(msg.head_yaw_delta)

    def _authentication_problem(self, robot: int, msg: Action) -> str:
        """Why ``msg`` is not its robot's team's own, fresh action: "" (it is), ``mac_missing``, ``mac_invalid``
        (forged, altered, another team's secret or another topic's) or ``replayed`` (its nonce was used)."""
        problem = check_action(msg, self.action_topics[robot], self.secrets.for_agent(self.names[robot]))
        if problem:
            return f"{problem}: episode {msg.episode_id} period {msg.motion_period}"
        if self.replay_guard.used((msg.robot_id, msg.episode_id, msg.motion_period)):
            return f"replayed: episode {msg.episode_id} period {msg.motion_period} was acted on already"
        return ""

    def _receive_action(self, robot: int, msg: Action) -> None:
        """On this node's thread: an action that passed the screen; the period may have moved on since."""
        accepted, reason = self.session.submit(msg.robot_id, msg.episode_id, msg.motion_period,
                                               *self._action_fields(msg))
        if not accepted:
            self._count_refusals(Counter({refusal_key(reason): 1}), f"{self.names[robot]}: {reason}", counted=True)
            return
        self._accepted_digests[robot] = action_digest(msg, self.action_topics[robot])
        if self.secrets is not None:
            self.replay_guard.use((msg.robot_id, msg.episode_id, msg.motion_period))
        if self.mode == "stepped" and self.session.ready():
            self._run_period()

    def _count_refusals(self, refused: Counter[str], last: str, counted: bool = False) -> None:
        # Counted (diagnostics) and summarised in the log once per diagnostics period: logging each one cost ~30x
        # the check itself, so a flood of bad actions starved the node's services.
        if not counted:
            self.session.counts.update(refused)
        for key, n in refused.items():
            if key.startswith("rejected_"):
                self._refused_since_log[key[len("rejected_"):]] += n
                self._last_refusal = last

    # -- running ---------------------------------------------------------------------------------------------------
    def _run_period(self) -> None:
        if not self.started:
            return
        if self.session.finished:
            if not self.auto_reset:
                return
            self._reset(None, 1)
            return
        executed, self._accepted_digests = self._accepted_digests, {}
        output = self.session.step()
        self._executed_digests[(output.episode_id, output.motion_period)] = executed
        while len(self._executed_digests) > 8:      # bounded (real time: the feedback follows within a period)
            del self._executed_digests[next(iter(self._executed_digests))]
        self.periods_run += 1
        if self.ros_sports:
            for event in output.events:
                if event.kind == "penalty" and event.robot is not None:
                    self.penalty_codes[event.robot] = penalty_code(event.detail)
        now = time.monotonic()
        self._first_period_wall = self._first_period_wall or now
        self._last_period_wall = now
        self._emit(output)
        logged = getattr(self.session, "logged_events", ("goal", "penalty"))
        for event in output.events:
            if event.kind in logged:
                who = self.names[event.robot] if event.robot is not None else f"team {'A' if event.team > 0 else 'B'}"
                self.get_logger().info(f"{event.kind}: {who} {event.detail}")
                if self.live_view is not None:
                    self.live_view.log_event(f"{event.kind}: {who} {event.detail}", self._now_ns())

    def _realtime_tick(self) -> None:
        if not self._buffer:
            self._run_period()
        if self._buffer:
            output, k, poses = self._buffer.popleft()
            self._publish_frame(output, k, poses)
            if k == len(output.frames) - 1:
                self._publish_feedback(output)

    def _emit(self, output: PeriodOutput) -> None:
        """Stepped mode: every frame of the period now, then the feedback; real time: the frames wait in the
        buffer for their instants. The period's pose estimates go with them (the session's arrays are new ones
        every period)."""
        localization = self.session.vision.localization if self.localization else None
        poses = None if localization is None else (localization.estimates, localization.variances)
        if self.mode == "realtime":
            self._buffer.extend((output, k, poses) for k in range(len(output.frames)))
            return
        for k in range(len(output.frames)):
            self._publish_frame(output, k, poses)
        self._publish_feedback(output)

    def _publish(self, publisher, message) -> None:
        """Publish on a KEEP_ALL topic. In stepped mode nothing is lost: if Fast DDS refuses after its blocking
        time, try again for up to ``STEPPED_PUBLISH_PATIENCE_S``. Why that long: a reader killed without goodbye
        (SIGKILL) stays matched until its participant's lease runs out (Fast DDS: 20 s by default) and its
        unacknowledged samples fill the writer's history meanwhile; a one-second patience dropped frames then and
        stalled the game. A reader that is alive but never reads is a fault of its own: after the patience the
        message is counted in ``publish_failed`` and dropped. In real time one attempt only: a frame that cannot
        go out now is counted and dropped, the clock does not wait."""
        deadline = time.monotonic() + (STEPPED_PUBLISH_PATIENCE_S if self.mode == "stepped" else 0.0)
        waited = False
        while True:
            try:
                publisher.publish(message)
                return
            except Exception as error:          # rclpy's RCLError: "cannot publish data"
                if type(error).__name__ != "RCLError":
                    raise
            if time.monotonic() >= deadline:
                break
            if not waited:
                waited = True
                self.get_logger().warning(f"{publisher.topic_name}: a reader does not acknowledge (killed?); "
                                          f"waiting up to {STEPPED_PUBLISH_PATIENCE_S:.0f} s for DDS to drop it",
                                          throttle_duration_sec=5.0)
            time.sleep(0.01)
        self.session.counts["publish_failed"] += 1
        self.get_logger().error(f"could not publish on {publisher.topic_name}: its readers are stuck",
                                throttle_duration_sec=1.0)

    def _publish_frame(self, output: PeriodOutput, k: int, poses: tuple | None = None) -> None:
        """Frame k of a period: /clock, /world_state, TF, the pose estimates (``poses``: the period's (F, n, 3)
        estimates and variances, None without localization), then every robot's detections."""
        frame = output.frames[k]
        stamp = cv.sim_time(self._tick_offset + frame.tick, self._tick_s)
        self._publish(self.clock_pub, ClockMsg(clock=stamp))
        world = cv.world_state(frame.snapshot, stamp)
        self._publish(self.world_pub, world)
        if self.frame_tag_pubs:
            self._publish(self.frame_tag_pubs[0], tag_message(self.frames_secret,
                                                              world_state_bytes(world, self.world_pub.topic_name)))
        truth = [(o.x, o.y, o.yaw, o.head_yaw) for o in frame.snapshot.objects[:len(self.names)]]
        estimates = odometry = None
        if poses is not None:
            estimates, variances = poses[0][k], poses[1][k]
            odometry = self.odometry.step([t[:3] for t in truth])
        # Period 0 repeats one instant and tf2 warns on repeated stamps: one tree per instant, its last frame's
        # (the estimate a policy acts on).
        last_of_instant = k == len(output.frames) - 1 or output.frames[k + 1].tick != frame.tick
        tf_ns = stamp_ns(stamp)
        if tf_ns > self._last_tf_ns and last_of_instant:
            self._last_tf_ns = tf_ns
            transforms = robot_frames(self.names, truth, estimates, odometry)
            self.tf_pub.publish(tf_message(transforms, stamp))
            if self.live_view is not None:   # the same instant and tree, to Foxglove (live_view/server.py)
                self.live_view.publish_frame(frame.snapshot, frame.robots, tf_ns, motion_period=output.motion_period,
                                             transforms=transforms)
        if poses is not None:
            for i, publisher in enumerate(self.pose_pubs):
                self._publish(publisher, pose_message(estimates[i], variances[i], stamp))
        frames_per_period = len(output.frames)
        for i, robot in enumerate(frame.robots):   # serialised from the numpy records directly (ros/cdr.py)
            fields = dict(stamp_sec=stamp.sec, stamp_nanosec=stamp.nanosec, frame_id=cv.camera_frame(self.names[i]),
                          robot_id=i, episode_id=output.episode_id, motion_period=output.motion_period,
                          frame_index=k, frames_per_period=frames_per_period, head_yaw=robot.head_yaw,
                          fallen=robot.fallen, penalized=robot.penalized, kicking=robot.kicking,
                          ball_owner=robot.ball_owner, ball_owner_seconds=robot.ball_owner_seconds,
                          game_seconds_remaining=robot.game_seconds_remaining)
            self._publish(self.detection_pubs[i], detection_array_cdr(robot.detections, **fields))
            if self.frame_tag_pubs:
                data = detection_rows_bytes(robot.detections, self.detection_pubs[i].topic_name, **fields)
                self._publish(self.frame_tag_pubs[i + 1], tag_message(self.frames_secret, data))
        self.robot_io.frame(output, k, frame, stamp)        # joints, fall flags, GameController UDP (issue 41)
        if self.ros_sports:
            self._publish_ros_sports(output, k, frame, stamp)
        self.frames_published += 1
        if self.publish_markers and k == len(output.frames) - 1:
            self._publish_markers(frame, stamp)

    def _publish_ros_sports(self, output: PeriodOutput, k: int, frame, stamp) -> None:
        """Frame k's detections as soccer_vision_3d_msgs per robot (base_link frame); at a period's first frame the
        game as RCGCD15 on each robot's gc/data, as game_controller_spl relays the GameController's 2 Hz packets
        (one motion period is 0.5 s by default)."""
        for i, robot in enumerate(frame.robots):
            header = Header(stamp=stamp, frame_id=base_frame(self.names[i]))
            records = soccer_vision_3d(robot.detections, robot.head_yaw)
            for publisher, message in zip(self.ros_sports_pubs[i], soccer_vision_messages(records, header)):
                self._publish(publisher, message)
        if k != 0:
            return
        data = game_control_data(frame.snapshot, players_per_team=self.config.players_per_team,
                                 team_numbers=self.gc_team_numbers, packet_number=self.gc_packet_number,
                                 penalties=self.penalty_codes)
        self.gc_packet_number = (self.gc_packet_number + 1) % 256
        message = rcgcd15(data)
        for publisher in self.gc_pubs:
            self._publish(publisher, message)

    def _publish_feedback(self, output: PeriodOutput) -> None:
        stamp = cv.sim_time(self._tick_offset + output.frames[-1].tick, self._tick_s)
        executed = self._executed_digests.pop((output.episode_id, output.motion_period), {})
        for i, fb in enumerate(output.feedback):
            msg = cv.step_feedback(
                robot_id=i, episode_id=output.episode_id, motion_period=output.motion_period, rewards=fb.rewards,
                terminated=output.terminated if fb.terminated is None else fb.terminated,
                truncated=output.truncated if fb.truncated is None else fb.truncated,
                seen_object_ids=fb.seen_object_ids, landmarks_seen=fb.landmarks_seen, stamp=stamp,
                action_digest=executed.get(i, b""))
            if self.secrets is not None:
                msg.mac = tag_feedback(msg, self.feedback_topics[i], self.secrets.simulator)
            self._publish(self.feedback_pubs[i], msg)
        if output.terminated or output.truncated:
            if self.scenario == "robocup":
                self.episode_scores.append((self.session.world.state.score[1], self.session.world.state.score[-1]))
            if self.auto_reset and self.mode == "stepped":
                self._reset(None, 1)
            elif not self.auto_reset and self.exit_when_finished:
                self._finish()

    def _finish(self) -> None:
        """Let every subscriber receive everything, write the report, and stop spinning with status 0."""
        from rclpy.duration import Duration

        from dynenv_ros.ros.node_runner import NodeExit
        final = self.diagnostics()     # before waiting: acknowledgements take a heartbeat period (≈ 3 s)
        publishers = ([self.clock_pub, self.world_pub] + self.detection_pubs + self.frame_tag_pubs + self.feedback_pubs
                      + self.pose_pubs)
        for publisher in publishers:
            publisher.wait_for_all_acked(Duration(seconds=5.0))
        self.write_report(final)
        raise NodeExit(0)

    def write_report(self, diagnostics: dict[str, str] | None = None) -> None:
        if not self.report_path:
            return
        import json
        report = {"diagnostics": diagnostics or self.diagnostics(), "episode_scores": self.episode_scores,
                  "published": {"world_state": self.frames_published,
                                "detections_per_robot": self.frames_published,
                                "feedback_per_robot": self.periods_run + self.episodes_started,
                                "pose_estimates_per_robot": self.frames_published if self.localization else 0},
                  # what a lossless recorder must hold on each /<robot>/action (the main job checks it)
                  "accepted_actions": {n: self.session.accepted_per_robot[i] for i, n in enumerate(self.names)},
                  "robots": self.names, "scenario": self.scenario}
        if self.scenario == "driving":     # finished episodes, then the one running (if any period ran)
            report["episodes"] = list(self.session.episodes)
            if not self.session.finished and self.session.world.period > 0:
                report["episodes"].append(self.session.summary())
        with open(self.report_path, "w") as handle:
            json.dump(report, handle, indent=2)

    def _publish_markers(self, frame, stamp) -> None:
        if self.scenario == "driving":
            self._publish_driving_markers(frame, stamp)
            return
        self.truth_marker_pub.publish(markers.ground_truth_markers(frame.snapshot, self.config.field, stamp,
                                                                   include_field=True))
        if self.marker_robot:
            i = self.names.index(self.marker_robot)
            me, robot = frame.snapshot.objects[i], frame.robots[i]
            missed = [] if robot.missed is None else [tuple(p) for p in robot.missed.tolist()]
            self.detection_marker_pub.publish(markers.detection_markers(
                robot.detections, (me.x, me.y, me.yaw + me.head_yaw), stamp, missed=missed,
                robot_name=self.marker_robot))

    def _publish_driving_markers(self, frame, stamp) -> None:
        self.truth_marker_pub.publish(driving_markers.ground_truth_markers(frame.snapshot, self.map, stamp,
                                                                           include_map=True))
        if self.marker_robot:
            i = self.names.index(self.marker_robot)
            me, car = frame.snapshot.objects[i], frame.robots[i]
            missed = [] if car.missed is None else [tuple(p) for p in car.missed.tolist()]
            self.detection_marker_pub.publish(driving_markers.detection_markers(
                car.detections, (me.x, me.y, me.yaw), stamp, missed=missed, car_name=self.marker_robot))

    # -- parameters and diagnostics ----------------------------------------------------------------------------------
    def _on_set_parameters(self, parameters: list) -> SetParametersResult:
        for p in parameters:
            if p.name == "missing_action" and p.value not in MISSING_ACTION_RULES:
                return SetParametersResult(successful=False,
                                           reason=f"missing_action must be one of {MISSING_ACTION_RULES}")
            if p.name == "marker_robot" and p.value and p.value not in self.names:
                return SetParametersResult(successful=False, reason=f"marker_robot must be one of {self.names}")
        for p in parameters:
            if p.name == "missing_action":
                self.missing_action = self.session.missing_action = p.value
            elif p.name == "marker_robot":
                self.marker_robot = p.value
                self.session.missed_for = self.names.index(p.value) if p.value else None
            elif p.name == "publish_markers":
                self.publish_markers = bool(p.value)
            elif p.name == "auto_reset":
                self.auto_reset = bool(p.value)
            elif p.name == "real_time_factor" and float(p.value) != self.real_time_factor:
                # Change the period in place: re-creating the timer restarted its period, so setting the factor
                # faster than one vision period (even to the same value) starved the simulation.
                self.real_time_factor = float(p.value)
                if self.vision_timer is not None:
                    self._retime_vision_timer()
        return SetParametersResult(successful=True)

    def _retime_vision_timer(self) -> None:
        """The new period applies from the next frame on, which keeps its phase (the timer is not restarted); only
        if that frame is further away than one new period is it brought forward to one new period from now."""
        period_ns = self._vision_period_ns()
        self.vision_timer.timer_period_ns = period_ns
        if self.vision_timer.time_until_next_call() > period_ns:
            self.vision_timer.reset()

    def _vision_period_ns(self) -> int:
        return round(self.config.rates.vision_period_ticks * self._tick_s / self.real_time_factor * 1e9)

    def _vision_timer(self):
        """Realtime mode: one frame per vision period of sim time, on the wall clock scaled by the factor."""
        return self.create_timer(self._vision_period_ns() * 1e-9, self._realtime_tick, clock=self.wall)

    def _now_ns(self) -> int:
        """Sim time now (the stamp of the frame at the world's tick), ns."""
        return stamp_ns(cv.sim_time(self._tick_offset + self.session.world.tick, self._tick_s))

    def destroy_node(self) -> None:
        inbox = getattr(self, "action_inbox", None)
        if inbox is not None:
            inbox.close()
        live_view = getattr(self, "live_view", None)
        if live_view is not None:
            live_view.stop()
        if getattr(self, "robot_io", None) is not None:
            self.robot_io.close()
        super().destroy_node()

    def diagnostics(self) -> dict[str, str]:
        """Achieved rates over the last diagnostics window and action counts, as strings (DiagnosticStatus)."""
        now = time.monotonic()
        sim_now = self.session.world.tick * self._tick_s
        self._window.append((now, sim_now, self.frames_published))
        (t0, s0, f0), (t1, s1, f1) = self._window[0], self._window[-1]
        wall = max(t1 - t0, 1e-9)
        overall = self.periods_run * self.config.period_seconds / max(now - self._started_wall, 1e-9)
        # From the first period to the last: the loop itself, without start-up and discovery.
        running = (self.periods_run - 1) * self.config.period_seconds / max(
            self._last_period_wall - self._first_period_wall, 1e-9) if self.periods_run > 1 else 0.0
        values = {"mode": self.mode, "episode": str(self.session.episode_id), "period": str(self.session.period),
                  "real_time_factor_since_start": f"{overall:.2f}",
                  "real_time_factor_running": f"{running:.2f}",
                  "sim_time_s": f"{sim_now:.2f}", "real_time_factor": f"{(s1 - s0) / wall:.2f}",
                  "vision_frames_per_s": f"{(f1 - f0) / wall:.1f}", "periods_run": str(self.periods_run)}
        counts: Counter[str] = self.session.counts
        rejected = ("malformed", "out_of_range", "unknown_robot", "wrong_episode", "late", "early", "duplicate",
                    "mac_missing", "mac_invalid", "replayed")
        values["action_authentication"] = "off" if self.secrets is None else "on"
        values["frame_authentication"] = "off" if self.frames_secret is None else "on"
        values["runtime_controls"] = "on" if self.runtime_controls else "off"
        for key in ("accepted", "missing", "ignored_after_episode_end", "publish_failed") + tuple(
                f"rejected_{r}" for r in rejected):
            values[key] = str(counts.get(key, 0))
        if self.recorder_error:
            values["recorder_error"] = self.recorder_error
        values.update(self.robot_io.diagnostics())
        return values

    def _on_recorder_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            for value in status.values:
                if value.key.startswith(topics.MATCHED_PREFIX) and value.value.isdigit():
                    self.recorder_matched[value.key[len(topics.MATCHED_PREFIX):]] = int(value.value)
        errors = [s.message or "error" for s in msg.status if s.level == DiagnosticStatus.ERROR]
        error = "; ".join(errors)
        if error and error != self.recorder_error:
            self.get_logger().error(f"recorder: {error}")
        elif not error and self.recorder_error:
            self.get_logger().info("recorder: recording again")
        self.recorder_error = error

    def _publish_diagnostics(self) -> None:
        values = self.diagnostics()
        problems = sum(int(v) for k, v in values.items() if k.startswith("rejected_"))
        if self.recorder_error:
            level, message = DiagnosticStatus.ERROR, f"recorder: {self.recorder_error}"
        elif problems:
            level, message = DiagnosticStatus.WARN, f"{problems} actions rejected"
        else:
            level, message = DiagnosticStatus.OK, "ok"
        status = DiagnosticStatus(level=level, name="dynenv_sim", message=message, hardware_id="simulation",
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(msg)
        self._diagnostics_sent += 1
        if self._refused_since_log:
            summary = ", ".join(f"{n} {k}" for k, n in sorted(self._refused_since_log.items()))
            self.get_logger().warning(f"actions refused since the last report: {summary}; last: "
                                      f"{self._last_refusal}")
            self._refused_since_log.clear()
        line = " ".join(f"{k}={v}" for k, v in values.items() if v not in ("0", "0.00"))
        if problems or self._diagnostics_sent % 10 == 1:     # the log gets one line in ten, or any trouble
            self.get_logger().info(line)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(SimNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
