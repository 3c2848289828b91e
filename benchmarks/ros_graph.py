"""dynenv-bench ros: the simulator node as a process with a policy process (this one) driving every robot.

- stepped: real-time factor of the lockstep loop (sim seconds per wall second), 2v2 and 5v5;
- realtime: CPU share of the simulator process for 5v5 with vision at 30 Hz (physics 90 Hz, 3 ticks per frame);
- recorder: messages lost by the recorder node during a stepped 2v2 game (published vs recorded).

Beside the real-time factors, CPU time: the simulator's (the whole process, start-up included: ``getrusage`` of the
waited-for child) and the driving process's own. The four measurements run ``--repeat`` times; every figure is the
median and [min, max] of the runs (``benchmarks/timing.py``).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.timing import children_cpu_seconds, combine, format_stat, print_table, process_cpu_seconds


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    env.pop("ROS_LOCALHOST_ONLY", None)
    return env


def _launch(module: str, params: dict[str, Any], domain: int, log: Path) -> subprocess.Popen:
    args = [sys.executable, "-m", module, "--ros-args"]
    for key, value in params.items():
        literal = str(value).lower() if isinstance(value, bool) else str(value)
        args += ["-p", f"{key}:={literal}"]
    return subprocess.Popen(args, env=_env(domain), stdout=log.open("w"), stderr=subprocess.STDOUT)


def _drive(players: int, domain: int, until: callable, timeout_s: float) -> int:
    """Idle actions for every robot, sent as soon as a period's last frame arrives; returns actions sent."""
    os.environ.update(_env(domain))
    import rclpy
    from dynenv_msgs.msg import Action, DetectionArray
    from rclpy.node import Node

    from dynenv_ros.ros import topics
    from dynenv_ros.ros.qos import sim_stream
    rclpy.init()
    node = Node("bench_driver")
    from dynenv_ros.soccer.config import robot_names
    names = robot_names(players)
    pubs = [node.create_publisher(Action, topics.action(n), sim_stream()) for n in names]
    sent = [0]

    def on_frame(i: int):
        def receive(msg: DetectionArray) -> None:
            if msg.frame_index == msg.frames_per_period - 1:
                pubs[i].publish(Action(robot_id=i, episode_id=msg.episode_id, motion_period=msg.motion_period + 1))
                sent[0] += 1
        return receive

    for i, n in enumerate(names):
        node.create_subscription(DetectionArray, topics.detections(n), on_frame(i), sim_stream())
    from rclpy.executors import SingleThreadedExecutor
    executor = SingleThreadedExecutor()             # one executor: rclpy.spin_once would rebuild one per call
    executor.add_node(node)
    deadline = time.monotonic() + timeout_s
    try:
        while not until() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return sent[0]


def stepped_rtf(players: int, sim_seconds: float, domain: int, work: Path) -> dict[str, Any]:
    report = work / f"stepped_{players}.json"
    sim_cpu, driver_cpu = children_cpu_seconds(), time.process_time()
    sim = _launch("dynenv_ros.nodes.sim_node", {
        "players_per_team": players, "seed": 1, "episode_seconds": sim_seconds, "auto_reset": False,
        "exit_when_finished": True, "report_path": str(report), "publish_markers": False,
        "wait_for_subscribers": 1}, domain, work / f"sim_stepped_{players}.log")
    actions = _drive(players, domain, lambda: sim.poll() is not None, 300.0)
    driver_cpu = time.process_time() - driver_cpu
    sim.wait(timeout=60)
    sim_cpu = children_cpu_seconds() - sim_cpu               # the simulator: the only child waited for here
    diag = json.loads(report.read_text())["diagnostics"]
    return {"players_per_team": players, "sim_seconds": sim_seconds, "actions": actions,
            "real_time_factor": float(diag["real_time_factor_running"]),
            "real_time_factor_with_start_up": float(diag["real_time_factor_since_start"]),
            "sim_cpu_s": sim_cpu, "sim_seconds_per_sim_cpu_s": sim_seconds / sim_cpu, "driver_cpu_s": driver_cpu,
            "missing": int(diag["missing"])}


def realtime_cpu(players: int, wall_seconds: float, domain: int, work: Path) -> dict[str, Any]:
    sim = _launch("dynenv_ros.nodes.sim_node", {
        "players_per_team": players, "mode": "realtime", "physics_hz": 90.0, "vision_period_ticks": 3,
        "motion_period_ticks": 45, "publish_markers": False, "missing_action": "hold"},
        domain, work / f"sim_realtime_{players}.log")
    time.sleep(4.0)                                        # start-up: imports, discovery
    c0, t0 = process_cpu_seconds(sim.pid), time.monotonic()
    time.sleep(wall_seconds)
    c1, t1 = process_cpu_seconds(sim.pid), time.monotonic()
    sim.send_signal(signal.SIGINT)
    sim.wait(timeout=10)
    return {"players_per_team": players, "vision_hz": 30.0, "cpu_share_of_one_core": (c1 - c0) / (t1 - t0)}


def recorder_loss(players: int, sim_seconds: float, domain: int, work: Path) -> dict[str, Any]:
    from dynenv_ros.bags.inspect import bag_info
    bag = work / "recorder_bag"
    report = work / "recorder_sim.json"
    recorder = _launch("dynenv_ros.nodes.recorder", {"output": str(bag)}, domain, work / "recorder.log")
    sim = _launch("dynenv_ros.nodes.sim_node", {
        "players_per_team": players, "seed": 2, "episode_seconds": sim_seconds, "auto_reset": False,
        "exit_when_finished": True, "report_path": str(report), "publish_markers": False,
        "wait_for_subscribers": 2, "wait_for_recorder": True}, domain, work / "sim_recorded.log")
    _drive(players, domain, lambda: sim.poll() is not None, 300.0)
    sim.wait(timeout=30)
    recorder.send_signal(signal.SIGINT)
    recorder.wait(timeout=30)
    from dynenv_ros.main_job import missing_from_bag
    sim_report = json.loads(report.read_text())
    info = bag_info(bag)
    lost = sum(max(0, published - recorded) for published, recorded in missing_from_bag(sim_report, info).values())
    published = sum(t["count"] for t in info["topics"] if t["name"] != "/sim/diagnostics") + lost
    return {"players_per_team": players, "published": published, "lost": lost}


def run(args: Any) -> int:
    domain = 90 + os.getpid() % 10
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            work = Path(tmp) / str(k)
            work.mkdir()
            runs.append([stepped_rtf(2, args.sim_seconds, domain, work), stepped_rtf(5, args.sim_seconds, domain, work),
                         realtime_cpu(5, args.wall_seconds, domain, work),
                         recorder_loss(2, args.sim_seconds, domain, work)])
    rows = [combine([run[i] for run in runs], plain=("players_per_team", "sim_seconds", "vision_hz"))
            for i in range(4)]
    if args.json:
        print(json.dumps(rows))
    else:
        def rtf(row: dict[str, Any]) -> str:
            return (f"{format_stat(row['real_time_factor'], '{:.1f}')}x "
                    f"({format_stat(row['real_time_factor_with_start_up'], '{:.1f}')}x counting start-up; "
                    f"{format_stat(row['sim_seconds_per_sim_cpu_s'], '{:.1f}')} sim s per simulator CPU s, start-up "
                    f"included)")
        print_table(f"dynenv-bench ros (median [min–max] of {args.repeat} runs)", [
            ("stepped 2v2 real-time factor", rtf(rows[0])),
            ("stepped 5v5 real-time factor", rtf(rows[1])),
            ("realtime 5v5 @30 Hz vision, sim CPU",
             f"{format_stat({k: 100 * v for k, v in rows[2]['cpu_share_of_one_core'].items() if k != 'runs'}, '{:.1f}')}"
             f" % of a core"),
            ("recorder loss (2v2 stepped)", f"{format_stat(rows[3]['lost'])} of {format_stat(rows[3]['published'])}")])
    return 0
