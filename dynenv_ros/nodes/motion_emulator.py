"""The motion emulator (``ros2 run dynenv_ros motion_emulator``; issue 41, docs/deploy.md "The motion emulator"):
a robot's walk engine, kick engine and head over the simulator, so that only ros-sports messages pass between a
team's stack (or a policy node with ``interfaces:=ros_sports``) and the simulated robot.

Per robot it reads what a stack commands — ``<robot>/cmd_vel`` (geometry_msgs/Twist: the walk target),
``<robot>/motion/kick`` (std_msgs/Bool: a kick request, ``data`` = use_left_foot), ``<robot>/motion/head``
(sensor_msgs/JointState: the head yaw joint's rate over the period in ``velocity``, stamped with the frame it
answers) — and the simulator's ``<robot>/feedback`` (the end of each motion period), and sends the simulator one
``dynenv_msgs/Action`` per period on ``<robot>/action``: the commands quantised to the motion layer's steps
(``soccer.motion_commands``), when the head command answering the period's last frame has come or
``command_timeout`` seconds (steady clock) after the period ended without one (``soccer.motion_emulation``). Before
any node publishes on ``cmd_vel`` it waits without a timeout: the stack is not up yet. A command that cannot be one
(a walk target or head rate that is not finite or beyond any robot, a head command without the head joint) is refused
with the reason, counted, and the node keeps serving. The counts go to ``/diagnostics`` every second.
"""
from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

from dynenv_msgs.msg import Action, StepFeedback
from geometry_msgs.msg import Twist
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import action_tagger
from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.drain import take
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.qos import action_stream
from dynenv_ros.ros.robot_state import stamp_of
from dynenv_ros.sim.frames import base_frame
from dynenv_ros.soccer.config import MotionConfig, SoccerConfig, robot_names
from dynenv_ros.soccer.motion_commands import StepSpeeds
from dynenv_ros.soccer.motion_emulation import Due, EngineLatch

TICK_S = 0.005        # how often (steady clock) the timeouts are looked at


def command_qos(depth: int = 10) -> QoSProfile:
    """Reliable keep-last: the policy node's command publishers; a lost kick request would be a lost kick."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)


class MotionEmulator(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("motion_emulator", **node_options)
        fixed = dict(read_only=True)
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team in the game.", **fixed)
        team = declare_str(self, "team", "", "Emulate team 'a''s robots, team 'b''s, or both ('').",
                           choices=("", "a", "b"), **fixed)
        robots = declare_str_list(self, "robots", [], "Robots to emulate; empty: those of team.", **fixed)
        period_s = declare_float(self, "motion_period", SoccerConfig().period_seconds, 0.01, 10.0, "Seconds per motion "
                                 "period (the simulator's): a twist is a step per this time.", **fixed)
        timeout = declare_float(self, "command_timeout", 1.0, 0.0, 60.0, "Seconds (steady clock) after a period "
                                "ended that the action goes out without the stack's answer (newest walk target, "
                                "head still).", **fixed)
        tolerance = declare_float(self, "stamp_tolerance", 0.05, 0.0, 1.0, "A head command stamped up to this (s) "
                                  "before a period's last frame answers it.", **fixed)
        twist_age = declare_float(self, "twist_max_age", 2.0, 0.0, 60.0, "A walk target older than this (s, "
                                  "steady clock) is dropped: the robot stands.", **fixed)
        self.joint = declare_str(self, "head_yaw_joint", "HeadYaw", "The head command's joint.", **fixed)
        names = robot_names(players)
        unknown = [r for r in robots if r not in names]
        if unknown:
            raise ParameterException(f"unknown robots {unknown}; robots are {names}", ["robots"])
        self.names = list(robots) or [n for n in names if not team or n[5] == team]
        self.ids = {n: names.index(n) for n in self.names}
        motion = MotionConfig()
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.latches = {n: EngineLatch(StepSpeeds.of(motion, period_s), motion.head_max_delta, round(tolerance * 1e9),
                                       round(timeout * 1e9), round(twist_age * 1e9)) for n in self.names}
        self.counts: Counter[str] = Counter()
        self.commanded: set[str] = set()           # robots whose walk target has a publisher (the stack is up)
        self.tag_action = action_tagger(self, self.names)      # secrets_dir: its team's secret (issue 27)
        self.action_pubs = {n: self.create_publisher(Action, topics.local(topics.action(n)), action_stream())
                            for n in self.names}
        feedback_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.command_subs: dict[str, list[tuple[Any, Any]]] = {}    # robot -> (walk target, kick) (sub, callback)
        for name in self.names:
            local = topics.local
            self.command_subs[name] = [
                (self.create_subscription(t, local(topic(name)), callback(name), command_qos()), callback(name))
                for t, topic, callback in ((Twist, topics.walk_target, self._twist), (Bool, topics.kick_request,
                                                                                      self._kick))]
            self.create_subscription(JointState, local(topics.head_command(name)), self._head(name), command_qos())
            self.create_subscription(StepFeedback, local(topics.feedback(name)), self._feedback(name), feedback_qos)
        self.create_timer(TICK_S, self._tick, clock=self.steady)
        self.heartbeat = Heartbeat(self, "motion emulator", lambda: dict(sorted(self.counts.items())))
        self.get_logger().info(f"emulating the walk, kick and head of {', '.join(self.names)} "
                               f"({period_s:g} s periods)")

    def _now(self) -> int:
        return self.steady.now().nanoseconds

    def _refuse(self, name: str, what: str, reason: str) -> None:
        self.counts[f"{what}_refused"] += 1
        self.get_logger().warning(f"{name}: {what} refused: {reason}", throttle_duration_sec=5.0)

    # -- the stack's commands ------------------------------------------------------------------------------------
    def _twist(self, name: str):
        def on_twist(msg: Twist) -> None:
            problem = self.latches[name].walk_target(msg.linear.x, msg.linear.y, msg.angular.z, self._now())
            if problem:
                self._refuse(name, "walk_target", problem)
            else:
                self.counts["walk_targets"] += 1
        return on_twist

    def _kick(self, name: str):
        def on_kick(msg: Bool) -> None:
            self.latches[name].kick_request(bool(msg.data))
            self.counts["kick_requests"] += 1
        return on_kick

    def _head(self, name: str):
        def on_head(msg: JointState) -> None:
            names = list(msg.name)
            if self.joint not in names or names.index(self.joint) >= len(msg.velocity):
                self._refuse(name, "head_command", f"no velocity for joint {self.joint} in {names}")
                return
            rate = float(msg.velocity[names.index(self.joint)])
            problem = self.latches[name].head_command(stamp_of(msg), rate)
            if problem:
                self._refuse(name, "head_command", problem)
                return
            self.counts["head_commands"] += 1
            self._send(name)
        return on_head

    # -- the simulator's periods ---------------------------------------------------------------------------------
    def _feedback(self, name: str):
        def on_feedback(msg: StepFeedback) -> None:
            if msg.terminated or msg.truncated:
                return                      # the episode is over: no period follows
            self.latches[name].period_ended(int(msg.episode_id), int(msg.motion_period), stamp_of(msg), self._now())
            self._send(name)
        return on_feedback

    def _tick(self) -> None:
        for name in self.names:
            self._send(name)

    def _send(self, name: str) -> None:
        for sub, callback in self.command_subs[name]:    # a kick and twist sent before the head may still wait
            while (msg := take(sub)) is not None:
                callback(msg)
        if name not in self.commanded and self.count_publishers(topics.local(topics.walk_target(name))) > 0:
            self.commanded.add(name)
        commander = name in self.commanded
        try:
            due = self.latches[name].due(self._now(), commander)
        except ValueError as error:        # a command that passed its own check but not the action's
            self._refuse(name, "command", str(error))
            self.latches[name].waiting = None
            return
        if due is not None:
            self._publish(name, due)

    def _publish(self, name: str, due: Due) -> None:
        walk, turn, kick, head = due.action
        msg = Action(robot_id=self.ids[name], episode_id=due.episode, motion_period=due.period, walk=walk, turn=turn,
                     kick=kick, head_yaw_delta=float(head) if math.isfinite(head) else 0.0)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(due.stamp_ns, 1_000_000_000)
        msg.header.frame_id = base_frame(name)
        self.tag_action(name, msg, self.action_pubs[name])
        self.action_pubs[name].publish(msg)
        self.counts[f"actions_{due.why}"] += 1


def main(args: Sequence[str] | None = None) -> int:
    return run_node(MotionEmulator, args)


if __name__ == "__main__":
    raise SystemExit(main())
