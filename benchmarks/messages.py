"""Message costs on the hot path: building, serialising and passing a vision frame's DetectionArray.

A 5v5 game at 30 Hz vision publishes 300 DetectionArrays a second; these figures say what that costs in Python.
Each figure is frames per wall second and per CPU second, the median and [min, max] of ``--repeat`` runs
(``benchmarks/timing.py``).
"""
from __future__ import annotations

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from dynenv_msgs.msg import Detection, DetectionArray

import json

from benchmarks.timing import format_stat, measure, print_table, summarise

DETECTIONS_PER_FRAME = 12  # the original's mean at noise 1, 2v2 (docs/original.md §4.2) rounded up


def vision_frame():
    frame = DetectionArray(robot_id=3, frames_per_period=5)
    frame.header.frame_id = "team_a_3/camera"
    for index in range(DETECTIONS_PER_FRAME):
        detection = Detection(class_id=Detection.CLASS_BALL, yaw=0.1 * index, size_x=0.1, size_y=0.1,
                              confidence=0.9, sighting=Detection.SIGHTING_PARTIAL)
        detection.position.x, detection.position.y = 1.0 + index, -0.5 * index
        frame.detections.append(detection)
    return frame


def pubsub_runs(count: int, repeat: int) -> list:
    """``repeat`` runs of ``count`` frames published and received in one process (reliable, KEEP_ALL)."""
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
        return measure(work, repeat)
    finally:
        rclpy.try_shutdown(context=context)


def run(args) -> int:
    repeat = args.repeat
    frame = vision_frame()
    data = serialize_message(frame)
    figures = {"detections": DETECTIONS_PER_FRAME, "cdr_bytes": len(data), "repeat": repeat}
    for name, runs in (
            ("build", measure(lambda: [vision_frame() for _ in range(2000)] and 2000, repeat)),
            ("serialise", measure(lambda: [serialize_message(frame) for _ in range(5000)] and 5000, repeat)),
            ("deserialise", measure(lambda: [deserialize_message(data, DetectionArray) for _ in range(5000)]
                                    and 5000, repeat)),
            ("publish_receive", pubsub_runs(3000, repeat))):
        summary = summarise(runs, "frames")
        figures[name] = {"frames_per_s": summary["frames_per_s"], "frames_per_cpu_s": summary["frames_per_cpu_s"]}
    if getattr(args, "json", False):
        print(json.dumps(figures))
        return 0
    labels = {"build": "build", "serialise": "serialise", "deserialise": "deserialise",
              "publish_receive": "publish+receive, one process, reliable"}
    print_table(f"DetectionArray with {DETECTIONS_PER_FRAME} detections ({len(data)} B CDR), one core; frames/s, "
                f"median [min–max] of {repeat} runs", [
                    *((f"{label}", f"{format_stat(figures[name]['frames_per_s'])} per wall s, "
                                   f"{format_stat(figures[name]['frames_per_cpu_s'])} per CPU s")
                      for name, label in labels.items()),
                    ("5v5 at 30 Hz needs", "300")])
    return 0
