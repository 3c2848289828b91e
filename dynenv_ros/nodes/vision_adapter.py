"""Standard vision messages in and out (``ros2 run dynenv_ros vision_adapter``; docs/ros_graph.md, "Standard vision
messages").

Forward (default): each robot's ``/<robot>/detections`` (dynenv_msgs/DetectionArray) is republished as
``/<robot>/detections_3d`` (vision_msgs/Detection3DArray) with the error model's covariances, for RViz's
vision_msgs displays, trackers and other generic tools.

Reverse (``reverse:=true``): a robot's own vision stack publishes ``/<robot>/detections_3d``; the adapter turns each
message into the DetectionArray the policy node reads. Frames and motion periods are numbered from the stamps on
each camera's own grid of slots (``ros.frame_grid``: nearest slot within ``frame_tolerance``, the grid anchored at
``frame_epoch`` — by default the first stamp's phase — and following the camera's phase); a duplicate, a frame too
old or one off the grid is refused and counted (docs/deploy.md, "A real camera's timing"). Labels outside the
documented vocabulary are dropped and counted. The robot's own state comes from what a real robot publishes
(``ros.robot_state``): head yaw from ``<robot>/joint_states`` (sensor_msgs/JointState, joint ``head_yaw_joint``),
fallen and penalized from ``<robot>/fallen`` and ``<robot>/penalized`` (std_msgs/Bool), the GameController's
values from ``<robot>/game_state`` (std_msgs/Float32MultiArray); stale or missing ones keep their defaults, counted.
The counts go to ``~/diagnostics``.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dynenv_msgs.msg import DetectionArray
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float32MultiArray
from vision_msgs.msg import Detection3DArray

from dynenv_ros.perception.params import PRESETS, load_preset
from dynenv_ros.ros import topics
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.frame_grid import ACCEPTED, FrameGrid
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.robot_state import FALLEN, PENALIZED, RobotState, stamp_of
from dynenv_ros.ros.vision_msgs_conversion import from_vision_msgs, to_vision_msgs
from dynenv_ros.soccer.config import robot_names

QUEUE_DEPTH = 50      # per robot topic: ten periods of 5 frames; a stalled reader never grows memory beyond it
# Counts that make a diagnostics window WARN when they grow: frames refused, state values stale or malformed.
WATCHED = ("frames_duplicate", "frames_too_old", "frames_out_of_tolerance", "frames_before_epoch", "grid_restarts",
           "head_yaw_stale", "fallen_stale", "penalized_stale", "game_state_stale", "state_malformed")


def state_qos() -> QoSProfile:
    """Best effort, keep-last 10: matches reliable and best-effort publishers alike (a robot's joint states and a
    GameController bridge may be either); a lost sample is replaced by the next."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


class VisionAdapter(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("vision_adapter", **node_options)
        fixed = dict(read_only=True)
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team (names team_a_0 ...).", **fixed)
        robots = declare_str_list(self, "robots", [], "Robots to adapt; empty: all of players_per_team.", **fixed)
        self.reverse = declare_bool(self, "reverse", False, "Detection3DArray -> DetectionArray (a robot's own "
                                    "vision stack feeding the policy node) instead of the other way.", **fixed)
        preset = declare_str(self, "perception_preset", "realistic", "Error model whose covariances are attached "
                             "(use the simulator's), and whose ranges define the sighting bits in reverse.",
                             choices=PRESETS, **fixed)
        self.vision_hz = declare_float(self, "vision_hz", 10.0, 0.1, 1000.0, "Reverse: camera frame rate.", **fixed)
        self.frames_per_period = declare_int(self, "frames_per_period", 5, 1, 255, "Reverse: vision frames per "
                                             "motion period.", **fixed)
        self.episode_id = declare_int(self, "episode_id", 1, 0, 2**32 - 1, "Reverse: episode id to stamp.", **fixed)
        epoch = declare_float(self, "frame_epoch", -1.0, -1.0, 1e10, "Reverse: the stamp (s) of frame slot 0; "
                              "negative: the first stamp's phase (slot ≈ stamp·vision_hz, centred on the camera's "
                              "timing); 0: the plain round(stamp·vision_hz) numbering.", **fixed)
        self.frame_epoch = epoch if epoch >= 0 else None
        self.frame_tolerance = declare_float(self, "frame_tolerance", 0.4, 0.01, 0.5, "Reverse: a stamp further "
                                             "than this (frame intervals) from its nearest slot is refused.",
                                             **fixed)
        self.frame_phase_gain = declare_float(self, "frame_phase_gain", 0.05, 0.0, 0.5, "Reverse: how far each "
                                              "accepted frame pulls the grid toward its stamp (follows a camera "
                                              "whose rate is a little off; 0: a fixed grid).", **fixed)
        self.head_yaw_joint = declare_str(self, "head_yaw_joint", "HeadYaw", "Reverse: the JointState joint whose "
                                          "position is the head yaw (rad, + left).", **fixed)
        self.head_yaw_max_age = declare_float(self, "head_yaw_max_age", 0.1, 0.0, 10.0, "Reverse: a head yaw "
                                              "sample further than this (s) from the frame's stamp is stale.",
                                              **fixed)
        self.state_max_age = declare_float(self, "state_max_age", 1.0, 0.0, 60.0, "Reverse: a fallen, penalized "
                                           "or game_state value received longer ago than this (s) is stale.",
                                           **fixed)
        diagnostics_s = declare_float(self, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.",
                                      **fixed)
        names = robot_names(players)
        unknown = [r for r in robots if r not in names]
        if unknown:
            raise ParameterException(f"unknown robots {unknown}; robots are {names}", ["robots"])
        self.names = list(robots) or names
        self.params = load_preset(preset)
        self.converted = 0
        self.received = 0
        self.dropped: Counter[str] = Counter()
        self.counts: Counter[str] = Counter()         # frame refusals and state values (reverse)
        self.grids: dict[str, FrameGrid] = {}
        self.states: dict[str, RobotState] = {}
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self.publishers_by_robot = {}
        for name in self.names:
            robot_id = names.index(name)
            if self.reverse:
                publisher = self.create_publisher(DetectionArray, topics.local(topics.detections(name)), qos)
                self.grids[name] = FrameGrid(self.vision_hz, self.frames_per_period, self.frame_tolerance,
                                             self.frame_epoch, self.frame_phase_gain, counts=self.counts)
                self.states[name] = RobotState(self.head_yaw_joint, self.head_yaw_max_age, self.state_max_age,
                                               counts=self.counts)
                self._subscribe_state(name)
                self.create_subscription(Detection3DArray, topics.detections_3d(name),
                                         self._reverse_callback(name, robot_id, publisher), qos)
            else:
                publisher = self.create_publisher(Detection3DArray, topics.detections_3d(name), qos)
                self.create_subscription(DetectionArray, topics.local(topics.detections(name)),
                                         self._forward_callback(publisher),
                                         qos)
            self.publishers_by_robot[name] = publisher
        self.diagnostics_pub = Diagnostics(self, "~/diagnostics")     # and /diagnostics
        self._reported: Counter[str] = Counter()
        self.create_timer(diagnostics_s, self._publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"{'reverse' if self.reverse else 'forward'} for {', '.join(self.names)}")

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _subscribe_state(self, name: str) -> None:
        """The robot's own state topics (``ros.robot_state``), arrivals timed on the node's clock."""
        state, qos = self.states[name], state_qos()
        self.create_subscription(JointState, topics.joint_states(name),
                                 lambda msg: state.joint_state(msg, self._now_ns()), qos)
        self.create_subscription(Bool, topics.fallen(name), lambda msg: state.flag(FALLEN, msg, self._now_ns()),
                                 qos)
        self.create_subscription(Bool, topics.penalized(name),
                                 lambda msg: state.flag(PENALIZED, msg, self._now_ns()), qos)

        def game(msg: Float32MultiArray) -> None:
            problem = state.game_state(msg, self._now_ns())
            if problem:
                self.get_logger().warning(f"{topics.game_state(name)}: refused: {problem}", throttle_duration_sec=5.0)
        self.create_subscription(Float32MultiArray, topics.game_state(name), game, qos)

    def _forward_callback(self, publisher):
        def convert(msg: DetectionArray) -> None:
            publisher.publish(to_vision_msgs(msg, self.params))
            self.converted += 1
        return convert

    def _reverse_callback(self, name: str, robot_id: int, publisher):
        grid, state = self.grids[name], self.states[name]

        def convert(msg: Detection3DArray) -> None:
            self.received += 1
            stamp = stamp_of(msg)
            slot = grid.assign(stamp)
            if slot.status != ACCEPTED:
                self.get_logger().warning(f"{topics.detections_3d(name)}: frames refused so far: "
                                          f"{self._refusals()}", throttle_duration_sec=5.0)
                return
            out, dropped = from_vision_msgs(msg, self.params, robot_id=robot_id, episode_id=self.episode_id,
                                            motion_period=slot.period, frame_index=slot.index,
                                            frames_per_period=self.frames_per_period)
            if dropped:
                self.dropped.update(dropped)
                self.get_logger().warning(f"dropped detections not in the vocabulary so far: {dict(self.dropped)}",
                                          throttle_duration_sec=5.0)
            state.fill(out, stamp, self._now_ns())
            publisher.publish(out)
            self.converted += 1
        return convert

    def _refusals(self) -> str:
        return ", ".join(f"{self.counts[k]} {k[len('frames_'):]}" for k in ("frames_duplicate", "frames_too_old",
                         "frames_out_of_tolerance", "frames_before_epoch") if self.counts[k]) or "none"

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def diagnostics(self) -> dict[str, str]:
        """Counts since start, as strings (DiagnosticStatus)."""
        values = {"direction": "reverse" if self.reverse else "forward", "robots": str(len(self.names)),
                  "frames_received": str(self.received), "frames_converted": str(self.converted),
                  "labels_dropped": str(sum(self.dropped.values()))}
        values.update({k: str(v) for k, v in sorted(self.counts.items())})
        refusal = " ".join(s.refusal for s in self.states.values() if s.refusal)
        if refusal:
            values["state_refusal"] = refusal
        return values

    def _publish_diagnostics(self) -> None:
        values = self.diagnostics()
        new = {k: self.counts[k] - self._reported[k] for k in WATCHED if self.counts[k] > self._reported[k]}
        self._reported.update(new)
        status = DiagnosticStatus(level=DiagnosticStatus.WARN if new else DiagnosticStatus.OK,
                                  name="dynenv_vision_adapter", hardware_id=self.get_fully_qualified_name(),
                                  message=", ".join(f"{v} {k}" for k, v in new.items()) if new else "ok",
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(msg)


def main(args: Sequence[str] | None = None) -> int:
    return run_node(VisionAdapter, args)


if __name__ == "__main__":
    raise SystemExit(main())
