"""dynenv-bench soak: the real-time graph under sustained load (issue 12), not run in CI.

A real-time 5v5 game with 30 Hz vision (physics 90 Hz, 3 ticks per frame, 0.5 s motion period), team A and team B
each driven by one learned policy node (the shipped policy; torch by default — about 0.9 s of CPU per 5-robot
decision on this machine, slower than the motion period), and the recorder, for ``--minutes``. Every
``--sample-s`` it reads the simulator's resident memory (/proc) and every node's diagnostics. It reports:

- simulator RSS growth after the warm-up (goal < 5 %), and the recorder's and policies' RSS;
- vision frames per second (30 nominal): median and worst diagnostics window;
- the share of (robot, period) slots with an accepted action, and the refusals by reason;
- the policy nodes' decisions per second, actions sent to a later period than the one after the frames they answer
  (``actions_delayed``), periods dropped as stale;
- each node's CPU time after the warm-up, as a share of one core (``/proc/<pid>/stat``).

With ``--repeat N`` the whole soak runs N times and every figure is the median and [min, max] of the runs
(``benchmarks/timing.py``; one run by default: a run lasts ``--minutes``).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

from benchmarks.timing import (combine, format_stat, print_table, process_cpu_seconds, process_rss_mib,
                               runs_in_folders)

SHIPPED = Path(__file__).resolve().parent.parent / "policy_node" / "pretrained"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the game in wall minutes")
    parser.add_argument("--warmup-s", type=float, default=60.0, help="seconds before the RSS baseline")
    parser.add_argument("--sample-s", type=float, default=10.0, help="seconds between samples")
    parser.add_argument("--players", type=int, default=5, choices=range(1, 6), help="robots per team")
    parser.add_argument("--runtime", choices=("torch", "onnxruntime"), default="torch",
                        help="runtime of both policy nodes (torch: the slow case the issue describes)")
    parser.add_argument("--keep", metavar="DIR", help="keep logs and the bag in DIR (default: a temporary dir)")
    parser.add_argument("--json", action="store_true")


def _graph(args: Any, work: Path):
    from dynenv_ros.graph.process_graph import NodeLaunch
    checkpoint = SHIPPED / ("policy.safetensors" if args.runtime == "torch" else "policy.onnx")
    sim = NodeLaunch("sim_node", "dynenv_ros.nodes.sim_node", {
        "players_per_team": args.players, "seed": 1, "mode": "realtime", "physics_hz": 90.0,
        "vision_period_ticks": 3, "motion_period_ticks": 45, "auto_reset": True, "publish_markers": False})
    policies = [NodeLaunch(f"policy_team_{team}", "policy_node.policy_node", {
        "players_per_team": args.players, "team": team, "checkpoint": str(checkpoint), "runtime": args.runtime,
        "seed": 1 + k}) for k, team in enumerate("ab")]
    recorder = NodeLaunch("recorder", "dynenv_ros.nodes.recorder", {"output": str(work / "bag")})
    return [recorder, *policies, sim]


STARTUP_TIMEOUT_S = 90.0     # from starting the nodes to the simulator's first diagnostics (2-core machine, loaded)


class _Watcher:
    """Subscribes to every node's diagnostics; keeps the latest values per node and the frame-rate series."""

    def __init__(self, domain: int) -> None:
        os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        rclpy.init()
        self.rclpy = rclpy
        self.node = rclpy.create_node("soak_watcher")
        self.latest: dict[str, dict[str, str]] = {}
        self.frame_rates: list[tuple[float, float]] = []    # (wall time, vision frames/s of one window)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        for topic, qos in (("/sim/diagnostics", 10), ("/policy_team_a/diagnostics", 10),
                           ("/policy_team_b/diagnostics", 10), ("/recorder/diagnostics", latched)):
            self.node.create_subscription(DiagnosticArray, topic, self._receiver(topic), qos)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def _receiver(self, topic: str):
        def receive(msg) -> None:
            for status in msg.status:
                values = {v.key: v.value for v in status.values}
                self.latest[topic] = values
                if topic == "/sim/diagnostics" and "vision_frames_per_s" in values:
                    self.frame_rates.append((time.monotonic(), float(values["vision_frames_per_s"])))
        return receive

    def spin_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.1, max(0.0, deadline - time.monotonic())))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def soak(args: Any, work: Path) -> dict[str, Any]:
    import subprocess

    from dynenv_ros.graph.process_graph import _stop_all, isolated_environment
    domain = 80 + os.getpid() % 10
    env = isolated_environment(domain)
    nodes = _graph(args, work)
    processes = {}
    for node in nodes:
        with (work / f"{node.name}.log").open("w") as log:
            processes[node.name] = subprocess.Popen(node.command(), env=env, stdout=log, stderr=subprocess.STDOUT)
    watcher = _Watcher(domain)
    samples: list[dict[str, float]] = []

    def check_alive() -> None:
        dead = [name for name, p in processes.items() if p.poll() is not None]
        if dead:
            raise RuntimeError(f"nodes exited during the soak: {dead} (logs in {work})")

    try:
        # The clock starts at the simulator's first diagnostics: start-up (imports, discovery) is not the soak.
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while "/sim/diagnostics" not in watcher.latest:
            if time.monotonic() > deadline:
                raise RuntimeError(f"no /sim/diagnostics within {STARTUP_TIMEOUT_S:.0f} s of starting the graph "
                                   f"(logs in {work})")
            watcher.spin_for(0.5)
            check_alive()
        started = time.monotonic()
        while time.monotonic() - started < 60 * args.minutes:
            watcher.spin_for(args.sample_s)
            check_alive()
            samples.append({"t": time.monotonic() - started,
                            **{name: process_rss_mib(p.pid) for name, p in processes.items()},
                            **{f"{name}_cpu_s": process_cpu_seconds(p.pid) for name, p in processes.items()}})
            sim = watcher.latest.get("/sim/diagnostics", {})
            print(f"[soak] {samples[-1]['t']:6.0f} s  sim RSS {samples[-1]['sim_node']:.1f} MiB  "
                  f"frames/s {sim.get('vision_frames_per_s', '?')}  accepted {sim.get('accepted', '?')}  "
                  f"periods {sim.get('periods_run', '?')}", flush=True)
        final = {topic: dict(values) for topic, values in watcher.latest.items()}
        frame_rates = [rate for t, rate in watcher.frame_rates if t - started >= args.warmup_s]
    finally:
        watcher.close()
        _stop_all(list(processes.values()))
    baseline = next(s for s in samples if s["t"] >= args.warmup_s)
    last = samples[-1]
    sim = final["/sim/diagnostics"]
    robots = 2 * args.players
    periods = int(sim["periods_run"])
    refused = {k[len("rejected_"):]: int(v) for k, v in sim.items() if k.startswith("rejected_")}
    policies = {name: {k: int(final[f"/{name}/diagnostics"].get(k, 0)) for k in (
        "decisions", "actions_sent", "periods_dropped", "actions_delayed", "actions_superseded", "fallback_actions")}
        for name in ("policy_team_a", "policy_team_b") if f"/{name}/diagnostics" in final}
    for values in policies.values():
        values["decisions_per_s"] = round(values["decisions"] / (60 * args.minutes), 2)
    recorder = final.get("/recorder/diagnostics", {})
    return {
        "players_per_team": args.players, "runtime": args.runtime, "minutes": args.minutes,
        "warmup_s": args.warmup_s, "sim_rss_mib_after_warmup": round(baseline["sim_node"], 1),
        "sim_rss_mib_end": round(last["sim_node"], 1),
        "sim_rss_growth_pct": round(100 * (last["sim_node"] / baseline["sim_node"] - 1), 2),
        "sim_rss_max_mib": round(max(s["sim_node"] for s in samples if s["t"] >= args.warmup_s), 1),
        "recorder_rss_mib": [round(baseline["recorder"], 1), round(last["recorder"], 1)],
        "policy_rss_mib": {n: [round(baseline[n], 1), round(last[n], 1)] for n in ("policy_team_a", "policy_team_b")},
        "vision_frames_per_s_median": statistics.median(frame_rates) if frame_rates else float("nan"),
        "vision_frames_per_s_min": min(frame_rates) if frame_rates else float("nan"),
        "periods_run": periods, "accepted": int(sim["accepted"]), "missing": int(sim["missing"]),
        "accepted_share": round(int(sim["accepted"]) / max(1, periods * robots), 4),
        "refused": refused, "policies": policies,
        "recorder": {k: _number(recorder.get(k)) for k in ("messages_written", "messages_dropped")},
        "cpu_share_of_one_core": {name: round((last[f"{name}_cpu_s"] - baseline[f"{name}_cpu_s"])
                                              / (last["t"] - baseline["t"]), 4) if last["t"] > baseline["t"] else 0.0
                                  for name in processes},
    }


def _number(text: Any) -> Any:
    """A diagnostics value as a number where it is one (so repeated runs combine into a median and range)."""
    try:
        return int(text)
    except (TypeError, ValueError):
        return text


def run(args: Any) -> int:
    if (min(args.minutes, args.sample_s) <= 0 or args.warmup_s < 0
            or 60 * args.minutes < args.warmup_s + args.sample_s):
        raise SystemExit(f"dynenv-bench soak: --minutes {args.minutes:g} ({60 * args.minutes:g} s) must be at least "
                         f"--warmup-s {args.warmup_s:g} plus one --sample-s {args.sample_s:g}, --minutes and "
                         "--sample-s positive (the RSS baseline is the first sample after the warm-up)")
    runs = runs_in_folders(lambda folder: soak(args, folder), args.repeat, args.keep)
    result = combine(runs, plain=("players_per_team", "minutes", "warmup_s"))
    if args.json:
        print(json.dumps(result))
    else:
        one, pct = "{:.1f}", "{:.1%}"
        policies = "; ".join(f"{n}: {format_stat(p['decisions_per_s'], '{:.2f}')} decisions/s, "
                             f"{format_stat(p['actions_delayed'])} actions delayed, "
                             f"{format_stat(p['periods_dropped'])} periods dropped"
                             for n, p in result["policies"].items())
        print_table(f"dynenv-bench soak ({result['players_per_team']}v{result['players_per_team']} real time, 30 Hz "
                    f"vision, {result['runtime']} policies, {result['minutes']:g} min; median [min–max] of "
                    f"{args.repeat} runs)", [
            ("simulator RSS after warm-up → end", f"{format_stat(result['sim_rss_mib_after_warmup'], one)} → "
             f"{format_stat(result['sim_rss_mib_end'], one)} MiB "
             f"({format_stat(result['sim_rss_growth_pct'], '{:+.2f}')} %)"),
            ("vision frames/s (median, worst window)", f"{format_stat(result['vision_frames_per_s_median'], one)}, "
             f"{format_stat(result['vision_frames_per_s_min'], one)}"),
            ("slots with an accepted action", f"{format_stat(result['accepted_share'], pct)} of "
             f"{format_stat(result['periods_run'])} periods x {2 * result['players_per_team']} robots"),
            ("refused actions", ", ".join(f"{format_stat(n)} {k}" for k, n in result["refused"].items() if n["max"])
             or "none"),
            ("policies", policies),
            ("recorder", f"{format_stat(result['recorder']['messages_written'])} written, "
             f"{format_stat(result['recorder']['messages_dropped'])} dropped"),
            ("CPU after warm-up, share of one core", ", ".join(
                f"{name} {format_stat(share, pct)}" for name, share in result["cpu_share_of_one_core"].items()))])
    return 0
