"""The learned policy as a ROS 2 node (``ros2 run dynenv_ros policy_node``): detections in, one action per robot
per motion period out.

For each controlled robot (all, or one team — so two policies can play each other) it collects the vision frames
of the newest motion period, and once every controlled robot has a complete one it runs the network for all of
them in one batch, keeps each robot's recurrent state and publishes each robot's action for the next period.
State resets at episode boundaries. Weights come from a policy file (safetensors, no pickle: ``agent.checkpoint``)
or an ONNX file, at start or through the LoadPolicy service; either way the policy is checked first
(``agent.export.check_policy``: bounded sizes, finite weights, a trial decision on the last frames received giving
actions the simulator accepts) and a failing one is refused with the reason — at start a one-line error and exit
status 2, at run time a refusal that keeps the current policy. Swaps happen between two decisions. A trainer's
weights are taken only when signed by a key in ``trusted_weights_keys`` and newer than those acting: announced on
``/trainer/weights_announcement``, fetched in chunks without blocking decisions and checked against the signed
SHA-256 (``ros.weights_follower``; docs/ros_graph.md, "Who may change the weights").

Operator services (issue 43; docs/ros_graph.md, "Who may command a node"): ``~/load_policy`` and
``~/accept_older_weights`` change what the robot does, so they exist only when the node is given
``trusted_operator_keys``, and obey only a request an operator signed for this node (``ros.operator_gate``: the
request's fields, this node's name, a fresh stamp and an unused nonce); anything else is refused with the reason,
counted in ``~/diagnostics``. A file LoadPolicy names must carry a trusted detached signature (``FILE.sig``) unless
the node was started with ``allow_unsigned_files``; the bytes checked are the bytes loaded (read once).

Driving (``scenario:=driving``): the node acts for cars ``car_0`` … ``car_<n_cars-1>`` with a driving policy
(``DynEnvAgent(scenario='driving')``, a .safetensors or .onnx file): each car's one frame per period is packed into
driving's padded layout (``driving_layout_spec``), and the action goes out in Action's driving fields (throttle, brake,
steering; a discrete choice as the command ``driving.cars.discrete_action`` makes it, what the simulator's discrete
mode accepts); a car whose decision failed brakes. ``action_mode`` must be the simulator's, and the policy's: a
policy of the other scenario or action mode is refused with the reason (``agent.export.check_scenario``).

Self-localization (robocup): a policy that takes the pose estimate (``uses_pose``: a torch model's attribute, an
ONNX file's input ``pose_estimate``) makes the node subscribe to every robot's ``<robot>/pose_estimate``
(geometry_msgs/PoseWithCovarianceStamped, frame ``map``: the simulator's, or a real robot's localization) and put
each robot's newest estimate at or before its period's last frame into the batch as ``pose_estimate`` (B, 7)
(``envs/pose_features.py``, the robot's team frame); none, or one older than ``pose_max_age``, is "lost" (zeros, the
standard deviations at the bound; counted), and a malformed one is refused with the reason (counted, logged).

Real time degrades gracefully (docs/deploy.md, "Slow policies"): the detection subscriptions keep the last
``DETECTION_DEPTH`` messages per robot (bounded), and before each decision the node takes every frame already
waiting, so it always acts on the newest complete period; older ones are dropped and counted, and the counts go to
``~/diagnostics`` and, periodically, the log.

A real camera drops and delays frames (docs/deploy.md, "A real camera's timing"): with ``decision_deadline`` ≥ 0
the node does not wait for a complete period forever — it acts on what has arrived once the period's last frame is
``decision_deadline`` seconds overdue on its clock, or a newer period's frame arrives, with each missing frame an
empty one (``partial_periods``); by default (−2) 0.05 s on the wall clock, off on sim time (a stepped game).

``interfaces:=ros_sports`` (issue 41, ``ros.ros_sports_policy``): a team stack's soccer_vision_3d_msgs, RCGCD15 and
joint states in instead of DetectionArrays; a walk twist, kick request and head command out beside each Action.
"""
from __future__ import annotations

import hashlib
import json
import math
import statistics
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dynenv_msgs.msg import Action, DetectionArray
from dynenv_msgs.srv import LoadPolicy
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dynenv_ros.envs.detection_messages import frame_problem, pack_messages
from dynenv_ros.envs.pose_features import POSE_KEY
from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import action_tagger
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.frame_tags import FrameReceiver, frames_secret
from dynenv_ros.ros.node_runner import NodeExit, run_node
from dynenv_ros.ros.runtime_controls import declare_runtime_controls, lock_when_off
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.pose_estimates import (HISTORY_DEPTH, LOST_ROW, PoseHistory, declare_pose_input, pose_batch,
                                           pose_problem, stamp_ns)
from dynenv_ros.ros.qos import action_stream
from dynenv_ros.ros.tf import base_frame
from dynenv_ros.soccer.config import MotionConfig, SoccerConfig, robot_names
from dynenv_ros.agent import driving_actions
from dynenv_ros.agent.checkpoint import (MAX_POLICY_BYTES, agent_config, check_agent_config, check_file_size,
                                         load_policy, policy_from_bytes, sha256)
from dynenv_ros.agent.export import (MAX_FRAMES, TorchPolicy, behaviour_log_probs, check_driving_policy,
                                     check_policy, check_scenario, sample_actions)
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.driving.config import MAX_CARS, DrivingConfig, car_names
from dynenv_ros.envs.driving_observations import driving_layout_spec
from dynenv_ros.envs.padded_layout import SOCCER
from dynenv_ros.ros.dds_profiles import use_bounded_profiles
from dynenv_ros.ros.operator_gate import OperatorGate
from dynenv_ros.ros.weights_follower import WeightsFollower
from dynenv_ros.security.frame_auth import detection_array_bytes
from dynenv_ros.security.keys import KeyFileError, load_trusted_keys
from dynenv_ros.security.operator_requests import signature_path, verify_file
from dynenv_ros.security.weights_signing import Refused
from dynenv_ros.security.weights_order import ReleaseOrder
from dynenv_ros.security.weights_signing import Announcement
from dynenv_ros.ros.ros_sports_policy import ros_sports_io
from policy_node.partial_periods import AUTO_DEADLINE, FrameInterval, due_ns, fill, resolve_deadline
from policy_node.periods import PeriodMemory, close_period, file_frame, period_problem

RUNTIMES = ("torch", "onnxruntime")


def runtime_of(path: str) -> str:
    """The runtime a policy file needs: an .onnx file runs in onnxruntime, anything else (safetensors) in torch."""
    return "onnxruntime" if path.lower().endswith(".onnx") else "torch"
# The simulator refuses a head turn beyond this per period (docs/ros_graph.md): a policy must stay inside it.
HEAD_BOUND = MotionConfig().head_max_delta
DEFAULT_FRAMES = SoccerConfig().rates.frames_per_period      # the trial's frame count before any frame arrived
# Keep-last depth of each robot's detection subscription: two periods of the largest frame count accepted. Stepped
# mode publishes at most one period per robot and then waits for the actions — except at an episode's end, when
# the last period and the next episode's first follow each other — so nothing a stepped game needs is ever
# lost; in real time the queue is bounded whatever the policy's speed (a slow one finds at most this many frames,
# takes them all and acts on the newest complete period).
DETECTION_DEPTH = 2 * MAX_FRAMES
STAND_STILL = (0, 0, 0, 0.0)       # the fallback action of a robot whose decision failed or was not finite
BRAKE = driving_actions.BRAKE_COMMAND  # driving's: [throttle, brake, steering] (also the previous action at reset)
SCENARIOS = ("robocup", "driving")
DEADLINE_TICK_S = 0.01             # how often (node clock) overdue periods are looked for: the deadline's resolution


def pose_qos() -> QoSProfile:
    """Reliable, keep-last ``HISTORY_DEPTH``: matches the simulator's writers and reliable localization stacks
    (AMCL's, robot_localization's); a best-effort publisher does not match it (docs/deploy.md)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=HISTORY_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def uses_pose(policy: Any) -> bool:
    """Whether a policy takes the ``pose_estimate`` input: its torch model's ``uses_pose`` (absent, so False, in
    older checkpoints), or an ONNX file's input of that name."""
    own = getattr(policy, "uses_pose", None)        # TorchPolicy / OnnxPolicy say it themselves
    if isinstance(own, bool):
        return own
    model = getattr(policy, "model", None)
    if model is not None:
        return bool(getattr(model, "uses_pose", False))
    session = getattr(policy, "session", None)
    if session is not None:
        return any(i.name == POSE_KEY for i in session.get_inputs())
    return False


def detection_qos() -> QoSProfile:
    """Reliable (matches the simulator's writers), keep-last ``DETECTION_DEPTH``: bounded, lossless when stepped."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DETECTION_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


class RobotMemory(PeriodMemory):
    """What the node keeps per robot between periods: its frames (``periods.PeriodMemory``) and more."""

    def __init__(self, idle: tuple = STAND_STILL) -> None:
        super().__init__()
        self.idle = idle
        self.addressed: int | None = None              # the period its last action was sent for
        self.last: list[DetectionArray] | None = None  # its frames (the trial decision of a new policy)
        self.state: tuple | None = None
        self.previous = idle                           # soccer: [walk, turn, kick, head]; driving: the command


class PolicyNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("policy_node", **node_options)
        self.scenario = declare_str(self, "scenario", "robocup", "Which game: robocup (soccer robots) or driving "
                                    "(cars); the policy must be of the same scenario.", choices=SCENARIOS,
                                    read_only=True)
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team in the game (robocup).",
                              read_only=True)
        team = declare_str(self, "team", "", "Control team 'a', team 'b', or both ('') (robocup).", read_only=True,
                           choices=("", "a", "b"))
        n_cars = declare_int(self, "n_cars", 2, 1, MAX_CARS, "Cars in the game (driving).", read_only=True)
        cars = declare_str_list(self, "cars", [], "Cars to drive (car_0, …; driving); empty: all n_cars — the "
                                "others may be driven by other nodes, e.g. scripted_driver.", read_only=True)
        self.action_mode = declare_str(self, "action_mode", "discrete", "The simulator's action_mode (driving): the "
                                       "policy's must be the same.", choices=("discrete", "continuous"),
                                       read_only=True)
        self.driving = self.scenario == "driving"
        if self.driving and team:
            raise ParameterException("team applies to robocup; a driving node picks its cars with cars", ["team"])
        driving_config = DrivingConfig(n_cars=n_cars, action_mode=self.action_mode)
        self.spec = driving_layout_spec(driving_config) if self.driving else SOCCER
        self.max_yaw_rate = driving_config.cars.max_yaw_rate
        self.idle = BRAKE if self.driving else STAND_STILL
        runtime = declare_str(self, "runtime", "", "Inference runtime; empty: the checkpoint's (.onnx: onnxruntime, "
                              "else torch).", choices=("", *RUNTIMES), read_only=True)
        checkpoint = declare_str(self, "checkpoint", "", "Weights: a .safetensors policy file (torch) or .onnx "
                                 "file; empty: untrained weights from 'seed' (smoke tests only).", read_only=True)
        self.seed = declare_int(self, "seed", 0, 0, 2**31 - 1, "Seed of action sampling (and untrained weights).",
                                read_only=True)
        self.greedy = declare_bool(self, "greedy", False, "Take the most likely action instead of sampling.")
        diagnostics_s = declare_float(self, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.",
                                      read_only=True)
        weights_topic = declare_str(self, "weights_topic", topics.WEIGHTS_ANNOUNCEMENT, "A trainer's signed "
                                    "WeightsAnnouncements; the weights are fetched, checked and swapped in between "
                                    "two decisions (torch runtime); empty: never.", read_only=True)
        weights_service = declare_str(self, "weights_service", topics.FETCH_WEIGHTS, "The trainer's FetchWeights "
                                      "service the announced weights are fetched from.", read_only=True)
        trusted_keys = declare_str_list(self, "trusted_weights_keys", [], "Ed25519 public keys (.pub files, or "
                                        "directories of them) whose signed weights are taken; none: a trainer's "
                                        "weights are refused.", read_only=True)
        max_weights = declare_int(self, "max_weights_bytes", MAX_POLICY_BYTES, 1, MAX_POLICY_BYTES, "Largest "
                                  "announced policy file fetched, bytes (refused before any byte travels).",
                                  read_only=True)
        weights_state = declare_str(self, "weights_state_file", "", "JSON file keeping the last accepted release "
                                    "(run, version, stamp) across restarts, so a replay stays refused; empty: "
                                    "kept in memory only.", read_only=True)
        operator_keys = declare_str_list(self, "trusted_operator_keys", [], "Ed25519 public keys (.pub files, or "
                                         "directories of them) of the operators whose signed requests "
                                         "~/load_policy and ~/accept_older_weights obey (dynenv-keys operator); "
                                         "none: those services are off.", read_only=True)
        self.allow_unsigned_files = declare_bool(self, "allow_unsigned_files", False, "Let ~/load_policy load a "
                                                 "file without a trusted detached signature beside it (FILE.sig, "
                                                 "dynenv-keys sign-file); the request itself must still be "
                                                 "signed.", read_only=True)
        # use_sim_time (rclpy's own) and greedy are settable: fixed with runtime_controls false (ros/runtime_controls.py)
        self.runtime_controls = declare_runtime_controls(self, "greedy, use_sim_time")
        self.weights_run = declare_str(self, "weights_run_id", "", "Take weights from this trainer run only "
                                       "(WeightsAnnouncement.run_id); empty: any run.", read_only=True)
        self.pose_max_age, self.pose_frame = declare_pose_input(self, "Robocup, a policy that takes the pose "
                                                                "estimate")
        deadline = declare_float(self, "decision_deadline", AUTO_DEADLINE, AUTO_DEADLINE, 60.0, "Seconds (node "
                                 "clock) after a period's last frame is due by which the node acts on the frames "
                                 "that arrived, missing ones empty; a newer period's frame closes it too. -1: wait "
                                 "for complete periods; -2 (default): 0.05 on the wall clock, -1 on sim time.",
                                 read_only=True)
        deadline = resolve_deadline(deadline, bool(self.get_parameter("use_sim_time").value))
        self.deadline_ns = round(deadline * 1e9) if deadline >= 0 else None
        self.frame_interval = FrameInterval()       # learnt from the stamps (partial_periods)
        everyone = car_names(n_cars) if self.driving else robot_names(players)
        unknown = [c for c in cars if c not in everyone] if self.driving else []
        if cars and not self.driving:
            raise ParameterException("cars is a driving parameter (robocup picks robots with team)", ["cars"])
        if unknown:
            raise ParameterException(f"unknown cars {unknown}; cars are {everyone}", ["cars"])
        self.names = [name for name in everyone if (not team or name[5] == team) and (not cars or name in cars)]
        self.ids = {name: everyone.index(name) for name in self.names}
        self.tag_action = action_tagger(self, self.names)    # secrets_dir: team secrets, Action.mac (issue 27)
        # Authenticated frames (issue 43, the train graph): a frame counts once its tag under frames.secret came.
        secret = frames_secret(self, self.get_parameter("secrets_dir").value, "Act only on frames whose tag "
                               "verifies")
        self.memory = {name: RobotMemory(self.idle) for name in self.names}
        self.teams = {name: 1 if name.startswith("team_a") else -1 for name in self.names}   # robocup's team signs
        self.pose_histories = {name: PoseHistory() for name in self.names}
        self.pose_subs: dict[str, Any] = {}          # created when a policy takes the pose estimate
        self.pose_refusal = ""                       # the last refused estimate and why
        self.graph_frames: int | None = None           # frames per period of the detections arriving
        self.counts: Counter[str] = Counter()
        self.latencies_ms: list[float] = []
        self.actions_sent = 0
        self.dropped_detections = 0          # rows beyond the maxima, farthest first
        # Version of the weights acting (Action.policy_version): a trainer's announced version, else 1 + the
        # update count a trained policy file records (1 if it records none); 0 for the untrained smoke-test
        # weights, which no trainer should learn from (docs/interfaces.md).
        self.policy_version = 0
        self.weights_refusal = ""
        self.weights_acting: tuple[str, int] | None = None     # (run_id, version) of the trainer's weights acting
        self.runtime_name = runtime or runtime_of(checkpoint)
        try:
            if checkpoint:
                self.policy, self.checkpoint_sha256, self.policy_version = self._load(checkpoint, self.runtime_name)
            else:
                torch.manual_seed(self.seed)
                policy = TorchPolicy(DynEnvAgent(scenario="driving", action_mode=self.action_mode) if self.driving
                                     else DynEnvAgent())
                self._validate(policy)
                self.policy, self.checkpoint_sha256 = policy, ""
                self.get_logger().warning("no checkpoint: acting with untrained weights")
        except ValueError as error:
            raise ParameterException(str(error), ["checkpoint"]) from None
        self.ros_sports = ros_sports_io(self, self.names, self.ids, self._receiver)   # interfaces:=ros_sports
        self.action_pubs = {n: self.create_publisher(Action, topics.local(topics.action(n)), action_stream())
                            for n in self.names}
        self.detection_subs = {} if self.ros_sports else {
            n: self.create_subscription(DetectionArray, topics.local(topics.detections(n)), self._receiver(n),
                                        detection_qos()) for n in self.names}
        self.frame_gate = FrameReceiver(self, secret) if secret is not None else None
        if self.frame_gate is not None:
            for sub in self.detection_subs.values():
                self.frame_gate.subscribe(sub.topic_name, detection_qos(), self._release)
        self._subscribe_poses()
        self.operator = self._operator_gate(operator_keys)
        self.load_srv = (self.create_service(LoadPolicy, "~/load_policy", self._on_load) if self.operator
                         else None)
        self.weights = (self._follow_weights(weights_topic, weights_service, trusted_keys, max_weights,
                                             weights_state, diagnostics_s) if weights_topic else None)
        self.diagnostics_pub = Diagnostics(self, "~/diagnostics")     # and /diagnostics
        self._diagnostics_sent = 0
        self._reported: Counter[str] = Counter()
        self._window_latencies: list[float] = []
        self.diagnostics_timer = self.create_timer(diagnostics_s, self._publish_diagnostics,
                                                   clock=Clock(clock_type=ClockType.STEADY_TIME))
        # On the node's clock (ROS time: sim time where use_sim_time is set), like the frames' arrival it measures.
        self.deadline_timer = (self.create_timer(DEADLINE_TICK_S, self._on_deadline_tick)
                               if self.deadline_ns is not None else None)
        self.get_logger().info(f"controlling {', '.join(self.names)} with {self.runtime_name}"
                               f"{'; the policy takes the pose estimates' if self.pose_wanted else ''}")
        # last: the lock refuses every parameter set from now on, declarations included
        lock_when_off(self, self.runtime_controls, "greedy and use_sim_time stay as started")

    # -- weights ---------------------------------------------------------------------------------------------------
    def _operator_gate(self, key_paths: list[str]) -> OperatorGate | None:
        """The gate of the operator services, or None (they are off) without trusted operator keys: said once."""
        try:
            trusted = load_trusted_keys(key_paths)
        except KeyFileError as error:
            raise ParameterException(str(error), ["trusted_operator_keys"]) from None
        if not trusted:
            self.get_logger().info("no trusted_operator_keys: ~/load_policy and ~/accept_older_weights are off "
                                   "(give the operators' public keys to turn them on, e.g. -p "
                                   "trusted_operator_keys:=[~/.config/dynenv_ros/keys/operator.pub])")
            return None
        self.get_logger().info(f"~/load_policy and ~/accept_older_weights obey requests signed by "
                               f"{', '.join(sorted(trusted))}; files "
                               f"{'need no signature (allow_unsigned_files)' if self.allow_unsigned_files else 'need a trusted FILE.sig'}")
        return OperatorGate(self, trusted, self.counts)

    def _load(self, path: str, runtime: str, data: bytes | None = None):
        """(policy, sha256, version) of a file that passed every check; ValueError with a one-line reason
        otherwise. ``data``: the file's bytes already read (and their signature checked): nothing is read again."""
        if runtime not in RUNTIMES:
            raise ValueError(f"runtime must be one of {RUNTIMES}, got {runtime!r}")
        suffix = path.lower().rsplit(".", 1)[-1] if "." in path else ""
        if runtime == "torch" and suffix == "onnx":
            raise ValueError(f"{path} is an ONNX file: load it with runtime onnxruntime (the torch runtime loads "
                             f".safetensors policy files)")
        if runtime == "onnxruntime" and suffix in ("safetensors", "pt", "pth"):
            raise ValueError(f"{path} is a torch policy file: load it with runtime torch, or export it to ONNX "
                             f"(dynenv_ros.agent.export.export_onnx)")
        try:
            version = 1
            if runtime == "torch":
                agent, meta = load_policy(path) if data is None else policy_from_bytes(data, f"policy file {path}")
                policy, version = TorchPolicy(agent), version_of(meta)
            else:
                from dynenv_ros.agent.export import OnnxPolicy
                policy = OnnxPolicy(path, data=data)
            self._validate(policy)
            digest = sha256(path) if data is None else hashlib.sha256(data).hexdigest()
        except ValueError as error:
            raise ValueError(_one_line(error)) from None
        except Exception as error:           # anything else a hostile or broken file provokes: refused, not fatal
            raise ValueError(f"cannot load {path}: {type(error).__name__}: {_one_line(error)}") from None
        return policy, digest, version

    def _validate(self, policy) -> None:
        """``check_policy`` on the last frames each robot acted on (a synthetic period with no detections where
        there are none yet), with the frame count the graph sends once known."""
        try:
            check_scenario(policy, self.scenario, self.action_mode if self.driving else None)
            if self.driving:
                check_driving_policy(policy, self._trial_inputs(policy), self.max_yaw_rate, self.graph_frames)
            else:
                check_policy(policy, self._trial_inputs(policy), HEAD_BOUND, self.graph_frames)
        except ValueError as error:
            raise ValueError(f"policy refused: {_one_line(error)}") from None

    def _trial_inputs(self, policy):
        frames = self.graph_frames or getattr(policy, "frames", None) or (1 if self.driving else DEFAULT_FRAMES)
        periods = [m.last if m.last is not None and len(m.last) == frames else _empty_period(frames)
                   for m in self.memory.values()]
        recorded = sum(m.last is not None and len(m.last) == frames for m in self.memory.values())
        self._trial_note = (f"the last frames of {recorded} robot{'s' * (recorded != 1)}" if recorded
                            else f"an empty period of {frames} frames (no frames received yet)")
        observation, _ = pack_messages(periods, [m.previous for m in self.memory.values()],
                                       getattr(policy, "max_landmarks", None), getattr(policy, "max_objects", None),
                                       spec=self.spec)
        if self.driving:
            return (*streams_from_padded(observation, self.spec), *side_inputs(observation, spec=self.spec))
        head_max = float(policy.head_max)
        if not math.isfinite(head_max) or head_max <= 0:
            head_max = 1.0            # check_policy refuses it with the reason; the trial inputs must stay finite
        if uses_pose(policy):         # the trial runs as a robot that has lost its pose
            observation[POSE_KEY] = np.tile(LOST_ROW, (len(periods), 1))
        return (*streams_from_padded(observation), *self._side_inputs(observation, head_max, uses_pose(policy)))

    def _on_load(self, request: LoadPolicy.Request, response: LoadPolicy.Response):
        """Only an operator's signed request, and (unless ``allow_unsigned_files``) a file with a trusted
        detached signature; the bytes verified are the bytes loaded."""
        refused, data = self.operator.refusal("load_policy", request), None
        if refused is None and not self.allow_unsigned_files:
            refused, data = self._signed_file(request.checkpoint_path)
        if refused is not None:
            response.success, response.reason = False, refused[0]
            response.message = f"kept the current policy: refused ({refused[0]}): {refused[1]}"
            return response
        runtime = request.runtime or runtime_of(request.checkpoint_path)
        try:
            policy, digest, version = self._load(request.checkpoint_path, runtime, data)
        except ValueError as error:
            response.success, response.reason = False, "load_failed"
            response.message = f"kept the current policy: {error}"
            self.get_logger().warning(f"LoadPolicy {request.checkpoint_path!r}: {response.message}")
            return response
        self._swap(policy, digest, version)
        self.runtime_name, self.weights_acting = runtime, None
        response.success, response.checkpoint_sha256 = True, digest
        response.message = f"loaded ({runtime}); its trial decision on {self._trial_note} passed"
        self.get_logger().info(f"loaded {request.checkpoint_path} ({runtime}, sha256 {digest[:12]})")
        return response

    def _signed_file(self, path: str) -> tuple[tuple[str, str] | None, bytes | None]:
        """(None, the file's bytes) when they carry a trusted operator's detached signature — read once, bounded,
        and loaded from memory, so the file cannot change between check and load; else ((reason, text), None), a
        signature problem counted as an operator refusal."""
        try:
            file = Path(path)
            check_file_size(file, "policy file")
            with file.open("rb") as handle:
                data = handle.read(MAX_POLICY_BYTES + 1)
            verify_file(data, signature_path(file), self.operator.verifier.trusted)
        except Refused as refused:
            return self.operator.refuse("load_policy", refused.reason, f"{path}: {refused}"), None
        except (OSError, ValueError) as error:
            self.get_logger().warning(f"LoadPolicy {path!r}: {_one_line(error)}")
            return ("load_failed", _one_line(error)), None
        return None, data

    def _swap(self, policy, digest: str, version: int) -> None:
        """Callbacks run one at a time: the swap happens between two decisions. The recurrent states carry over
        when they fit the new network; a network of another size starts from fresh states."""
        if policy.feature_size != self.policy.feature_size:
            for memory in self.memory.values():
                memory.state = None
        self.policy, self.checkpoint_sha256, self.policy_version = policy, digest, version
        self._subscribe_poses()

    def _follow_weights(self, topic: str, service: str, key_paths: list[str], max_bytes: int, state_file: str,
                        report_s: float) -> WeightsFollower:
        """Signed weights from a trainer (``ros.weights_follower``): only releases a trusted key signed, newer than
        the one acting, fitting this node, fetched without blocking decisions."""
        try:
            trusted = load_trusted_keys(key_paths)
        except KeyFileError as error:
            raise ParameterException(str(error), ["trusted_weights_keys"]) from None
        try:
            order = ReleaseOrder(state_file or None)
        except ValueError as error:
            raise ParameterException(str(error), ["weights_state_file"]) from None
        if trusted:       # the first shape check on torch's meta device imports ~70 MB of torch (2-3 s): now, not
            with torch.device("meta"):          # as a stall of the decisions when the first weights arrive
                DynEnvAgent(feature_size=1)
        return WeightsFollower(self, topic=topic, service=service, accept_service="~/accept_older_weights",
                               trusted=trusted, max_bytes=max_bytes, order=order, fits=self._announced_network,
                               install=self._install_weights, counts=self.counts, operator=self.operator,
                               note=lambda text: setattr(self, "weights_refusal", text), run_filter=self.weights_run,
                               report_period_s=report_s)

    def _announced_network(self, metadata_json: str) -> None:
        """ValueError unless an announced network (its signed metadata: the policy file's config) can play here:
        checked before the weights are fetched."""
        if self.runtime_name != "torch":
            raise ValueError(f"weights need the torch runtime; this node runs {self.runtime_name}")
        try:
            meta = json.loads(metadata_json)
            config = check_agent_config(meta["config"])
        except (ValueError, KeyError, TypeError) as error:
            raise ValueError(f"metadata_json does not describe a network: {_one_line(error)}") from None
        scenario, mine = config.get("scenario", "soccer"), "driving" if self.driving else "soccer"
        if scenario != mine:
            raise ValueError(f"it is a {scenario} policy and this node plays {mine}")
        if self.driving and config.get("action_mode") != self.action_mode:
            raise ValueError(f"it is a {config.get('action_mode')} driving policy and the simulator's action_mode "
                             f"is {self.action_mode}")

    def _install_weights(self, data: bytes, announcement: Announcement) -> str:
        """Swap in fetched weights whose bytes matched the signed SHA-256, after the checks a policy file gets and
        the check that they are the network announced; ValueError with the reason otherwise (the current weights
        keep playing). Returns the file's SHA-256."""
        try:
            agent, _ = policy_from_bytes(data, "weights")
            policy = TorchPolicy(agent)
        except ValueError as error:
            raise ValueError(_one_line(error)) from None
        except Exception as error:           # anything else hostile bytes provoke: refused, not fatal
            raise ValueError(f"{type(error).__name__}: {_one_line(error)}") from None
        if agent_config(agent) != json.loads(announcement.metadata_json)["config"]:
            raise ValueError(f"the file's network {agent_config(agent)} is not the one announced")
        self._validate(policy)
        self._swap(policy, announcement.sha256, int(announcement.version))
        self.weights_acting = (announcement.run_id, int(announcement.version))
        return announcement.sha256

    # -- pose estimates --------------------------------------------------------------------------------------------
    def _subscribe_poses(self) -> None:
        """Subscribe to every robot's ``<robot>/pose_estimate`` once a policy takes the pose (kept afterwards)."""
        self.pose_wanted = not self.driving and uses_pose(self.policy)
        if self.pose_wanted and not self.pose_subs:
            self.pose_subs = {n: self.create_subscription(PoseWithCovarianceStamped,
                                                          topics.local(topics.pose_estimate(n)),
                                                          self._pose_receiver(n), pose_qos()) for n in self.names}

    def _pose_receiver(self, name: str):
        return lambda msg: self.store_pose(name, msg)

    def store_pose(self, name: str, msg: PoseWithCovarianceStamped) -> bool:
        """File one robot's estimate, or refuse it (counted in ``pose_malformed``, logged with the reason)."""
        problem = pose_problem(msg, self.pose_frame)
        if problem:
            self.counts["pose_malformed"] += 1
            self.pose_refusal = f"{name}: {problem}"
            self.get_logger().warning(f"{topics.pose_estimate(name)}: estimate refused: {problem}",
                                      throttle_duration_sec=5.0)
            return False
        self.pose_histories[name].add(msg)
        return True

    def pose_rows(self, periods: list[list[DetectionArray]]) -> np.ndarray:
        """(B, 7) float32 ``pose_estimate`` of the robots (``self.names`` order) for their periods: each robot's
        newest estimate at or before its period's last frame, in its team's frame; ``LOST_ROW`` (zeros, the
        standard deviations at the bound) without one, or when it is older than ``pose_max_age`` (counted:
        pose_used, pose_missing, pose_stale). Takes every estimate already waiting first."""
        for name, sub in self.pose_subs.items():
            for msg in _waiting(sub, HISTORY_DEPTH):
                self.store_pose(name, msg)
        return pose_batch([self.pose_histories[n] for n in self.names],
                          [stamp_ns(p[-1].header.stamp) for p in periods], [self.teams[n] for n in self.names],
                          round(self.pose_max_age * 1e9), self.counts)

    # -- frames ----------------------------------------------------------------------------------------------------
    def _receiver(self, name: str):
        def receive(msg: DetectionArray) -> None:
            self._admit(name, msg)
            self._drain()
            while self._decide_if_ready():     # frames taken during a decision may complete the next period
                pass
        return receive

    def _release(self, items: list[tuple[str, DetectionArray]]) -> None:
        """With authenticated frames: frames whose tag came after them are stored, and acted on, from here. Each
        names its robot (a tag binds its frame's topic, whichever companion topic it came on)."""
        for name, msg in items:
            self._store(name, msg)
        self._drain()
        while self._decide_if_ready():
            pass

    def _admit(self, name: str, msg: DetectionArray) -> None:
        """Store a frame, or with authenticated frames hand it to the gate: stored once its tag came."""
        if self.frame_gate is None:
            self._store(name, msg)
            return
        topic = self.detection_subs[name].topic_name
        try:
            data: bytes | None = detection_array_bytes(msg, topic)
        except ValueError:
            data = None
        for verified_name, verified in self.frame_gate.frame((name, msg), data, topic):
            self._store(verified_name, verified)

    def _drain(self) -> None:
        """Take every detection message already waiting (at most the queue's depth per robot), so the decision
        that follows acts on the newest complete period, not on one a slow decision left behind. Uses the
        subscription handle's take, what rclpy's executor itself calls (there is no public take in rclpy)."""
        for name, sub in self.detection_subs.items():
            for msg in _waiting(sub, DETECTION_DEPTH):
                self._admit(name, msg)

    def _store(self, name: str, msg: DetectionArray) -> None:
        """File one frame (``periods.file_frame``); a new episode resets the robot. With a decision deadline, an
        incomplete period's due time is kept (``partial_periods.due_ns``: the earliest its frames say)."""
        self.counts["frames_received"] += 1
        memory = self.memory[name]
        problem = frame_problem(msg) or period_problem(memory, msg)
        if problem:
            self.counts["frames_malformed"] += 1
            self.get_logger().warning(f"{topics.detections(name)}: frame refused: {problem}",
                                      throttle_duration_sec=5.0)
            return
        if memory.episode != msg.episode_id:                 # a new episode: forget everything
            memory.__init__(self.idle)
            memory.episode = msg.episode_id
        if self.deadline_ns is None:
            file_frame(memory, msg, self.counts)
            return
        self.frame_interval.observe(name, msg)
        interval = self.frame_interval.ns
        if file_frame(memory, msg, self.counts, self._close) and interval is not None:
            due = due_ns(self.get_clock().now().nanoseconds, msg.frame_index, msg.frames_per_period, interval)
            memory.due = due if memory.due is None else min(memory.due, due)

    def _close(self, frames: dict[int, DetectionArray]) -> list[DetectionArray]:
        """An incomplete period with its gaps filled by empty frames (``partial_periods.fill``), counted."""
        period, missing = fill(frames, next(iter(frames.values())).frames_per_period, self.frame_interval.ns,
                               _empty_like)
        self.counts["frames_missing"] += missing
        return period

    def _on_deadline_tick(self) -> None:
        """Close every robot's period whose deadline passed (after taking the frames already waiting, which may
        complete a period too), then decide on whatever is ready."""
        self._drain()
        now = self.get_clock().now().nanoseconds
        for memory in self.memory.values():
            if memory.frames and memory.due is not None and now >= memory.due + self.deadline_ns:
                close_period(memory, self.counts, self._close)
        while self._decide_if_ready():
            pass

    # -- decisions -------------------------------------------------------------------------------------------------
    def _decide_if_ready(self) -> bool:
        """Decide if every robot has a complete period; True if it did (the drain after a decision may have made
        the next one ready: nothing else would wake the node for frames already taken)."""
        memories = [self.memory[n] for n in self.names]
        if any(m.ready is None for m in memories):
            return False
        # A robot still holding the previous episode's last period while another has the new episode's first: that
        # last period's answer would be ignored, and deciding both together would leave the new episode waiting
        # for an answer never sent (a stepped game stalls). Drop the old period and wait for the new one.
        newest = max(m.ready[0].episode_id for m in memories)
        stale = [m for m in memories if m.ready[0].episode_id != newest]
        if stale:
            for m in stale:
                m.ready = None
            self.counts["periods_dropped"] += len(stale)
            return False
        periods = [m.ready for m in memories]
        frames = len(periods[0])
        if any(len(p) != frames for p in periods):
            self.get_logger().error(f"robots' periods have different frame counts {[len(p) for p in periods]}: "
                                    "dropped", throttle_duration_sec=5.0)
            for m in memories:
                m.ready = None
            self.counts["periods_dropped"] += len(memories)
            return False
        self.graph_frames = frames
        fixed = getattr(self.policy, "frames", None)
        if fixed is not None and fixed != frames:
            self.get_logger().error(f"the policy takes {fixed} vision frames per period, "
                                    f"{topics.detections(self.names[0])} has {frames}: it cannot play this graph "
                                    f"(export it with frames={frames})")
            raise NodeExit(2)
        started = time.perf_counter()
        actions, finite, step = self._run(memories, periods)
        log_probs, values = self._behaviour(step, actions, finite)
        for memory, period in zip(memories, periods):          # consumed: newer frames are no longer stale-checked
            memory.decided, memory.ready = period[-1].motion_period, None
        # Frames that arrived while deciding say which periods have started since; an action addressed to one of
        # them would be refused as late, so it goes to the next period that has not started (docs/deploy.md).
        self._drain()
        for b, (name, memory, period) in enumerate(zip(self.names, memories, periods)):
            frame = period[-1]
            same_episode = memory.episode == frame.episode_id
            started_since = max(frame.motion_period, memory.period) if same_episode else frame.motion_period
            action = tuple(actions[b]) if finite[b] else self.idle
            target = started_since + 1
            if same_episode and memory.addressed is not None and target <= memory.addressed:
                # the previous, slower decision already answered that period (first action per period wins):
                # this one only advances the recurrent state
                self.counts["actions_superseded"] += 1
            else:
                if started_since > frame.motion_period:
                    self.counts["actions_delayed"] += 1
                if self.driving:
                    msg = Action(robot_id=self.ids[name], episode_id=frame.episode_id, motion_period=target,
                                 throttle=float(action[0]), brake=float(action[1]), steering=float(action[2]))
                else:
                    msg = Action(robot_id=self.ids[name], episode_id=frame.episode_id, motion_period=target,
                                 walk=int(action[0]), turn=int(action[1]), kick=int(action[2]),
                                 head_yaw_delta=float(action[3]))
                if finite[b]:                              # the learning fields (docs/interfaces.md)
                    msg.policy_version = self.policy_version
                    msg.log_prob, msg.value = float(log_probs[b]), float(values[b])
                msg.header.stamp = frame.header.stamp          # the observation acted on (sim time in the sim)
                msg.header.frame_id = base_frame(name)
                self.tag_action(name, msg, self.action_pubs[name])
                self.action_pubs[name].publish(msg)
                if self.ros_sports is not None:        # the walk, kick and head commands beside it (issue 41)
                    self.ros_sports.command(name, msg, frame)
                self.actions_sent += 1
                if same_episode:
                    memory.addressed = target
                    memory.previous = (tuple(float(v) for v in action) if self.driving else
                                       (int(action[0]), int(action[1]), int(action[2]), float(action[3])))
            if same_episode:                                   # (a new episode's first frames reset the robot)
                memory.state = tuple(s[b:b + 1] for s in step.state) if finite[b] else None
                memory.last = period
            if not finite[b]:
                self.counts["fallback_actions"] += 1
        self.counts["decisions"] += 1
        latency = 1000 * (time.perf_counter() - started)
        self.latencies_ms.append(latency)
        self._window_latencies.append(latency)
        if len(self.latencies_ms) % 100 == 0:
            recent = self.latencies_ms[-100:]
            self.latencies_ms = self.latencies_ms[-100:]
            self.get_logger().info(f"decision latency for {len(self.names)} robots: median "
                                   f"{statistics.median(recent):.2f} ms, max {max(recent):.2f} ms")
        return True

    def _run(self, memories: list[RobotMemory], periods: list[list[DetectionArray]]):
        """(actions (B, 4), finite (B,), step) of one decision — driving: (B, 3) commands [throttle, brake,
        steering], the network's own actions (indices or normalised values) kept in ``self._network_actions`` for
        their log-probabilities; a policy that raises gives every robot the fallback (counted, logged): one bad
        decision must not stop the node or a stepped game."""
        first = periods[0][-1]
        generator = torch.Generator().manual_seed(_decision_seed(self.seed, first.episode_id, first.motion_period))
        try:
            observation = self._padded(memories, periods)
            landmarks, objects = streams_from_padded(observation, self.spec)
            if self.driving:
                previous, proprio = side_inputs(observation, spec=self.spec)
            else:
                head_max = float(self.policy.head_max)
                previous, proprio = self._side_inputs(observation, head_max, self.pose_wanted)
            states = [m.state or self.policy.initial_state(1) for m in memories]
            state = tuple(torch.cat([s[i] for s in states]) for i in range(4))
            step = self.policy(landmarks, objects, previous, proprio, state)
            if self.driving:
                chosen, finite = driving_actions.sample_actions(step, self.policy.action_mode, generator, self.greedy)
                self._network_actions = chosen
                actions = driving_actions.commands(chosen, self.policy.action_mode, self.max_yaw_rate)
            else:
                actions, finite = sample_actions(step, self.policy.head_mode, self.policy.head_units, head_max,
                                                 generator, self.greedy)
        except Exception as error:
            self.counts["failed_decisions"] += 1
            self.get_logger().error(f"decision failed, robots {'brake' if self.driving else 'stand still'}: "
                                    f"{type(error).__name__}: {_one_line(error)}", throttle_duration_sec=5.0)
            return np.zeros((len(memories), len(self.idle))), np.zeros(len(memories), bool), None
        if not finite.all():
            self.get_logger().error(f"non-finite outputs for {[n for n, f in zip(self.names, finite) if not f]}: "
                                    "they stand still", throttle_duration_sec=5.0)
        return actions, finite, step

    @staticmethod
    def _side_inputs(observation: dict[str, np.ndarray], head_max: float, pose: bool):
        """Soccer's side inputs; a policy taking the pose gets the batch's ``pose_estimate`` appended
        (``agent.inputs.side_inputs(..., pose=True)``)."""
        return side_inputs(observation, head_max, pose=True) if pose else side_inputs(observation, head_max)

    def _behaviour(self, step: Any, actions: np.ndarray, finite: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each robot's action log-probability and value estimate, for the trainer (NaN where unknown: the
        fallback action was not the policy's choice, and the learning fields stay 0)."""
        n = len(actions)
        if step is None or not finite.any():
            return np.full(n, np.nan), np.full(n, np.nan)
        if self.driving:
            log_probs = driving_actions.log_probs(step, self._network_actions, self.policy.action_mode)
        else:
            log_probs = behaviour_log_probs(step, actions, self.policy.head_mode, self.policy.head_units,
                                            float(self.policy.head_max))
        values = np.asarray(torch.as_tensor(step.value), np.float64).reshape(n)
        ok = finite & np.isfinite(log_probs) & np.isfinite(values)
        finite &= ok
        return log_probs, values

    def _padded(self, memories: list[RobotMemory], periods: list[list[DetectionArray]]) -> dict[str, np.ndarray]:
        stats: Counter[str] = Counter()
        observation, dropped = pack_messages(periods, [m.previous for m in memories],
                                             getattr(self.policy, "max_landmarks", None),
                                             getattr(self.policy, "max_objects", None), stats, self.spec)
        self.dropped_detections += dropped
        self.counts.update(stats)
        if self.pose_wanted:           # the network reads it from the batch (envs/pose_features.py)
            observation[POSE_KEY] = self.pose_rows(periods)
        return observation

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def diagnostics(self) -> dict[str, str]:
        """Counts since start and the decision latency of the last window, as strings (DiagnosticStatus)."""
        window, self._window_latencies = self._window_latencies, []
        values = {"runtime": self.runtime_name, "checkpoint_sha256": self.checkpoint_sha256[:12],
                  "policy_version": str(self.policy_version), "weights_refusal": self.weights_refusal,
                  "robots": str(len(self.names)), "actions_sent": str(self.actions_sent),
                  "detections_dropped": str(self.dropped_detections)}
        for key in ("decisions", "periods_dropped", "actions_delayed", "actions_superseded", "frames_received",
                    "frames_stale", "frames_duplicate", "periods_partial", "frames_missing", "frames_malformed",
                    "detections_malformed", "values_malformed", "self_missing", "fallback_actions",
                    "failed_decisions", "weights_loaded", "weights_refused", "weights_duplicate", "weights_other_run",
                    "pose_used", "pose_missing", "pose_stale", "pose_malformed"):
            values[key] = str(self.counts.get(key, 0))
        if self.weights is not None:                 # refusals by reason, the fetch running (ros.weights_follower)
            values.update(self.weights.diagnostics())
        values["operator_services"] = "on" if self.operator else "off"
        values["runtime_controls"] = "on" if self.runtime_controls else "off"
        if self.operator is not None:                # signed operator requests: accepted, refused by reason
            values.update(self.operator.diagnostics())
        values["frame_authentication"] = "off"
        if self.frame_gate is not None:              # frames verified, waiting for their tag, refused by reason
            values.update(self.frame_gate.diagnostics())
        if self.ros_sports is not None:
            values.update(self.ros_sports.diagnostics())
        values["pose_input"] = "yes" if self.pose_wanted else "no"
        values["pose_refusal"] = self.pose_refusal
        values["latency_median_ms"] = f"{statistics.median(window):.2f}" if window else "0.00"
        values["latency_max_ms"] = f"{max(window):.2f}" if window else "0.00"
        return values

    def _publish_diagnostics(self) -> None:
        values = self.diagnostics()
        watched = ("periods_dropped", "frames_duplicate", "frames_missing", "frames_malformed",
                   "detections_malformed", "values_malformed", "fallback_actions", "failed_decisions",
                   "weights_refused", "pose_missing", "pose_stale", "pose_malformed")
        new = {k: int(values[k]) - self._reported[k] for k in watched if int(values[k]) > self._reported[k]}
        self._reported.update(new)
        status = DiagnosticStatus(level=DiagnosticStatus.WARN if new else DiagnosticStatus.OK, name="dynenv_policy",
                                  message=", ".join(f"{v} {k}" for k, v in new.items()) if new else "ok",
                                  hardware_id=self.get_fully_qualified_name(),
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(msg)
        self._diagnostics_sent += 1
        if new or self._diagnostics_sent % 10 == 1:         # the log gets one line in ten, or any new trouble
            self.get_logger().info(" ".join(f"{k}={v}" for k, v in values.items() if v not in ("0", "0.00", "")))


def version_of(meta: dict[str, Any]) -> int:
    """A policy file's version: 1 + the updates its training recorded (``meta["updates"]``), 1 if unknown."""
    updates = meta.get("updates", 0)
    if isinstance(updates, bool) or not isinstance(updates, int) or not 0 <= updates < 2**32 - 1:
        return 1
    return updates + 1


def _one_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def _decision_seed(seed: int, episode: int, period: int) -> int:
    """A sampling seed per (node seed, episode, period): which periods a slow node drops, or whether it answers
    an episode's last period, cannot change the draws of any other decision, so stepped runs stay reproducible."""
    return int(np.random.SeedSequence([seed, episode, period]).generate_state(1, np.uint64)[0] >> 1)


def _waiting(sub: Any, limit: int):
    """The messages already waiting on ``sub``, at most ``limit``: the subscription handle's take, what rclpy's
    executor itself calls (rclpy has no public take); none on an rclpy without it (the bounded queue alone then
    limits staleness)."""
    for _ in range(limit):
        try:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
        except AttributeError:
            return
        if taken is None:
            return
        yield taken[0]


def _empty_like(like: DetectionArray, index: int, stamp_ns: int) -> DetectionArray:
    """A frame that never came: ``like``'s robot, period and own state, no detections, its slot's stamp."""
    msg = DetectionArray(robot_id=like.robot_id, episode_id=like.episode_id, motion_period=like.motion_period,
                         frame_index=index, frames_per_period=like.frames_per_period, head_yaw=like.head_yaw,
                         self_fallen=like.self_fallen, self_penalized=like.self_penalized,
                         self_kicking=like.self_kicking, ball_owner=like.ball_owner,
                         ball_owner_seconds=like.ball_owner_seconds,
                         game_seconds_remaining=like.game_seconds_remaining)
    msg.header.frame_id = like.header.frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return msg


def _empty_period(frames: int) -> list[DetectionArray]:
    return [DetectionArray(frame_index=k, frames_per_period=frames) for k in range(frames)]


def main(args: Sequence[str] | None = None) -> int:
    use_bounded_profiles()        # before rclpy.init: DDS drops oversized announcements (ros/dds_profiles.py)
    return run_node(PolicyNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
