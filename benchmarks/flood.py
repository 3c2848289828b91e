"""dynenv-bench flood: what two publishers flooding a robot's action topic do to a real-time game (issue 12).

A real-time 1v1 game (10 Hz vision, 0.5 s motion period) with a scripted policy node per robot. After a calm
phase, two extra processes publish refused actions (walk = 99) on /team_a_0/action as fast as they can; then they
stop. In each phase the benchmark reports the share of (robot, period) slots with an accepted action — does the
legitimate policy keep control? — the simulator's frame rate, and the round-trip time of a service of the
simulator (its get_parameters) called every 0.2 s — are services delayed? — and the simulator's CPU time as a
share of one core (``/proc/<pid>/stat``: what the flood costs it, whoever else shares the machine). With
``--repeat N`` the whole measurement runs N times and every figure is the median and [min, max] of the runs
(``benchmarks/timing.py``; one run by default).
"""
from __future__ import annotations

import argparse
import json
import os
import os as _os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.timing import combine, format_stat, print_table, process_cpu_seconds, runs_in_folders


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calm-s", type=float, default=20.0, help="seconds before and after the flood")
    parser.add_argument("--flood-s", type=float, default=30.0, help="seconds of flooding")
    parser.add_argument("--flooders", type=int, default=2, help="flooding processes")
    parser.add_argument("--keep", metavar="DIR", help="keep the nodes' logs in DIR (default: a temporary dir)")
    parser.add_argument("--json", action="store_true")


def flood(seconds: float) -> None:
    """The flooding process: refused actions for team_a_0 at full speed; prints how many it sent."""
    import rclpy
    from dynenv_msgs.msg import Action

    from dynenv_ros.ros.qos import sim_stream
    rclpy.init()
    node = rclpy.create_node(f"flooder_{os.getpid()}")
    publisher = node.create_publisher(Action, "/team_a_0/action", sim_stream())
    deadline = time.monotonic() + 2.0
    while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    message, sent = Action(robot_id=0, episode_id=1, motion_period=1, walk=99), 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            publisher.publish(message)
            sent += 1
        except Exception:      # a writer that cannot keep up refuses: a flood does not care
            pass
    print(json.dumps({"sent": sent, "seconds": seconds}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


class Probe:
    """Calls the simulator's get_parameters service every 0.2 s and keeps its diagnostics."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import GetParameters
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init()
        self.rclpy, self.GetParameters = rclpy, GetParameters
        self.node = rclpy.create_node("flood_probe")
        self.client = self.node.create_client(GetParameters, _os.environ.get("XSRV", "/sim_node/get_parameters"))
        self.diagnostics: list[tuple[float, dict[str, str]]] = []
        self.node.create_subscription(DiagnosticArray, "/sim/diagnostics", lambda m: self.diagnostics.extend(
            (time.monotonic(), {v.key: v.value for v in s.values}) for s in m.status), 10)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def spin(self, seconds: float, latencies: list[float]) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            sent = time.monotonic()
            future = self.client.call_async(self.GetParameters.Request(names=["real_time_factor"]))
            while not future.done() and time.monotonic() - sent < 5.0:
                self.executor.spin_once(timeout_sec=0.01)
            latencies.append(1000 * (time.monotonic() - sent) if future.done() else 5000.0)
            pause = sent + 0.2 - time.monotonic()
            while pause > 0:
                self.executor.spin_once(timeout_sec=pause)
                pause = sent + 0.2 - time.monotonic()

    def counters(self, after: float, timeout: float) -> None:
        """Spins until the simulator has sent its counters after `after`: a short phase on a loaded machine may
        hold no diagnostics message of its own (they come about once a second)."""
        deadline = time.monotonic() + timeout
        while not any(t > after and "accepted" in d for t, d in self.diagnostics) and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def phase_figures(probe: Probe, start: float, end: float, latencies: list[float], sim_cpu_s: float) -> dict[str, Any]:
    """The counters' change from the last message before the phase to the first one after it (the phase's own
    messages in between give the frame rate)."""
    counted = [(t, d) for t, d in probe.diagnostics if "accepted" in d]
    before = [(t, d) for t, d in counted if t <= start][-1:]
    after = [(t, d) for t, d in counted if t > end][:1]
    own = [(t, d) for t, d in counted if start < t <= end]
    window = before + own + after
    if len(window) < 2:
        raise RuntimeError(f"the simulator sent {len(window)} diagnostics message(s) around a "
                           f"{end - start:.1f}-s phase; its counters need one before and one after")
    first, last = window[0][1], window[-1][1]
    periods = int(last["periods_run"]) - int(first["periods_run"])
    accepted = int(last["accepted"]) - int(first["accepted"])
    refused = sum(int(last[k]) - int(first[k]) for k in last if k.startswith("rejected_"))
    ordered = sorted(latencies)
    return {"periods": periods, "accepted_share": round(accepted / max(1, 2 * periods), 3), "refused": refused,
            "frames_per_s": statistics.median(float(d["vision_frames_per_s"]) for _, d in (own or window)),
            "service_ms_median": round(statistics.median(ordered), 2),
            "service_ms_p99": round(ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))], 2),
            "service_ms_max": round(ordered[-1], 2), "sim_cpu_share_of_one_core": round(sim_cpu_s / (end - start), 4)}


def measure(args: Any, work: Path) -> dict[str, Any]:
    from dynenv_ros.graph.process_graph import NodeLaunch, _stop_all, isolated_environment
    domain = 70 + os.getpid() % 10
    env = isolated_environment(domain)
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    nodes = [NodeLaunch("sim_node", "dynenv_ros.nodes.sim_node", {
        "players_per_team": 1, "seed": 1, "mode": "realtime", "auto_reset": True, "publish_markers": False,
        "missing_action": "none"})]
    nodes += [NodeLaunch(f"policy_{r}", "policy_node.scripted_policy", {"robot": r, "policy": "chaser"})
              for r in ("team_a_0", "team_b_0")]
    processes = []
    for node in nodes:
        with (work / f"{node.name}.log").open("w") as log:
            processes.append(subprocess.Popen(node.command(), env=env, stdout=log, stderr=subprocess.STDOUT))
    probe = Probe()
    sim_pid = processes[0].pid

    def phase(seconds: float) -> dict[str, Any]:
        latencies: list[float] = []
        start, cpu = time.monotonic(), process_cpu_seconds(sim_pid)
        probe.spin(seconds, latencies)
        end, cpu = time.monotonic(), process_cpu_seconds(sim_pid) - cpu
        probe.counters(after=end, timeout=10.0)
        return phase_figures(probe, start, end, latencies, cpu)
    try:
        probe.spin(5.0, [])                                   # start-up and discovery
        probe.counters(after=0.0, timeout=20.0)
        phases = {"before": phase(args.calm_s)}
        flooders = [subprocess.Popen([sys.executable, "-m", "benchmarks.flood", "--flood-process",
                                      str(args.flood_s)], env=env, stdout=subprocess.PIPE, text=True)
                    for _ in range(args.flooders)]
        phases["flood"] = phase(args.flood_s)
        sent = [json.loads(f.communicate(timeout=60)[0].strip().splitlines()[-1])["sent"] for f in flooders]
        phases["after"] = phase(args.calm_s)
    finally:
        probe.close()
        _stop_all(processes)
    return {"flooders": args.flooders, "flood_messages_per_s": round(sum(sent) / args.flood_s), **phases}


def run(args: Any) -> int:
    runs = runs_in_folders(lambda folder: measure(args, folder), args.repeat, args.keep)
    result = combine(runs, plain=("flooders",))
    if args.json:
        print(json.dumps(result))
        return 0
    rows = [("flood", f"{result['flooders']} processes, {format_stat(result['flood_messages_per_s'])} refused "
                      f"actions/s sent")]
    for phase in ("before", "flood", "after"):
        p = result[phase]
        rows.append((f"{phase}: accepted slots, frames/s", f"{format_stat(p['accepted_share'], '{:.1%}')} of "
                     f"{format_stat(p['periods'])} periods x 2, {format_stat(p['frames_per_s'], '{:.1f}')} frames/s, "
                     f"{format_stat(p['refused'])} refused"))
        rows.append((f"{phase}: service round trip", f"median {format_stat(p['service_ms_median'], '{:.2f}')} ms, p99 "
                     f"{format_stat(p['service_ms_p99'], '{:.2f}')} ms, max {format_stat(p['service_ms_max'], '{:.2f}')}"
                     f" ms"))
        rows.append((f"{phase}: simulator CPU", f"{format_stat(p['sim_cpu_share_of_one_core'], '{:.1%}')} of a core"))
    print_table(f"dynenv-bench flood (real-time 1v1, scripted policies; median [min–max] of {args.repeat} runs)", rows)
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--flood-process"]:
        flood(float(sys.argv[2]))
