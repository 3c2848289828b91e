"""A real camera's timing (issue 28 item 1): the share of motion periods that get an action when a robot's vision
stack publishes vision_msgs/Detection3DArray at 10 Hz into the reverse vision adapter and the policy node, under
four timing profiles: clean; stamps jittered ±6 ms around half an interval (where ``round(stamp · hz)`` flips);
that and every 7th frame dropped; that and every 4th frame delivered 250 ms late (past its period's deadline
when it is one of the period's last two).

One process on sim time: the camera here publishes ``/clock`` in steps of ``STEP_S`` and each frame when it is
delivered, and lets the adapter and the policy node take everything before the clock moves on. Their deadline
timers run on the same clock, so the figures do not depend on the machine's load. ``run_profile`` is also what
``test/test_camera_timing.py`` runs.

``dynenv-bench camera`` prints, per profile, the periods the camera's frames fell in, those answered (an Action for
the next period arrived), and the adapter's and the policy node's counts. ``--deadline -1 --epoch 0 --tolerance 0.5
--gain 0`` is the numbering and waiting of before (``round(stamp · hz)``, complete periods only), except that a
duplicate frame number now keeps the first frame instead of the last.
"""
from __future__ import annotations

import contextlib
import json
import random
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

HZ = 10.0
FRAMES_PER_PERIOD = 5
START_S = 100.0                # sim time of the camera's first frame slot
PHASE_S = 0.05                 # frames half an interval past the 100 ms grid: round(stamp · hz) flips with jitter
LATENCY_S = 0.02               # capture to delivery
STEP_S = 0.01                  # the clock's step
ROBOT = "team_a_0"


@dataclass(frozen=True)
class Profile:
    """A camera's timing: uniform stamp jitter (± s), every ``drop_every``-th frame never sent, every
    ``late_every``-th frame delivered ``late_s`` after the others."""
    name: str
    jitter_s: float = 0.0
    drop_every: int = 0
    late_every: int = 0
    late_s: float = 0.25


PROFILES = {p.name: p for p in (Profile("clean"), Profile("jitter", jitter_s=0.006),
                                Profile("jitter_drops", jitter_s=0.006, drop_every=7),
                                Profile("jitter_drops_late", jitter_s=0.006, drop_every=7, late_every=4))}


@dataclass
class Result:
    profile: str
    periods: int                       # motion periods the camera's frames fell in (adapter's numbering)
    answered: int                      # of those, periods followed by an Action for the next one
    frames_sent: int
    adapter: dict[str, int] = field(default_factory=dict)
    policy: dict[str, int] = field(default_factory=dict)

    @property
    def share(self) -> float:
        return self.answered / self.periods if self.periods else 0.0


def schedule(profile: Profile, periods: int, seed: int = 0) -> list[tuple[int, int]]:
    """(delivery ns, stamp ns) of every frame sent, in delivery order."""
    rng = random.Random(seed)
    frames = []
    for n in range(periods * FRAMES_PER_PERIOD):
        if profile.drop_every and (n + 1) % profile.drop_every == 0:
            continue
        stamp = START_S + PHASE_S + n / HZ + rng.uniform(-profile.jitter_s, profile.jitter_s)
        late = profile.late_every and (n + 1) % profile.late_every == 0
        delivery = stamp + LATENCY_S + (profile.late_s if late else 0.0)
        frames.append((round(delivery * 1e9), round(stamp * 1e9)))
    return sorted(frames)


def _frame_message(stamp_ns: int, n: int):
    """A Detection3DArray with one ball, stamped ``stamp_ns``."""
    from dynenv_msgs.msg import Detection, DetectionArray
    from geometry_msgs.msg import Point

    from dynenv_ros.perception.params import load_preset
    from dynenv_ros.ros.vision_msgs_conversion import to_vision_msgs
    ball = DetectionArray(detections=[Detection(class_id=1, position=Point(x=1.0 + 0.01 * (n % 50), y=0.2),
                                                confidence=0.9, size_x=0.1, size_y=0.1, yaw=float("nan"))])
    message = to_vision_msgs(ball, load_preset("realistic"))
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    message.header.frame_id = f"{ROBOT}/camera"
    return message


def _pose_message(stamp_ns: int):
    from builtin_interfaces.msg import Time

    from dynenv_ros.ros.pose_estimates import pose_message
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return pose_message((-1.0, 0.5, 0.1), (0.01, 0.01, 0.01), Time(sec=sec, nanosec=nanosec))


def run_profile(make_node: Callable[..., Any], executor: Any, profile: Profile, periods: int = 40, seed: int = 0,
                deadline_s: float = 0.05, adapter_params: dict[str, Any] | None = None,
                policy_params: dict[str, Any] | None = None, poses: bool = False, timeout_s: float = 120.0
                ) -> Result:
    """Run the adapter and the policy node against a camera of ``profile`` for ``periods`` motion periods.
    ``make_node(class_or_name, **options)`` and ``executor``: as test/conftest.py's fixtures. ``poses``: the
    camera's robot also publishes a pose estimate per frame (a pose-taking policy uses it)."""
    from dynenv_msgs.msg import Action, DetectionArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock
    from vision_msgs.msg import Detection3DArray

    from dynenv_ros.nodes.vision_adapter import VisionAdapter
    from dynenv_ros.ros.qos import action_stream
    from policy_node.policy_node import PolicyNode

    def params(values: dict[str, Any]) -> list[Parameter]:
        return [Parameter(k, value=v) for k, v in values.items()]

    adapter = make_node(VisionAdapter, parameter_overrides=params({
        "players_per_team": 1, "robots": [ROBOT], "reverse": True, "vision_hz": HZ,
        "frames_per_period": FRAMES_PER_PERIOD, "use_sim_time": True, **(adapter_params or {})}))
    policy = make_node(PolicyNode, parameter_overrides=params({
        "players_per_team": 1, "team": "a", "seed": 3, "decision_deadline": deadline_s, "use_sim_time": True,
        "weights_topic": "", **(policy_params or {})}))
    camera = make_node("camera")
    clock = camera.create_publisher(Clock, "/clock", 10)
    frames_out = camera.create_publisher(Detection3DArray, f"/{ROBOT}/detections_3d", 50)
    poses_out = camera.create_publisher(PoseWithCovarianceStamped, f"/{ROBOT}/pose_estimate", 50)
    actions: list[Action] = []
    frame_periods: set[int] = set()
    camera.create_subscription(Action, f"/{ROBOT}/action", actions.append, action_stream())
    camera.create_subscription(DetectionArray, f"/{ROBOT}/detections",
                               lambda m: frame_periods.add(int(m.motion_period)), 50)
    for node in (adapter, policy, camera):
        executor.add_node(node)
    give_up = time.monotonic() + timeout_s

    def spin_until(condition: Callable[[], bool], what: str) -> None:
        while not condition():
            if time.monotonic() > give_up:
                raise TimeoutError(f"camera timing: gave up waiting for {what}")
            executor.spin_once(timeout_sec=0.01)

    spin_until(lambda: frames_out.get_subscription_count() > 0 and clock.get_subscription_count() >= 2
               and camera.count_publishers(f"/{ROBOT}/action") > 0 and camera.count_publishers(
                   f"/{ROBOT}/detections") > 0 and (not poses or poses_out.get_subscription_count() > 0),
               "the nodes to match")
    plan = schedule(profile, periods, seed)
    # The localization's estimates: one per frame slot, in order and on time, whatever the camera's frames do.
    pose_plan = [round((START_S + PHASE_S + n / HZ + LATENCY_S) * 1e9) for n in range(periods * FRAMES_PER_PERIOD)]
    end = plan[-1][0] + round(FRAMES_PER_PERIOD / HZ * 1e9)      # a period more: the last deadline passes
    now, k, sent, p = round(START_S * 1e9) - round(STEP_S * 1e9), 0, 0, 0
    while now < end:
        now += round(STEP_S * 1e9)
        clock.publish(Clock(clock=_time(now)))
        spin_until(lambda: adapter.get_clock().now().nanoseconds >= now
                   and policy.get_clock().now().nanoseconds >= now, "the clock")
        while poses and p < len(pose_plan) and pose_plan[p] <= now:
            poses_out.publish(_pose_message(pose_plan[p] - round(LATENCY_S * 1e9)))
            p += 1
        while k < len(plan) and plan[k][0] <= now:
            stamp = plan[k][1]
            frames_out.publish(_frame_message(stamp, k))
            k, sent = k + 1, sent + 1
        spin_until(lambda: adapter.received >= sent, "the adapter")
        spin_until(lambda: policy.counts["frames_received"] >= adapter.converted, "the policy node")
        for _ in range(3):                   # timers due at this time (the deadline check)
            executor.spin_once(timeout_sec=0)
    targets = {int(a.motion_period) for a in actions}
    answered = sum(p + 1 in targets for p in frame_periods)
    keys = ("decisions", "actions_delayed", "actions_superseded", "periods_dropped", "periods_partial",
            "frames_missing", "frames_stale", "frames_duplicate", "pose_used", "pose_missing", "pose_stale")
    return Result(profile.name, len(frame_periods), answered, sent, adapter=dict(sorted(adapter.counts.items())),
                  policy={key: int(policy.counts.get(key, 0)) for key in keys})


def _time(ns: int):
    from builtin_interfaces.msg import Time
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


@contextlib.contextmanager
def ros_graph() -> Iterator[tuple[Callable[..., Any], Any]]:
    """(make_node, executor) in a fresh rclpy context, as test/conftest.py's fixtures give them."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    context = Context()
    rclpy.init(context=context)
    nodes: list[Node] = []

    def make_node(name_or_class: Any, **options: Any) -> Node:
        node = (Node(name_or_class, context=context, **options) if isinstance(name_or_class, str)
                else name_or_class(context=context, **options))
        nodes.append(node)
        return node

    executor = SingleThreadedExecutor(context=context)
    try:
        yield make_node, executor
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def add_arguments(parser) -> None:
    parser.add_argument("--profiles", nargs="+", choices=list(PROFILES), default=list(PROFILES))
    parser.add_argument("--periods", type=int, default=40, help="motion periods the camera runs for")
    parser.add_argument("--deadline", type=float, default=0.05, help="the policy node's decision_deadline (s; "
                        "negative: complete periods only)")
    parser.add_argument("--epoch", type=float, default=-1.0, help="the adapter's frame_epoch (s; negative: the "
                        "first stamp's phase; 0: the round(stamp·hz) numbering)")
    parser.add_argument("--tolerance", type=float, default=0.4, help="the adapter's frame_tolerance")
    parser.add_argument("--gain", type=float, default=0.05, help="the adapter's frame_phase_gain (0: a fixed grid)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="one JSON object per profile")


def run(args) -> int:
    adapter_params = {"frame_epoch": args.epoch, "frame_tolerance": args.tolerance, "frame_phase_gain": args.gain}
    for seed in range(args.seed, args.seed + args.repeat):
        for name in args.profiles:
            with ros_graph() as (make_node, executor):
                result = run_profile(make_node, executor, PROFILES[name], args.periods, seed, args.deadline,
                                     adapter_params)
            if args.json:
                print(json.dumps({**asdict(result), "share": round(result.share, 4), "seed": seed}))
            else:
                print(f"{name:18s} seed {seed}: {result.answered}/{result.periods} periods answered "
                      f"({100 * result.share:.1f} %), {result.frames_sent} frames sent; adapter "
                      f"{_nonzero(result.adapter)}; policy {_nonzero(result.policy)}")
    return 0


def _nonzero(counts: dict[str, int]) -> str:
    return " ".join(f"{k}={v}" for k, v in counts.items() if v) or "-"
