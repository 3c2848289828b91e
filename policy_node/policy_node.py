"""The learned policy as a ROS 2 node (``ros2 run dynenv_ros policy_node``): detections in, one action per robot
per motion period out.

For each controlled robot (all, or one team — so two policies can play each other) it collects the vision frames
of the newest motion period, and once every controlled robot has a complete one it runs the network for all of
them in one batch, keeps each robot's recurrent state and publishes each robot's action for the next period.
State resets at episode boundaries. The decisions are ROS-free (``decider.Decider`` over
``batch_policy.BatchPolicy``); this module is the adapter that takes messages off ROS and publishes the actions,
with its parameters (``node_parameters``), inputs (``node_inputs``), operator services (``operator_services``), a
trainer's weights (``weights_following``) and ``~/diagnostics`` (``node_diagnostics``) in their own modules.

Weights come from a policy file (safetensors, no pickle: ``agent.checkpoint``) or an ONNX file, at start or through
the LoadPolicy service; either way the policy is checked first (``agent.export.check_policy``: bounded sizes, finite
weights, a trial decision on the last frames received giving actions the simulator accepts) and a failing one is
refused with the reason — at start a one-line error and exit status 2, at run time a refusal that keeps the current
policy. Swaps happen between two decisions.

Driving (``scenario:=driving``): the node acts for cars ``car_0`` … ``car_<n_cars-1>`` with a driving policy
(``DynEnvAgent(scenario='driving')``, a .safetensors or .onnx file): each car's one frame per period is packed into
driving's padded layout (``driving_layout_spec``), and the action goes out in Action's driving fields (throttle, brake,
steering; a discrete choice as the command ``driving.cars.discrete_action`` makes it, what the simulator's discrete
mode accepts); a car whose decision failed brakes. ``action_mode`` must be the simulator's, and the policy's: a
policy of the other scenario or action mode is refused with the reason (``agent.export.check_scenario``).

Self-localization (robocup): a policy that takes the pose estimate (``uses_pose``) makes the node subscribe to every
robot's ``<robot>/pose_estimate`` (geometry_msgs/PoseWithCovarianceStamped, frame ``map``) and put each robot's
newest estimate at or before its period's last frame into the batch as ``pose_estimate`` (``BatchPolicy.pose_rows``);
none, or one older than ``pose_max_age``, is "lost" (counted), and a malformed one is refused with the reason.

Real time degrades gracefully (docs/deploy.md, "Slow policies"): before each decision the node takes every frame
already waiting (bounded queues), so it always acts on the newest complete period; older ones are dropped and
counted. With ``decision_deadline`` ≥ 0 (docs/deploy.md, "A real camera's timing") it acts on what has arrived once
the period's last frame is that many seconds overdue on its clock, or a newer period's frame arrives, each missing
frame an empty one (``partial_periods``); by default (−2) 0.05 s on the wall clock, off on sim time (a stepped game).

``interfaces:=ros_sports`` (issue 41, ``ros.ros_sports_policy``): a team stack's soccer_vision_3d_msgs, RCGCD15 and
joint states in instead of DetectionArrays; a walk twist, kick request and head command out beside each Action.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

from dynenv_msgs.msg import Action, DetectionArray
from dynenv_msgs.srv import LoadPolicy
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import action_tagger
from dynenv_ros.ros.dds_profiles import use_bounded_profiles
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.frame_tags import FrameReceiver, frames_secret
from dynenv_ros.ros.node_runner import NodeExit, run_node
from dynenv_ros.ros.pose_estimates import HISTORY_DEPTH, pose_problem
from dynenv_ros.ros.qos import action_stream
from dynenv_ros.ros.ros_sports_policy import ros_sports_io
from dynenv_ros.ros.runtime_controls import lock_when_off
from dynenv_ros.ros.tf import base_frame
from dynenv_ros.security.frame_auth import detection_array_bytes
from policy_node import policy_files
from policy_node.batch_policy import BatchPolicy
from policy_node.decider import CannotPlay, Decider, Outgoing
from policy_node.node_diagnostics import NodeDiagnostics
from policy_node.node_inputs import DETECTION_DEPTH, detection_qos, empty_like, empty_period, pose_qos, waiting
from policy_node.node_parameters import controlled_robots, declare_parameters
from policy_node.operator_services import OperatorServices
from policy_node.policy_files import runtime_of
from policy_node.weights_following import WeightsFollowing

DEADLINE_TICK_S = 0.01             # how often (node clock) overdue periods are looked for: the deadline's resolution


class PolicyNode(OperatorServices, WeightsFollowing, NodeDiagnostics, Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("policy_node", **node_options)
        params = declare_parameters(self)
        self.scenario, self.action_mode = params.game, params.action_mode
        self.allow_unsigned_files, self.runtime_controls = params.allow_unsigned_files, params.runtime_controls
        self.weights_run, self.pose_frame = params.weights_run, params.pose_frame
        self.names, self.ids = controlled_robots(params)
        self.tag_action = action_tagger(self, self.names)    # secrets_dir: team secrets, Action.mac (issue 27)
        # Authenticated frames (issue 43, the train graph): a frame counts once its tag under frames.secret came.
        secret = frames_secret(self, self.get_parameter("secrets_dir").value, "Act only on frames whose tag "
                               "verifies")
        self.counts: Counter[str] = Counter()
        log = self.get_logger()
        self.batch = BatchPolicy(self.names, scenario=self.scenario,
                                 settings=self.scenario.game_settings(params.agent_count, self.action_mode),
                                 seed=params.seed, greedy=params.greedy,
                                 pose_max_age=params.pose_max_age, counts=self.counts, log=log,
                                 take_estimates=self._take_estimates, empty_period=empty_period)
        self.decider = Decider(self.names, self.batch, self.counts, log, params.deadline_ns,
                               lambda: self.get_clock().now().nanoseconds, empty_like)
        self.memory, self.pose_histories = self.decider.memory, self.batch.pose_histories
        self.pose_subs: dict[str, Any] = {}          # created when a policy takes the pose estimate
        self.pose_refusal = ""                       # the last refused estimate and why
        self.actions_sent = 0
        # Version of the weights acting (Action.policy_version): a trainer's announced version, else 1 + the
        # update count a trained policy file records (1 if it records none); 0 for the untrained smoke-test
        # weights, which no trainer should learn from (docs/interfaces.md).
        self.policy_version = 0
        self.weights_refusal = ""
        self.weights_acting: tuple[str, int] | None = None     # (run_id, version) of the trainer's weights acting
        self.runtime_name = params.runtime or runtime_of(params.checkpoint)
        try:
            if params.checkpoint:
                self.batch.policy, self.checkpoint_sha256, self.policy_version = self._load(params.checkpoint,
                                                                                            self.runtime_name)
            else:
                policy = policy_files.untrained(self.scenario, self.action_mode, params.seed)
                self._validate(policy)
                self.batch.policy, self.checkpoint_sha256 = policy, ""
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
        self.operator = self._operator_gate(params.operator_keys)
        self.load_srv = (self.create_service(LoadPolicy, "~/load_policy", self._on_load) if self.operator
                         else None)
        self.weights = (self._follow_weights(params.weights_topic, params.trusted_keys,
                                             params.max_weights, params.weights_state, params.diagnostics_s)
                        if params.weights_topic else None)
        self.diagnostics_pub = Diagnostics(self, "~/diagnostics")     # and /diagnostics
        self._diagnostics_sent = 0
        self._reported: Counter[str] = Counter()
        self.diagnostics_timer = self.create_timer(params.diagnostics_s, self._publish_diagnostics,
                                                   clock=Clock(clock_type=ClockType.STEADY_TIME))
        # On the node's clock (ROS time: sim time where use_sim_time is set), like the frames' arrival it measures.
        self.deadline_timer = (self.create_timer(DEADLINE_TICK_S, self._on_deadline_tick)
                               if params.deadline_ns is not None else None)
        self.get_logger().info(f"controlling {', '.join(self.names)} with {self.runtime_name}"
                               f"{'; the policy takes the pose estimates' if self.pose_wanted else ''}")
        # last: the lock refuses every parameter set from now on, declarations included
        lock_when_off(self, self.runtime_controls, "greedy and use_sim_time stay as started")

    @property
    def policy(self) -> Any:
        """The policy acting (``BatchPolicy.policy``): set once a policy passed its check (tests set fakes)."""
        return self.batch.policy

    @policy.setter
    def policy(self, policy: Any) -> None:
        self.batch.policy = policy

    # the core's state, read by diagnostics and tests
    pose_wanted = property(lambda self: self.batch.pose_wanted)
    dropped_detections = property(lambda self: self.batch.dropped_detections)
    latencies_ms = property(lambda self: self.decider.latencies_ms)

    # -- the acting policy -----------------------------------------------------------------------------------------
    def _load(self, path: str, runtime: str, data: bytes | None = None):
        """(policy, sha256, version) of a policy file that passed every check (``policy_files.load``)."""
        return policy_files.load(path, runtime, self._validate, data)

    def _validate(self, policy) -> None:
        """A trial decision on the robots' last frames (``BatchPolicy.check``); ValueError with the reason."""
        self.decider.check(policy)

    def _swap(self, policy, digest: str, version: int) -> None:
        """Callbacks run one at a time: the swap happens between two decisions (``Decider.swap``)."""
        self.decider.swap(policy)
        self.checkpoint_sha256, self.policy_version = digest, version
        self._subscribe_poses()

    # -- pose estimates --------------------------------------------------------------------------------------------
    def _subscribe_poses(self) -> None:
        """Subscribe to every robot's ``<robot>/pose_estimate`` once a policy takes the pose (kept afterwards)."""
        if self.batch.refresh_pose() and not self.pose_subs:
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

    def _take_estimates(self) -> None:
        """Every estimate already waiting, filed before a decision reads the rows (``BatchPolicy.pose_rows``)."""
        for name, sub in self.pose_subs.items():
            for msg in waiting(sub, HISTORY_DEPTH):
                self.store_pose(name, msg)

    # -- frames ----------------------------------------------------------------------------------------------------
    def _receiver(self, name: str):
        def receive(msg: DetectionArray) -> None:
            self._admit(name, msg)
            self._drain()
            self._decide()
        return receive

    def _release(self, items: list[tuple[str, DetectionArray]]) -> None:
        """With authenticated frames: frames whose tag came after them are stored, and acted on, from here. Each
        names its robot (a tag binds its frame's topic, whichever companion topic it came on)."""
        for name, msg in items:
            self._store(name, msg)
        self._drain()
        self._decide()

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
            for msg in waiting(sub, DETECTION_DEPTH):
                self._admit(name, msg)

    def _store(self, name: str, msg: DetectionArray) -> None:
        """File one frame in the decider (``Decider.store``); a refused one is logged with the reason."""
        problem = self.decider.store(name, msg)
        if problem:
            self.get_logger().warning(f"{topics.detections(name)}: frame refused: {problem}",
                                      throttle_duration_sec=5.0)

    def _on_deadline_tick(self) -> None:
        """Close every robot's period whose deadline passed (after taking the frames already waiting, which may
        complete a period too), then decide on whatever is ready."""
        self._drain()
        self.decider.close_overdue()
        self._decide()

    # -- decisions -------------------------------------------------------------------------------------------------
    def _decide(self) -> None:
        """Decide while periods are ready: frames taken during a decision may complete the next period."""
        try:
            while self.decider.decide(self._drain, self._send):
                pass
        except CannotPlay as mismatch:
            self.get_logger().error(f"the policy takes {mismatch.fixed} vision frames per period, "
                                    f"{topics.detections(self.names[0])} has {mismatch.frames}: it cannot play "
                                    f"this graph (export it with frames={mismatch.frames})")
            raise NodeExit(2) from None

    def _send(self, out: Outgoing) -> None:
        """One robot's action: stamped with the observation acted on (sim time in the sim), in its base frame,
        with the learning fields (docs/interfaces.md) when the action is the policy's own."""
        frame, action = out.frame, out.action
        msg = Action(robot_id=self.ids[out.name], episode_id=frame.episode_id, motion_period=out.target,
                     **self.scenario.message_fields(action))
        if out.learning is not None:
            msg.policy_version = self.policy_version
            msg.log_prob, msg.value = out.learning
        msg.header.stamp = frame.header.stamp
        msg.header.frame_id = base_frame(out.name)
        self.tag_action(out.name, msg, self.action_pubs[out.name])
        self.action_pubs[out.name].publish(msg)
        if self.ros_sports is not None:        # the walk, kick and head commands beside it (issue 41)
            self.ros_sports.command(out.name, msg, frame)
        self.actions_sent += 1


def main(args: Sequence[str] | None = None) -> int:
    use_bounded_profiles()        # before rclpy.init: DDS drops oversized announcements (ros/dds_profiles.py)
    return run_node(PolicyNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
