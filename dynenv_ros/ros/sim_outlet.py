"""What the simulator node publishes (docs/ros_graph.md): per vision frame ``/clock``, ``/world_state``, TF, each
robot's pose estimate and detections (with ``authenticated_frames``, each frame's tag on ``<topic>_mac``), the
ros-sports messages (``sim_ros_sports``) and the markers; per motion period each robot's feedback. The game
(``envs/sim_game.py``) says what and when; this is its ``Outlet``.

Stepped mode is lossless (KEEP_ALL: a slow reader slows the simulation down); real time cannot wait, so its
publishers keep a bounded history (docs/ros_graph.md, "Real time, QoS and security").
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock as ClockMsg
from std_msgs.msg import UInt8MultiArray
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from dynenv_ros.envs.session import PeriodOutput
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros import driving_markers, markers, topics
from dynenv_ros.ros.cdr import detection_array_cdr
from dynenv_ros.ros.frame_tags import tag_message, tag_topic
from dynenv_ros.ros.pose_estimates import EmulatedOdometry, pose_message, stamp_ns
from dynenv_ros.ros.qos import REALTIME_FEEDBACK_DEPTH, REALTIME_FRAME_DEPTH, realtime_stream, sim_stream
from dynenv_ros.ros.sim_parameters import SimSettings
from dynenv_ros.ros.sim_robot_io import SimRobotIO
from dynenv_ros.ros.sim_ros_sports import RosSportsOutlet
from dynenv_ros.ros.tf import TF_STATIC_TOPIC, TF_TOPIC, static_transforms, tf_message, tf_qos, tf_static_qos
from dynenv_ros.ros.topics import local
from dynenv_ros.scenarios import get_scenario
from dynenv_ros.security.action_auth import tag_feedback
from dynenv_ros.security.frame_auth import detection_rows_bytes, world_state_bytes
from dynenv_ros.sim.frames import robot_frames

# Stepped mode's patience with a refused publish: longer than Fast DDS's default participant lease (20 s), after
# which a killed reader is unmatched and the writer accepts samples again (``SimOutlet.publish``).
STEPPED_PUBLISH_PATIENCE_S = 30.0


class SimOutlet:
    """The simulator's publishers (module docstring). ``counts``: the game's counters (``publish_failed``);
    ``finish``: what the node does when its last episode has ended; ``live_view``: the Foxglove view or None."""

    def __init__(self, node: Node, settings: SimSettings, counts: Counter[str], finish: Callable[[], None]) -> None:
        self.node, self.names, self.scenario = node, settings.names, settings.scenario
        self.stepped = settings.mode == "stepped"
        self.counts, self.finish = counts, finish
        self.config, self.secrets, self.frames_secret = settings.config, settings.secrets, settings.frames_secret
        self.publish_markers, self.marker_robot = settings.publish_markers, settings.marker_robot
        self.map: Any = None                 # driving: the road map the markers draw
        self.live_view: Any = None
        self.tick_s = settings.config.rates.tick_seconds
        if self.stepped:
            frame_qos = feedback_qos = sim_stream()
        else:
            frame_qos, feedback_qos = realtime_stream(REALTIME_FRAME_DEPTH), realtime_stream(REALTIME_FEEDBACK_DEPTH)
        # Joints, fall flags, GameController UDP (issue 41); its parameters declared before the first publisher.
        self.robot_io = SimRobotIO(node, self.names, settings.ros_sports, settings.game.legged, self.publish,
                                   frame_qos)
        create = node.create_publisher
        self.clock_pub = create(ClockMsg, local(topics.CLOCK), frame_qos)
        self.world_pub = create(cv.WorldState, local(topics.WORLD_STATE), frame_qos)
        self.detection_pubs = [create(cv.DetectionArray, local(topics.detections(n)), frame_qos) for n in self.names]
        self.frame_tag_pubs: list[Any] = []            # world_state's, then each robot's detections'
        if self.frames_secret is not None:
            self.frame_tag_pubs = [create(UInt8MultiArray, tag_topic(p.topic_name), frame_qos)
                                   for p in [self.world_pub] + self.detection_pubs]
        self.feedback_pubs = [create(cv.StepFeedback, local(topics.feedback(n)), feedback_qos) for n in self.names]
        # Self-localization (ros/pose_estimates.py): each robot's estimate per frame, with the detections' QoS.
        self.pose_pubs = [create(PoseWithCovarianceStamped, local(topics.pose_estimate(n)), frame_qos)
                          for n in self.names] if settings.localization else []
        self.ros_sports = RosSportsOutlet(node, self.names, frame_qos, self.config.players_per_team,
                                          settings.gc_team_numbers, self.publish) if settings.ros_sports else None
        self.odometry = EmulatedOdometry(self.config.rates.vision_period_ticks * self.tick_s)
        self.feedback_topics = [p.topic_name for p in self.feedback_pubs]
        # TF (ros/tf.py): the robots and their heads per frame; the team frames once, latched.
        self.tf_pub = create(TFMessage, local(TF_TOPIC), tf_qos())
        self.tf_static_pub = create(TFMessage, local(TF_STATIC_TOPIC), tf_static_qos())
        if settings.game.team_frames:          # the team frames of soccer's localization outputs
            self.tf_static_pub.publish(static_transforms(cv.sim_time(0, self.tick_s)))
        self._last_tf_ns = -1
        self.truth_marker_pub = create(MarkerArray, local(topics.GROUND_TRUTH_MARKERS), QoSProfile(depth=5))
        self.detection_marker_pub = create(MarkerArray, local(topics.DETECTION_MARKERS), QoSProfile(depth=5))

    def lossless(self) -> list[Any]:
        """The publishers a reader must have everything of before the node exits."""
        return ([self.clock_pub, self.world_pub] + self.detection_pubs + self.frame_tag_pubs + self.feedback_pubs
                + self.pose_pubs)

    # -- the game's Outlet -------------------------------------------------------------------------------------
    def episode_started(self, episode: int, tick: int) -> None:
        if self.ros_sports is not None:
            self.ros_sports.episode_started()
        self.odometry.restart()                 # a new episode, a new odometry (odom: the kickoff pose)
        if self.live_view is not None:
            self.live_view.log_event(f"episode {episode} started", stamp_ns(cv.sim_time(tick, self.tick_s)))

    def period_ran(self, output: PeriodOutput) -> None:
        if self.ros_sports is not None:
            self.ros_sports.period_ran(output)

    def announce(self, text: str, tick: int) -> None:
        self.node.get_logger().info(text)
        if self.live_view is not None:
            self.live_view.log_event(text, stamp_ns(cv.sim_time(tick, self.tick_s)))

    def frame(self, output: PeriodOutput, k: int, poses: tuple[Any, Any] | None, tick: int) -> None:
        """Frame k of a period (sim time: ``tick``): /clock, /world_state, TF, the pose estimates (``poses``: the
        period's (F, n, 3) estimates and variances, None without localization), then every robot's detections."""
        frame = output.frames[k]
        stamp = cv.sim_time(tick, self.tick_s)
        self.publish(self.clock_pub, ClockMsg(clock=stamp))
        world = cv.world_state(frame.snapshot, stamp)
        self.publish(self.world_pub, world)
        if self.frame_tag_pubs:
            self.publish(self.frame_tag_pubs[0], tag_message(self.frames_secret,
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
                self.publish(publisher, pose_message(estimates[i], variances[i], stamp))
        frames_per_period = len(output.frames)
        for i, robot in enumerate(frame.robots):   # serialised from the numpy records directly (ros/cdr.py)
            fields = dict(stamp_sec=stamp.sec, stamp_nanosec=stamp.nanosec, frame_id=cv.camera_frame(self.names[i]),
                          robot_id=i, episode_id=output.episode_id, motion_period=output.motion_period,
                          frame_index=k, frames_per_period=frames_per_period, head_yaw=robot.head_yaw,
                          fallen=robot.fallen, penalized=robot.penalized, kicking=robot.kicking,
                          ball_owner=robot.ball_owner, ball_owner_seconds=robot.ball_owner_seconds,
                          game_seconds_remaining=robot.game_seconds_remaining)
            self.publish(self.detection_pubs[i], detection_array_cdr(robot.detections, **fields))
            if self.frame_tag_pubs:
                data = detection_rows_bytes(robot.detections, self.detection_pubs[i].topic_name, **fields)
                self.publish(self.frame_tag_pubs[i + 1], tag_message(self.frames_secret, data))
        self.robot_io.frame(output, k, frame, stamp)        # joints, fall flags, GameController UDP (issue 41)
        if self.ros_sports is not None:
            self.ros_sports.frame(k, frame, stamp)
        if self.publish_markers and k == len(output.frames) - 1:
            self._markers(frame, stamp)

    def feedback(self, output: PeriodOutput, digests: dict[int, bytes], tick: int) -> None:
        """Each robot's feedback of a period (sim time: ``tick``, its last frame's), naming the action it ran."""
        stamp = cv.sim_time(tick, self.tick_s)
        for i, fb in enumerate(output.feedback):
            msg = cv.step_feedback(
                robot_id=i, episode_id=output.episode_id, motion_period=output.motion_period, rewards=fb.rewards,
                terminated=output.terminated if fb.terminated is None else fb.terminated,
                truncated=output.truncated if fb.truncated is None else fb.truncated,
                seen_object_ids=fb.seen_object_ids, landmarks_seen=fb.landmarks_seen, stamp=stamp,
                action_digest=digests.get(i, b""))
            if self.secrets is not None:
                msg.mac = tag_feedback(msg, self.feedback_topics[i], self.secrets.simulator)
            self.publish(self.feedback_pubs[i], msg)

    def _markers(self, frame: Any, stamp: Any) -> None:
        """RViz/Foxglove: the ground truth, and what ``marker_robot`` detected and missed."""
        getattr(self, f"_{get_scenario(self.scenario).name}_markers")(frame, stamp)

    # Each scenario's markers, by its canonical name (docs/decisions.md, "A scenario registry").
    def _soccer_markers(self, frame: Any, stamp: Any) -> None:
        self.truth_marker_pub.publish(markers.ground_truth_markers(frame.snapshot, self.config.field, stamp,
                                                                   include_field=True))
        seen = self._marker_robot_seen(frame)
        if seen is not None:
            me, detections, missed = seen
            self.detection_marker_pub.publish(markers.detection_markers(
                detections, (me.x, me.y, me.yaw + me.head_yaw), stamp, missed=missed, robot_name=self.marker_robot))

    def _driving_markers(self, frame: Any, stamp: Any) -> None:
        self.truth_marker_pub.publish(driving_markers.ground_truth_markers(frame.snapshot, self.map, stamp,
                                                                           include_map=True))
        seen = self._marker_robot_seen(frame)
        if seen is not None:
            me, detections, missed = seen
            self.detection_marker_pub.publish(driving_markers.detection_markers(
                detections, (me.x, me.y, me.yaw), stamp, missed=missed, car_name=self.marker_robot))

    def _marker_robot_seen(self, frame: Any) -> tuple[Any, Any, list[tuple[Any, ...]]] | None:
        """(body state, detections, missed objects) of ``marker_robot`` in ``frame``; None without one."""
        if not self.marker_robot:
            return None
        i = self.names.index(self.marker_robot)
        me, robot = frame.snapshot.objects[i], frame.robots[i]
        return me, robot.detections, [] if robot.missed is None else [tuple(p) for p in robot.missed.tolist()]

    def publish(self, publisher: Any, message: Any) -> None:
        """Publish on a KEEP_ALL topic. In stepped mode nothing is lost: if Fast DDS refuses after its blocking
        time, try again for up to ``STEPPED_PUBLISH_PATIENCE_S``. Why that long: a reader killed without goodbye
        (SIGKILL) stays matched until its participant's lease runs out (Fast DDS: 20 s by default) and its
        unacknowledged samples fill the writer's history meanwhile; a one-second patience dropped frames then and
        stalled the game. A reader that is alive but never reads is a fault of its own: after the patience the
        message is counted in ``publish_failed`` and dropped. In real time one attempt only: a frame that cannot
        go out now is counted and dropped, the clock does not wait."""
        deadline = time.monotonic() + (STEPPED_PUBLISH_PATIENCE_S if self.stepped else 0.0)
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
                self.node.get_logger().warning(f"{publisher.topic_name}: a reader does not acknowledge (killed?); "
                                               f"waiting up to {STEPPED_PUBLISH_PATIENCE_S:.0f} s for DDS to drop it",
                                               throttle_duration_sec=5.0)
            time.sleep(0.01)
        self.counts["publish_failed"] += 1
        self.node.get_logger().error(f"could not publish on {publisher.topic_name}: its readers are stuck",
                                     throttle_duration_sec=1.0)


__all__ = ["SimOutlet", "STEPPED_PUBLISH_PATIENCE_S"]
