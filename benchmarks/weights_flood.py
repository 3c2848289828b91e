"""dynenv-bench weights-flood: what a process flooding the weights announcement topic with oversized raw samples does
to a policy node that follows signed weights (issue 27; docs/ros_graph.md, "Signed weights").

A real-time 1v1 game: the simulator, a learned-policy node for team A (``policy_node``, torch runtime, trusting a
trainer key made for the run) and a scripted policy for team B. After a calm phase, a second process publishes
``--megabytes`` of raw bytes on the announcement topic every second — a sample claiming a run id of that length, which
DDS must reassemble before the message type's bound could refuse it — then stops. Per phase: the policy node's
resident memory (before the flood, its peak during it, after), the share of (robot, period) slots with an accepted
action (does the node keep answering?), and the simulator's frame rate. ``--profiles off`` starts the policy node
with Fast DDS profiles of the user's choosing that bound nothing (an empty profiles file), to show what the shipped
profiles (``ros/fastdds_bounded.xml``) prevent.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.flood import Probe, phase_figures
from benchmarks.timing import (combine, format_stat, print_table, process_cpu_seconds, process_rss_mib,
                               runs_in_folders)

FLOOD_REPEAT_S = 1.0        # one oversized sample a second: handing 300 MB to DDS takes this machine most of that
EMPTY_PROFILES = """<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"><profiles/></dds>
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calm-s", type=float, default=15.0, help="seconds before and after the flood")
    parser.add_argument("--flood-s", type=float, default=20.0, help="seconds of flooding")
    parser.add_argument("--megabytes", type=float, default=300.0, help="size of each flooding sample, MB")
    parser.add_argument("--profiles", choices=("on", "off"), default="on",
                        help="off: the policy node runs with empty Fast DDS profiles (nothing bounded)")
    parser.add_argument("--keep", metavar="DIR", help="keep the nodes' logs in DIR (default: a temporary dir)")
    parser.add_argument("--json", action="store_true")


def oversized_announcement(size: int) -> bytes:
    """Raw CDR bytes of a WeightsAnnouncement whose run_id claims ``size`` characters (and has them): the stamp, an
    empty frame_id, then the run id. Far above the type's bound (128), so only DDS can refuse it before rclpy."""
    from dynenv_msgs.msg import WeightsAnnouncement
    from rclpy.serialization import serialize_message

    header = serialize_message(WeightsAnnouncement())[:4]              # the CDR encapsulation
    return header + bytes(8) + (1).to_bytes(4, "little") + bytes(4) + size.to_bytes(4, "little") + b"r" * size


def flood(seconds: float, megabytes: float) -> None:
    """The flooding process: one oversized sample a second on the announcement topic; prints how many it sent."""
    import rclpy
    from dynenv_msgs.msg import WeightsAnnouncement

    from dynenv_ros.ros import topics
    from dynenv_ros.ros.qos import latched
    rclpy.init()
    node = rclpy.create_node(f"weights_flooder_{os.getpid()}")
    publisher = node.create_publisher(WeightsAnnouncement, topics.WEIGHTS_ANNOUNCEMENT, latched(1))
    sample, published = oversized_announcement(int(megabytes * 1_000_000)), 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        started = time.monotonic()
        publisher.publish(sample)
        published += 1
        rclpy.spin_once(node, timeout_sec=max(0.0, FLOOD_REPEAT_S - (time.monotonic() - started)))
    print(json.dumps({"published": published, "seconds": seconds}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


class _PeakMemory:
    """The highest RSS of a process, sampled every 50 ms on a thread of its own while the block runs."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak, self._stop = pid, process_rss_mib(pid), threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.wait(0.05):
            self.peak = max(self.peak, process_rss_mib(self.pid))

    def __enter__(self) -> "_PeakMemory":
        self._thread.start()
        return self

    def __exit__(self, *_: Any) -> None:
        self._stop.set()
        self._thread.join()


def measure(args: Any, work: Path) -> dict[str, Any]:
    from dynenv_ros.graph.process_graph import NodeLaunch, _stop_all, isolated_environment
    from dynenv_ros.security.keys import generate_key_pair
    domain = 60 + os.getpid() % 10
    env = isolated_environment(domain)
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    _, public = generate_key_pair(work / "keys")
    policy_env = dict(env)
    if args.profiles == "off":
        (work / "empty_profiles.xml").write_text(EMPTY_PROFILES)
        policy_env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(work / "empty_profiles.xml")
    nodes = [(NodeLaunch("sim_node", "dynenv_ros.nodes.sim_node", {
                 "players_per_team": 1, "seed": 1, "mode": "realtime", "auto_reset": True, "publish_markers": False,
                 "missing_action": "none"}), env),
             (NodeLaunch("policy_node", "policy_node.policy_node", {
                 "players_per_team": 1, "team": "a", "trusted_weights_keys": [str(public)]}), policy_env),
             (NodeLaunch("policy_team_b_0", "policy_node.scripted_policy", {"robot": "team_b_0", "policy": "chaser"}),
              env)]
    processes = []
    for node, node_env in nodes:
        with (work / f"{node.name}.log").open("w") as log:
            processes.append(subprocess.Popen(node.command(), env=node_env, stdout=log, stderr=subprocess.STDOUT))
    probe = Probe()
    sim_pid, policy_pid = processes[0].pid, processes[1].pid

    def phase(seconds: float) -> dict[str, Any]:
        latencies: list[float] = []
        start, cpu = time.monotonic(), process_cpu_seconds(sim_pid)
        with _PeakMemory(policy_pid) as memory:
            probe.spin(seconds, latencies)
        end, cpu, rss_end = time.monotonic(), process_cpu_seconds(sim_pid) - cpu, process_rss_mib(policy_pid)
        probe.counters(after=end, timeout=10.0)
        figures = phase_figures(probe, start, end, latencies, cpu)
        return {"policy_rss_mb_end": round(rss_end, 1), "policy_rss_mb_peak": round(max(memory.peak, rss_end), 1),
                **{k: figures[k] for k in ("periods", "accepted_share", "frames_per_s")}}
    try:
        probe.spin(10.0, [])                                  # start-up (torch), discovery
        probe.counters(after=0.0, timeout=20.0)
        if any(p.poll() is not None for p in processes):
            raise RuntimeError(f"a node exited during start-up (logs in {work})")
        phases = {"before": phase(args.calm_s)}
        flooder = subprocess.Popen([sys.executable, "-m", "benchmarks.weights_flood", "--flood-process",
                                    str(args.flood_s), str(args.megabytes)], env=env, stdout=subprocess.PIPE,
                                   text=True)
        phases["flood"] = phase(args.flood_s)
        report = json.loads(flooder.communicate(timeout=120)[0].strip().splitlines()[-1])
        phases["after"] = phase(args.calm_s)
        if processes[1].poll() is not None:
            raise RuntimeError(f"the policy node exited during the flood (logs in {work})")
    finally:
        probe.close()
        _stop_all(processes)
    baseline = phases["before"]["policy_rss_mb_end"]
    return {"profiles": args.profiles, "megabytes": args.megabytes, "samples_published": report["published"],
            "policy_rss_growth_mb": round(phases["flood"]["policy_rss_mb_peak"] - baseline, 1), **phases}


def run(args: Any) -> int:
    if min(args.calm_s, args.flood_s, args.megabytes) <= 0:
        raise SystemExit("dynenv-bench weights-flood: --calm-s, --flood-s and --megabytes must be positive")
    runs = runs_in_folders(lambda folder: measure(args, folder), args.repeat, args.keep)
    result = combine(runs, plain=("profiles", "megabytes"))
    if args.json:
        print(json.dumps(result))
        return 0
    rows = [("flood", f"{format_stat(result['samples_published'])} samples of {result['megabytes']:g} MB, one a "
                      f"second; Fast DDS profiles {result['profiles']}"),
            ("policy node RSS: growth during the flood",
             f"{format_stat(result['policy_rss_growth_mb'], '{:+.1f}')} MB")]
    for phase in ("before", "flood", "after"):
        p = result[phase]
        rows.append((f"{phase}: policy node RSS end / peak", f"{format_stat(p['policy_rss_mb_end'], '{:.1f}')} / "
                     f"{format_stat(p['policy_rss_mb_peak'], '{:.1f}')} MB"))
        rows.append((f"{phase}: accepted slots, frames/s", f"{format_stat(p['accepted_share'], '{:.1%}')} of "
                     f"{format_stat(p['periods'])} periods x 2, {format_stat(p['frames_per_s'], '{:.1f}')} frames/s"))
    print_table(f"dynenv-bench weights-flood (real-time 1v1, learned policy for team A; median [min–max] of "
                f"{args.repeat} runs)", rows)
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--flood-process"]:
        flood(float(sys.argv[2]), float(sys.argv[3]))
