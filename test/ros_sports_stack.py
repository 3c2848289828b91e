"""A team's ROS 2 stack for test_ros_sports_policy.py, a process of its own on the test's ROS domain: a 10 Hz camera on
the wall clock publishing hand-built soccer_vision_3d_msgs for robot team_a_0 (one array per class and frame, each
stamped with the frame's time), its joint states (head yaw 0) and the GameController's RCGCD15 on gc/data at 2 Hz.

Arguments: ``periods`` (of five frames), ``jitter_ms`` (stamps uniform within ± this), ``drop_every`` (every
n-th frame is not published at all; 0: none), ``bad`` (1: also publish, before some frames' good messages, the
messages a stack should never send: a NaN ball, a robot of team 7, a confidence of 1.5, too many balls, detections
in another frame, a GameController message with state 9; and a field boundary and obstacles, which are read and
ignored). The first frame's slot is a multiple of five (stamp ≈ slot / 10 s), so frame n is frame n mod 5 of motion
period ``first_period`` + n div 5. Prints its plan and counts as one JSON line at the end."""
from __future__ import annotations

import json
import math
import sys
import time
from collections import Counter

import numpy as np
import rclpy
from game_controller_spl_interfaces.msg import RCGCD15
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from soccer_vision_3d_msgs.msg import (Ball, BallArray, FieldBoundary, Goalpost, GoalpostArray, MarkingArray,
                                       MarkingSegment, ObstacleArray, Robot, RobotArray)

ROBOT = "team_a_0"
HZ, FRAMES = 10.0, 5


def messages(stamp_ns: int, frame_id: str = f"{ROBOT}/base_link"):
    """One frame: the ball 1.2 m ahead and a little left, an opponent, a goalpost, a field line."""
    def header(msg):
        msg.header.frame_id = frame_id
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        return msg
    ball = Ball()
    ball.center.x, ball.center.y, ball.center.z, ball.confidence.confidence = 1.2, 0.3, 0.05, 0.9
    robot = Robot()
    robot.bb.center.position.x, robot.bb.center.position.y, robot.bb.center.orientation.w = 2.5, -0.5, 1.0
    robot.bb.size.x = robot.bb.size.y = 0.3
    robot.attributes.team, robot.attributes.state, robot.confidence.confidence = 2, 1, 0.8
    post = Goalpost()
    post.bb.center.position.x, post.bb.center.position.y, post.bb.center.orientation.w = 4.0, 0.8, 1.0
    post.bb.size.x = post.bb.size.y = 0.1
    post.confidence.confidence = 0.7
    line = MarkingSegment()
    line.start.x, line.start.y, line.end.x, line.end.y = 1.0, -1.5, 1.0, 1.5
    line.confidence.confidence = 0.6
    return {"balls": header(BallArray(balls=[ball])), "robots": header(RobotArray(robots=[robot])),
            "goalposts": header(GoalpostArray(posts=[post])), "markings": header(MarkingArray(segments=[line]))}


def bad_messages(stamp_ns: int):
    """(kind, message) pairs a stack should never send; each is refused for its own reason."""
    out = []
    for kind, change in (("balls", "nan"), ("robots", "team"), ("balls", "confidence"), ("balls", "many"),
                         ("goalposts", "frame")):
        msgs = messages(stamp_ns, frame_id=f"{ROBOT}/CameraTop_frame" if change == "frame" else
                        f"{ROBOT}/base_link")
        msg = msgs[kind]
        if change == "nan":
            msg.balls[0].center.x = math.nan
        elif change == "team":
            msg.robots[0].attributes.team = 7
        elif change == "confidence":
            msg.balls[0].confidence.confidence = 1.5
        elif change == "many":
            msg.balls = [msg.balls[0]] * 300
        out.append((kind, msg))
    return out


def game(state: int = 3) -> RCGCD15:
    msg = RCGCD15(state=state, set_play=0, kicking_team=255, secs_remaining=500, players_per_team=1)
    msg.teams[0].team_number, msg.teams[1].team_number = 1, 2
    return msg


def main(periods: int, jitter_ms: float, drop_every: int, bad: bool) -> None:
    rclpy.init()
    node = rclpy.create_node("team_stack")
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE)
    kinds = ("balls", "robots", "goalposts", "markings")
    types = {"balls": BallArray, "robots": RobotArray, "goalposts": GoalpostArray, "markings": MarkingArray}
    pubs = {k: node.create_publisher(types[k], f"{ROBOT}/soccer_vision_3d/{k}", qos) for k in kinds}
    boundary = node.create_publisher(FieldBoundary, f"{ROBOT}/soccer_vision_3d/field_boundary", qos)
    obstacles = node.create_publisher(ObstacleArray, f"{ROBOT}/soccer_vision_3d/obstacles", qos)
    joints = node.create_publisher(JointState, f"{ROBOT}/joint_states", qos)
    gc_data = node.create_publisher(RCGCD15, f"{ROBOT}/gc/data", qos)
    deadline = time.monotonic() + 20.0            # the policy node subscribes
    while time.monotonic() < deadline and pubs["markings"].get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)                               # and its readers match every writer
    rng = np.random.default_rng(0)
    first_slot = (math.ceil(time.time() * HZ) // FRAMES + 1) * FRAMES
    sent: Counter[str] = Counter()
    for n in range(periods * FRAMES):
        slot = first_slot + n
        due = slot / HZ
        while (wait := due - time.time()) > 0:
            rclpy.spin_once(node, timeout_sec=min(wait, 0.01))
        if drop_every and n % drop_every == drop_every - 1:
            sent["frames_dropped"] += 1
            continue
        stamp_ns = round((due + rng.uniform(-jitter_ms, jitter_ms) / 1000.0) * 1e9)
        state = JointState(name=["HeadYaw"], position=[0.0])
        state.header.stamp.sec, state.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        joints.publish(state)
        if n % FRAMES == 0:
            if bad:
                gc_data.publish(game(state=9))
                sent["bad"] += 1
            gc_data.publish(game())
        if bad and n % FRAMES == 2:
            for kind, msg in bad_messages(stamp_ns):
                pubs[kind].publish(msg)
                sent["bad"] += 1
            boundary.publish(FieldBoundary())
            obstacles.publish(ObstacleArray())
            sent["ignored"] += 2
        for kind, msg in messages(stamp_ns).items():
            pubs[kind].publish(msg)
        sent["frames"] += 1
    end = time.monotonic() + 2.0                  # the last period's answer
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps({"first_period": first_slot // FRAMES, **sent}), flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1")
