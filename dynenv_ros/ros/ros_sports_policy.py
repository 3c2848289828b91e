"""The policy node's ros-sports interfaces (``interfaces:=ros_sports``; issue 41, docs/deploy.md "The ros-sports
route"): a team's stack in, a walk engine's, kick engine's and head's commands out.

In, per robot in its namespace (instead of ``<robot>/detections``):

- ``soccer_vision_3d/balls``, ``robots``, ``goalposts``, ``markings`` (soccer_vision_3d_msgs, frame ``base_link``),
  each with its own stamp: grouped into frames by stamp (``frame_parts``: ``frame_tolerance`` of a frame interval,
  at most ``class_wait`` seconds for a missing class), numbered on the camera's grid of slots exactly as the reverse
  vision adapter numbers them (``frame_grid``: ``vision_hz``, ``frames_per_period``, ``frame_epoch``,
  ``frame_tolerance``, ``frame_phase_gain``), turned into the camera frame by the head's yaw at the frame's stamp
  (``perception.soccer_vision_3d.detection_rows``, ``camera_rows``) and handed to the node's frame path, where the
  decision deadline acts on periods a camera leaves incomplete. ``field_boundary`` and ``obstacles`` are read and
  ignored (counted), never refused.
- ``gc/data`` (game_controller_spl_interfaces/RCGCD15): ball ownership, its seconds, the seconds left, the robot's
  penalty (``gamecontroller.robot_view``; team numbers ``gc_team_number_a`` / ``_b``, robot k of a team is player
  k + 1); ``joint_states`` (the head yaw joint) and ``fallen`` (std_msgs/Bool) as ``ros.robot_state`` reads them.
  A GameController value older than ``state_max_age`` is stale and falls back to the defaults, like the others.
- The pose estimate: the node's own ``<robot>/pose_estimate`` input (unchanged).

Out, beside the node's ``dynenv_msgs/Action`` (``soccer.motion_commands``): ``cmd_vel`` (geometry_msgs/Twist, the
action's walk and turn as speeds), ``motion/kick`` (std_msgs/Bool, ``data`` = use_left_foot, once per kick) and
``motion/head`` (sensor_msgs/JointState: the head yaw joint's target and its rate over the period; stamped with the
frame the action answers), kick and twist first, the head command last.

``self_kicking`` has no ros-sports message: the node takes it from its own kick requests (a kick lasts the motion
layer's two periods from the period it was sent for, unless the robot was fallen, penalized or still kicking).
Every message that cannot be read is refused with a one-word reason and counted; the node keeps serving. The counts
go to ``~/diagnostics`` prefixed ``ros_sports_``.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
from dynenv_msgs.msg import DetectionArray
from game_controller_spl_interfaces.msg import RCGCD15
from geometry_msgs.msg import Twist
from rclpy.exceptions import ParameterException
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from soccer_vision_3d_msgs.msg import BallArray, FieldBoundary, GoalpostArray, MarkingArray, ObstacleArray, RobotArray
from std_msgs.msg import Bool

from dynenv_ros.gamecontroller.robot_view import Refused, RobotView, robot_view
from dynenv_ros.perception.detections import empty
from dynenv_ros.perception.params import PRESETS, load_preset
from dynenv_ros.perception.soccer_vision_3d import (IGNORED_KINDS, KINDS, MessageRefused, camera_rows,
                                                    detection_rows)
from dynenv_ros.ros import topics
from dynenv_ros.ros.conversions import detections_to_msgs
from dynenv_ros.ros.drain import take
from dynenv_ros.ros.frame_grid import ACCEPTED, FrameGrid
from dynenv_ros.ros.frame_parts import Frame, FrameParts
from dynenv_ros.ros.parameters import declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.robot_state import FALLEN, RobotState, stamp_of
from dynenv_ros.ros.vision_msgs_conversion import sighting_bits
from dynenv_ros.sim.frames import camera_frame
from dynenv_ros.soccer.actions import Kick
from dynenv_ros.soccer.config import KickConfig, MotionConfig
from dynenv_ros.soccer.motion_commands import StepSpeeds, command_of

INTERFACES = ("dynenv", "ros_sports")
TYPES = {"balls": BallArray, "robots": RobotArray, "goalposts": GoalpostArray, "markings": MarkingArray,
         "field_boundary": FieldBoundary, "obstacles": ObstacleArray}
TICK_S = 0.01            # how often (node clock) frames whose class wait ran out are passed on
QUEUE_DEPTH = 50         # per topic: ten periods of five frames


def reliable(depth: int = QUEUE_DEPTH) -> QoSProfile:
    """Reliable keep-last: lossless in a stepped game (a best-effort publisher does not match it: docs/deploy.md)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)


def ros_sports_io(node: Any, names: list[str], ids: dict[str, int],
                  receiver: Callable[[str], Callable[[DetectionArray], None]]) -> "RosSportsIO | None":
    """Declare ``interfaces`` and the ros-sports parameters (always, before the node's first publisher, so ``--help``
    lists them); the ros-sports inputs and outputs when ``interfaces`` is ``ros_sports``, else None."""
    interfaces = declare_str(node, "interfaces", "dynenv", "What the node reads and commands: dynenv "
                             "(<robot>/detections in, <robot>/action out) or ros_sports (a team stack's "
                             "soccer_vision_3d_msgs, gc/data, joint_states in; cmd_vel, motion/kick, motion/head out, "
                             "beside <robot>/action; docs/deploy.md).", read_only=True, choices=INTERFACES)
    settings = _declare(node)
    if interfaces != "ros_sports":
        return None
    if not node.scenario.legged:       # the ros-sports messages are a legged soccer robot's
        raise ParameterException("interfaces ros_sports is robocup's (soccer robots)", ["interfaces", "scenario"])
    if node.get_parameter("authenticated_frames").value:
        raise ParameterException("authenticated_frames tags DetectionArrays; a team stack's soccer_vision_3d "
                                 "messages carry no tags", ["interfaces", "authenticated_frames"])
    return RosSportsIO(node, settings, names, ids, receiver)


def _declare(node: Any) -> dict[str, Any]:
    """The ros-sports parameters (read-only), checked."""
    fixed = dict(read_only=True)
    values = dict(
        vision_hz=declare_float(node, "vision_hz", 10.0, 0.1, 1000.0, "ros_sports: camera frame rate.", **fixed),
        frames_per_period=declare_int(node, "frames_per_period", 5, 1, 64, "ros_sports: vision frames per motion "
                                      "period.", **fixed),
        frame_epoch=declare_float(node, "frame_epoch", -1.0, -1.0, 1e10, "ros_sports: the stamp (s) of frame slot "
                                  "0; negative: the first stamp's phase (as the reverse vision adapter).", **fixed),
        frame_tolerance=declare_float(node, "frame_tolerance", 0.4, 0.01, 0.5, "ros_sports: a stamp further than "
                                      "this (frame intervals) from its slot is refused; class messages within it of "
                                      "a frame's first one belong to that frame.", **fixed),
        frame_phase_gain=declare_float(node, "frame_phase_gain", 0.05, 0.0, 0.5, "ros_sports: how far each frame "
                                       "pulls the grid toward its stamp.", **fixed),
        class_wait=declare_float(node, "class_wait", 0.03, 0.0, 1.0, "ros_sports: seconds (node clock) a frame "
                                 "waits for its missing class messages after its first one arrived.", **fixed),
        frame_classes=declare_str_list(node, "frame_classes", list(KINDS), "ros_sports: the soccer_vision_3d arrays "
                                       "the stack publishes per frame (a frame is complete with these).", **fixed),
        detection_frame=declare_str(node, "detection_frame", "base_link", "ros_sports: the frame the detections "
                                    "are in (frame_id, or its last part after '/').", **fixed),
        perception_preset=declare_str(node, "perception_preset", "realistic", "ros_sports: the error model whose "
                                      "ranges give the sighting bits.", choices=PRESETS, **fixed),
        head_yaw_joint=declare_str(node, "head_yaw_joint", "HeadYaw", "ros_sports: the JointState joint that is "
                                   "the head yaw (read from joint_states, commanded on motion/head).", **fixed),
        head_yaw_max_age=declare_float(node, "head_yaw_max_age", 0.1, 0.0, 10.0, "ros_sports: a head yaw sample "
                                       "further than this (s) from the frame's stamp is stale.", **fixed),
        state_max_age=declare_float(node, "state_max_age", 1.0, 0.0, 60.0, "ros_sports: a fallen flag or "
                                    "GameController message received longer ago than this (s) is stale.", **fixed),
        gc_team_number_a=declare_int(node, "gc_team_number_a", 1, 1, 254, "ros_sports: team A's SPL team number "
                                     "in gc/data.", **fixed),
        gc_team_number_b=declare_int(node, "gc_team_number_b", 2, 1, 254, "ros_sports: team B's SPL team "
                                     "number.", **fixed),
        gc_player_number=declare_int(node, "gc_player_number", 0, 0, 20, "ros_sports: the robot's player number "
                                     "in gc/data (1 … 20); 0: robot k of its team is player k + 1.", **fixed),
        episode_id=declare_int(node, "episode_id", 1, 0, 2**32 - 1, "ros_sports: the episode id of the frames (a "
                               "team stack has no episodes).", **fixed))
    kinds = values["frame_classes"]
    if not kinds or any(k not in KINDS for k in kinds):
        raise ParameterException(f"frame_classes must be some of {list(KINDS)}, got {kinds}", ["frame_classes"])
    return values


class _Robot:
    """One robot's inputs being assembled and its command publishers."""

    def __init__(self, parts: FrameParts, grid: FrameGrid, state: RobotState, team_number: int,
                 player_number: int) -> None:
        self.parts, self.grid, self.state = parts, grid, state
        self.team_number, self.player_number = team_number, player_number
        self.game: tuple[int, RobotView] | None = None       # (arrival ns, view) of the newest RCGCD
        self.kick_from: int | None = None                   # the periods its own kick runs in
        self.kick_until: int | None = None
        self.frame_subs: list[tuple[str, Any]] = []
        self.state_subs: list[Callable[[], None]] = []
        self.publishers: tuple[Any, Any, Any] | None = None  # twist, kick, head


class RosSportsIO:
    """The ros-sports inputs and outputs of a policy node (module docstring)."""

    def __init__(self, node: Any, settings: dict[str, Any], names: list[str], ids: dict[str, int],
                 receiver: Callable[[str], Callable[[DetectionArray], None]]) -> None:
        self.node, self.ids, self.receiver = node, ids, receiver
        self.vision_hz, self.frames_per_period = settings["vision_hz"], settings["frames_per_period"]
        epoch, tolerance, gain = settings["frame_epoch"], settings["frame_tolerance"], settings["frame_phase_gain"]
        wait, kinds, self.frame_id = settings["class_wait"], settings["frame_classes"], settings["detection_frame"]
        preset, joint = settings["perception_preset"], settings["head_yaw_joint"]
        head_age, state_age = settings["head_yaw_max_age"], settings["state_max_age"]
        team_a, team_b, player = settings["gc_team_number_a"], settings["gc_team_number_b"], settings["gc_player_number"]
        self.episode_id = settings["episode_id"]
        if team_a == team_b:
            raise ParameterException(f"the teams need distinct numbers, got {team_a} twice",
                                     ["gc_team_number_a", "gc_team_number_b"])
        self.kinds = tuple(kinds)
        self.joint = joint
        self.params = load_preset(preset)
        self.state_age_ns = round(state_age * 1e9)
        period_s = self.frames_per_period / self.vision_hz
        self.speeds = StepSpeeds.of(MotionConfig(), period_s)
        self.head_limit = MotionConfig().head_limit
        self.kick_periods = KickConfig().periods
        self.counts: Counter[str] = Counter()
        interval_ns = 1e9 / self.vision_hz
        self.robots: dict[str, _Robot] = {}
        for name in names:
            robot = _Robot(FrameParts(self.kinds, max(1, round(tolerance * interval_ns)), round(wait * 1e9),
                                      counts=self.counts),
                           FrameGrid(self.vision_hz, self.frames_per_period, tolerance, epoch if epoch >= 0 else None,
                                     gain, counts=self.counts),
                           RobotState(joint, head_age, state_age, counts=self.counts),
                           team_a if name.startswith("team_a") else team_b,
                           player or int(name.rsplit("_", 1)[1]) + 1)
            self.robots[name] = robot
            self._subscribe(name, robot)
        self.node.create_timer(TICK_S, self._tick)
        self.node.get_logger().info(f"ros_sports: {', '.join(self.kinds)} frames at {self.vision_hz:g} Hz, "
                                    f"{self.frames_per_period} per period; commands on cmd_vel, motion/kick, "
                                    "motion/head")

    # -- in ----------------------------------------------------------------------------------------------------
    def _subscribe(self, name: str, robot: _Robot) -> None:
        node, local = self.node, topics.local
        for kind, msg_type in TYPES.items():
            sub = node.create_subscription(msg_type, local(topics.soccer_vision_3d(name, kind)),
                                           lambda msg, kind=kind: self.part(name, kind, msg), reliable())
            robot.frame_subs.append((kind, sub))
        joints = node.create_subscription(JointState, topics.joint_states(name),
                                          lambda msg: robot.state.joint_state(msg, self._now()), reliable())
        fallen = node.create_subscription(Bool, topics.fallen(name),
                                          lambda msg: robot.state.flag(FALLEN, msg, self._now()), reliable(10))
        game = node.create_subscription(RCGCD15, local(topics.gc_data(name)), lambda msg: self.game(name, msg),
                                         reliable(10))
        robot.state_subs = [lambda s=s, f=f: [f(m) for m in _take(s)] for s, f in (
            (joints, lambda m: robot.state.joint_state(m, self._now())),
            (fallen, lambda m: robot.state.flag(FALLEN, m, self._now())),
            (game, lambda m: self.game(name, m)))]
        robot.publishers = (node.create_publisher(Twist, local(topics.walk_target(name)), reliable(10)),
                            node.create_publisher(Bool, local(topics.kick_request(name)), reliable(10)),
                            node.create_publisher(JointState, local(topics.head_command(name)), reliable(10)))

    def _now(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def game(self, name: str, msg: Any) -> None:
        """File a GameController message, or refuse it (counted by reason, logged)."""
        robot = self.robots[name]
        try:
            view = robot_view(msg, robot.team_number, robot.player_number)
        except Refused as refused:
            self._refuse(name, "gc/data", refused.reason, str(refused))
            return
        robot.game = (self._now(), view)

    def part(self, name: str, kind: str, msg: Any) -> None:
        """File one soccer_vision_3d message: read (body frame rows), or refused with the reason; a frame it
        completes goes on."""
        self.counts["parts_received"] += 1
        if kind in IGNORED_KINDS or kind not in self.kinds:
            self.counts[f"{kind}_ignored"] += 1
            return
        frame_id = msg.header.frame_id
        if frame_id != self.frame_id and not frame_id.endswith("/" + self.frame_id):
            self._refuse(name, kind, "frame", f"frame_id '{frame_id}' is not {self.frame_id}")
            return
        try:
            rows = detection_rows(kind, msg)
        except MessageRefused as refused:
            self._refuse(name, kind, refused.reason, str(refused))
            return
        for frame in self.robots[name].parts.add(kind, stamp_of(msg), self._now(), rows):
            self._deliver(name, frame)

    def _refuse(self, name: str, topic: str, reason: str, text: str) -> None:
        self.counts[f"refused_{reason}"] += 1
        self.node.get_logger().warning(f"{name}/{topic}: refused ({reason}): {text}", throttle_duration_sec=5.0)

    def _tick(self) -> None:
        """Take what is waiting, then pass on the frames whose class wait ran out."""
        now = self._now()
        for name, robot in self.robots.items():
            for kind, sub in robot.frame_subs:
                for msg in _take(sub):
                    self.part(name, kind, msg)
            for frame in robot.parts.due(now):
                self._deliver(name, frame)

    def _deliver(self, name: str, frame: Frame) -> None:
        """A frame to the node: numbered on the grid (refused frames are counted there), in the camera frame, with
        the robot's own state and the game."""
        robot = self.robots[name]
        for drain in robot.state_subs:           # the joint sample of this stamp may be waiting still
            drain()
        slot = robot.grid.assign(frame.stamp_ns)
        if slot.status != ACCEPTED:
            return
        now = self._now()
        head_yaw = robot.state.head_yaw(frame.stamp_ns)
        parts = [frame.parts[k] for k in self.kinds if k in frame.parts]
        rows = camera_rows(np.concatenate(parts) if parts else empty(0), head_yaw)
        view = self._view(robot, now)
        kicking = robot.kick_from is not None and robot.kick_from <= slot.period <= (robot.kick_until or -1)
        msg = DetectionArray(robot_id=self.ids[name], episode_id=self.episode_id, motion_period=slot.period,
                             frame_index=slot.index, frames_per_period=self.frames_per_period, head_yaw=head_yaw,
                             self_fallen=bool(robot.state.value(FALLEN, now)),
                             self_penalized=view.penalized if view else False, self_kicking=kicking,
                             ball_owner=view.ball_owner if view else 0,
                             ball_owner_seconds=view.ball_owner_seconds if view else 0.0,
                             game_seconds_remaining=view.game_seconds_remaining if view else 0.0,
                             detections=detections_to_msgs(rows))
        msg.header.frame_id = camera_frame(name)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(frame.stamp_ns, 1_000_000_000)
        for detection, bits in zip(msg.detections, sighting_bits(msg.detections, self.params)):
            detection.sighting = int(bits)
        self.counts["frames_passed"] += 1
        self.receiver(name)(msg)

    def _view(self, robot: _Robot, now: int) -> RobotView | None:
        """The newest GameController view, None when missing or stale (counted)."""
        if robot.game is None:
            self.counts["gc_missing"] += 1
            return None
        if now - robot.game[0] > self.state_age_ns:
            self.counts["gc_stale"] += 1
            return None
        self.counts["gc_used"] += 1
        return robot.game[1]

    # -- out ---------------------------------------------------------------------------------------------------
    def command(self, name: str, action: Any, frame: DetectionArray) -> None:
        """The engines' commands for an Action the node sent: kick (if any), twist, then the head command."""
        robot = self.robots[name]
        assert robot.publishers is not None
        twist_pub, kick_pub, head_pub = robot.publishers
        cmd = command_of(action.walk, action.turn, action.kick, float(action.head_yaw_delta), self.speeds)
        target = int(action.motion_period)
        if cmd.kick != Kick.NONE:
            kick_pub.publish(Bool(data=cmd.kick == Kick.LEFT_FOOT))
            self.counts["kicks_requested"] += 1
            busy = robot.kick_until is not None and target <= robot.kick_until
            if not (frame.self_fallen or frame.self_penalized or busy):
                robot.kick_from, robot.kick_until = target, target + self.kick_periods - 1
        twist = Twist()
        twist.linear.x, twist.linear.y, twist.angular.z = cmd.vx, cmd.vy, cmd.wz
        twist_pub.publish(twist)
        head = JointState(name=[self.joint], position=[max(-self.head_limit, min(self.head_limit, float(
            frame.head_yaw) + float(action.head_yaw_delta)))], velocity=[cmd.head_rate])
        head.header.stamp = action.header.stamp
        head_pub.publish(head)
        self.counts["commands_sent"] += 1

    def diagnostics(self) -> dict[str, str]:
        return {f"ros_sports_{k}": str(v) for k, v in sorted(self.counts.items())}


def _take(sub: Any, limit: int = QUEUE_DEPTH):
    """The messages already waiting on ``sub`` (at most ``limit``; ``ros.drain``)."""
    for _ in range(limit):
        msg = take(sub)
        if msg is None:
            return
        yield msg


__all__ = ["INTERFACES", "RosSportsIO", "ros_sports_io"]
