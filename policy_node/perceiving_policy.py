"""The perceiving scripted team's robot as a ROS 2 node (``ros2 run dynenv_ros perceiving_policy --ros-args -p
robot:=…``): ``keeper_and_chasers`` on the robot's own detections and pose estimate, never the ground truth.

It plays ``soccer.perceiving.PerceivingPolicy`` (``dynenv-eval``'s team ``perceiving``): a goalkeeper in slot 0 of a
team of two or more, a chaser elsewhere. It subscribes to its robot's ``<robot>/detections`` (every frame of a
motion period) and ``<robot>/pose_estimate`` (PoseWithCovarianceStamped, frame ``map``: the simulator's with
``localization`` on, or a real robot's localization) and never to ``/world_state``. The period's frames are packed
into the padded layout as the policy node packs them (``envs.detection_messages.pack_messages``); the pose is the
estimate stamped with the period's last frame (``ros.pose_estimates``).

It acts once per motion period, when the period's last frame and the estimate of that same instant have both
arrived (as many estimates at that stamp as the period has frames at it: period 0's frames share one stamp), so
the order DDS delivers the two topics in cannot change a stepped run. An estimate stamped later than the frame that
came first instead (a localization that does not stamp at the camera's instants) settles it too: the newest
estimate at or before the frame, if at most ``pose_max_age`` older, else the robot is lost and stands still
(counted). The action, for the next period, is stamped with the last frame's time and framed in
``<robot>/base_link``, as ``scripted_policy``'s. Malformed frames and estimates are refused with the reason and
counted (``counts``, a throttled log line), a decision that raises stands the robot still (counted): never a crash.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

from dynenv_msgs.msg import Action, DetectionArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.envs.detection_messages import frame_problem, pack_messages
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import action_tagger
from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_float, declare_int, declare_str
from dynenv_ros.ros.pose_estimates import PoseHistory, declare_pose_input, pose_problem, stamp_ns
from dynenv_ros.ros.qos import action_stream, sim_stream
from dynenv_ros.ros.tf import base_frame
from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.config import SoccerConfig, robot_names
from dynenv_ros.soccer.perceiving import perceiving_team
from policy_node.periods import PeriodMemory, file_frame, period_problem

STAND_STILL = SoccerAction()          # a robot without a usable estimate, or whose decision failed
WATCHED = ("frames_malformed", "frames_stale", "periods_dropped", "detections_malformed", "values_malformed",
           "pose_malformed", "pose_missing", "pose_stale", "failed_decisions")


class PerceivingPolicyNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("perceiving_policy", **node_options)
        self.robot = declare_str(self, "robot", "team_a_0", "Robot to control (team_a_0, team_b_1, …).",
                                 read_only=True)
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team in the game: slot 0 of a team "
                              "of two or more keeps goal, the others chase.", read_only=True)
        period = declare_float(self, "period_seconds", SoccerConfig().period_seconds, 0.01, 10.0,
                               "The simulator's motion period, s (ages of the ball memory).", read_only=True)
        self.pose_max_age, self.pose_frame = declare_pose_input(self, "When an estimate stamped after a period's "
                                                                "last frame ends the wait")
        names = robot_names(players)
        if self.robot not in names:
            raise ParameterException(f"robot must be one of {', '.join(names)} (players_per_team {players}), got "
                                     f"{self.robot!r}", ["robot"])
        self.robot_id = names.index(self.robot)
        self.tag_action = action_tagger(self, [self.robot])      # secrets_dir: its team's secret (issue 27)
        self.policy = perceiving_team(players, period)[self.robot_id]
        self.role = type(self.policy.inner).__name__
        self.history = PoseHistory()
        self.counts: Counter[str] = Counter()
        self.refusal = ""                    # the last refused frame or estimate and why
        self.actions_sent = 0
        self.heartbeat = Heartbeat(self, "perceiving policy", lambda: {
            "robot": self.robot, "role": self.role, "actions_sent": self.actions_sent, **self.counts,
            "last_refusal": self.refusal})
        self._start_episode(None)
        self.action_pub = self.create_publisher(Action, topics.local(topics.action(self.robot)), action_stream())
        # The estimates' reader is created before the detections': a simulator that has seen the detections' reader
        # (wait_for_subscribers) has seen the announcement that came before it, so no first estimate goes unread.
        self.create_subscription(PoseWithCovarianceStamped, topics.local(topics.pose_estimate(self.robot)),
                                 self._on_pose, sim_stream())
        self.create_subscription(DetectionArray, topics.local(topics.detections(self.robot)), self._on_detections,
                                 sim_stream())
        self.get_logger().info(f"{self.robot}: {self.role} on its detections and pose estimate")

    def _start_episode(self, episode: int | None) -> None:
        self.memory = PeriodMemory()          # memory.ready: a complete period waiting for its estimate
        self.memory.episode = episode
        self.previous = STAND_STILL
        self.policy.reset()

    def _refuse(self, count: str, topic: str, problem: str) -> None:
        self.counts[count] += 1
        self.refusal = f"{topic}: {problem}"
        self.get_logger().warning(f"{topic}: refused ({self.counts[count]} {count}): {problem}",
                                  throttle_duration_sec=5.0)

    # -- inputs ----------------------------------------------------------------------------------------------------
    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        problem = pose_problem(msg, self.pose_frame)
        if problem:
            self._refuse("pose_malformed", topics.pose_estimate(self.robot), problem)
            return
        self.history.add(msg)
        self._act_if_ready()

    def _on_detections(self, msg: DetectionArray) -> None:
        problem = frame_problem(msg) or period_problem(self.memory, msg)
        if not problem and msg.robot_id != self.robot_id:
            problem = f"robot_id {msg.robot_id}, expected {self.robot_id} (is players_per_team the game's?)"
        if problem:
            self._refuse("frames_malformed", topics.detections(self.robot), problem)
            return
        if msg.episode_id != self.memory.episode:
            self._start_episode(msg.episode_id)
        file_frame(self.memory, msg, self.counts)
        self._act_if_ready()

    # -- decisions -------------------------------------------------------------------------------------------------
    def _act_if_ready(self) -> None:
        """Act on the waiting period once its last frame's estimate is in (module docstring)."""
        memory = self.memory
        if memory.ready is None:
            return
        stamp = stamp_ns(memory.ready[-1].header.stamp)
        needed = sum(stamp_ns(f.header.stamp) == stamp for f in memory.ready)
        entries = self.history.entries
        if sum(e[0] == stamp for e in entries) >= needed:
            estimate, status = self.history.at(stamp, 0)
        elif entries and entries[-1][0] > stamp:
            estimate, status = self.history.at(stamp, round(self.pose_max_age * 1e9))
        else:
            return
        self.counts[status] += 1
        frames, memory.ready = memory.ready, None
        memory.decided = frames[-1].motion_period
        self._publish(frames, estimate[0] if estimate is not None else None)

    def decide(self, frames: list[DetectionArray], pose) -> SoccerAction:
        """The action for a period's frames and the pose estimate (x, y, yaw; None: lost, stand still)."""
        if pose is None:
            self.get_logger().warning(f"{self.robot}: no pose estimate for period {frames[-1].motion_period}: "
                                      "standing still", throttle_duration_sec=5.0)
            return STAND_STILL
        try:
            previous = (int(self.previous.walk), int(self.previous.turn), int(self.previous.kick),
                        float(self.previous.head_yaw_delta))
            packed, _ = pack_messages([frames], [previous], stats=self.counts)
            return self.policy.act({key: value[0] for key, value in packed.items()}, pose)
        except Exception as error:         # one bad decision must not stop the node or a stepped game
            self.counts["failed_decisions"] += 1
            self.get_logger().error(f"decision failed, standing still: {type(error).__name__}: {error}",
                                    throttle_duration_sec=5.0)
            return STAND_STILL

    def _publish(self, frames: list[DetectionArray], pose) -> None:
        action = self.decide(frames, pose)
        last = frames[-1]
        msg = cv.action_msg(action, robot_id=self.robot_id, episode_id=last.episode_id,
                            motion_period=last.motion_period + 1, stamp=last.header.stamp)
        msg.header.frame_id = base_frame(self.robot)      # stamped with the observation it answers (sim time)
        self.tag_action(self.robot, msg, self.action_pub)
        self.action_pub.publish(msg)
        self.actions_sent += 1
        self.previous = action
        if self.actions_sent % 100 == 0 and any(self.counts[k] for k in WATCHED):
            self.get_logger().info(" ".join(f"{k}={self.counts[k]}" for k in WATCHED if self.counts[k]))


def main(args: Sequence[str] | None = None) -> int:
    return run_node(PerceivingPolicyNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
