"""Message costs on the hot path: building, serialising and passing a vision frame's DetectionArray.

A 5v5 game at 30 Hz vision publishes 300 DetectionArrays a second; these figures say what that costs in Python.
"""
from __future__ import annotations

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from dynenv_msgs.msg import Detection, DetectionArray

from benchmarks.timing import best_rate, print_table

DETECTIONS_PER_FRAME = 12  # the original's mean at noise 1, 2v2 (facts sheet 4.2) rounded up


def vision_frame():
    frame = DetectionArray(robot_id=3, frames_per_period=5)
    frame.header.frame_id = "team_a_3/camera"
    for index in range(DETECTIONS_PER_FRAME):
        detection = Detection(class_id=Detection.CLASS_BALL, yaw=0.1 * index, size_x=0.1, size_y=0.1,
                              confidence=0.9, sighting=Detection.SIGHTING_PARTIAL)
        detection.position.x, detection.position.y = 1.0 + index, -0.5 * index
        frame.detections.append(detection)
    return frame


def pubsub_rate(count: int) -> float:
    context = Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("bench_msgs", context=context)
        received = []
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(DetectionArray, "bench", received.append, qos)
        publisher = node.create_publisher(DetectionArray, "bench", qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        frame = vision_frame()

        def work() -> int:
            received.clear()
            for _ in range(count):
                publisher.publish(frame)
                executor.spin_once(timeout_sec=0)
            while len(received) < count:
                executor.spin_once(timeout_sec=0.1)
            return count
        return best_rate(work, 1)
    finally:
        rclpy.try_shutdown(context=context)


def run(args) -> int:
    repeat = args.repeat
    frame = vision_frame()
    data = serialize_message(frame)
    build = best_rate(lambda: [vision_frame() for _ in range(2000)] and 2000, repeat)
    serialise = best_rate(lambda: [serialize_message(frame) for _ in range(5000)] and 5000, repeat)
    deserialise = best_rate(lambda: [deserialize_message(data, DetectionArray) for _ in range(5000)] and 5000, repeat)
    pubsub = max(pubsub_rate(3000) for _ in range(repeat))
    print_table(f"DetectionArray with {DETECTIONS_PER_FRAME} detections ({len(data)} B CDR), one core", [
        ("build (frames/s)", f"{build:,.0f}"),
        ("serialise (frames/s)", f"{serialise:,.0f}"),
        ("deserialise (frames/s)", f"{deserialise:,.0f}"),
        ("publish+receive, one process, reliable (frames/s)", f"{pubsub:,.0f}"),
        ("5v5 at 30 Hz needs (frames/s)", "300"),
    ])
    return 0
