"""dynenv-bench live-view: what the Foxglove live view (``live_view/``, ``foxglove_port``) costs the simulator per
vision frame, with nobody watching and with one viewer subscribed to every channel.

The frames are a real game's (soccer, realistic perception, random actions), made before the timing starts; only
``LiveView.publish_frame`` is timed, by the process's CPU time (the calling thread's encoding plus the server's own
threads that send) and by wall time. The viewer is a separate process speaking the Foxglove WebSocket protocol
(``websockets``, from the test extra), so its reading costs the simulator's process nothing; it reports the bytes and
messages it received.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from typing import Any

from benchmarks.timing import format_stat, print_table, stat

SUBPROTOCOL = "foxglove.sdk.v1"       # foxglove-sdk 0.30's name for the protocol (docs/ros_graph.md)

# The viewer: connect, subscribe to every advertised channel, count what arrives until stdin closes.
VIEWER = r"""
import json, struct, sys, threading
from websockets.sync.client import connect
url, subprotocol = sys.argv[1], sys.argv[2]
stop = threading.Event()
threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
counts = {"bytes": 0, "messages": 0, "topics": set()}
with connect(url, subprotocols=[subprotocol], open_timeout=10, max_size=None) as ws:
    channels, by_id = {}, {}
    while not channels:
        frame = ws.recv(timeout=10)
        if isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
            channels = {c["topic"]: c["id"] for c in json.loads(frame)["channels"]}
    subscriptions = [{"id": i, "channelId": cid} for i, (topic, cid) in enumerate(sorted(channels.items()))]
    by_id = {i: topic for i, (topic, _) in enumerate(sorted(channels.items()))}
    ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
    print(json.dumps({"subscribed": len(subscriptions)}), flush=True)
    while not stop.is_set():
        try:
            frame = ws.recv(timeout=0.2)
        except TimeoutError:
            continue
        if isinstance(frame, bytes):
            counts["bytes"] += len(frame)
            counts["messages"] += 1
            counts["topics"].add(by_id[struct.unpack_from("<BI", frame)[1]])
print(json.dumps({"bytes": counts["bytes"], "messages": counts["messages"], "topics": len(counts["topics"])}),
      flush=True)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=400, help="vision frames timed per phase (10 Hz: 40 sim s)")
    parser.add_argument("--players", type=int, default=2, choices=range(1, 6), help="robots per team")
    parser.add_argument("--json", action="store_true")


def _frames(players: int, count: int, seed: int) -> tuple[Any, list[str], list[tuple[Any, Any, int, int]]]:
    """``count`` vision frames of a realistic-perception game under random actions: (snapshot, robots, stamp, period)."""
    import numpy as np

    from dynenv_ros.envs.soccer_session import SoccerSession
    from dynenv_ros.perception.params import load_preset
    from dynenv_ros.soccer.config import SoccerConfig, robot_names

    config = SoccerConfig.from_mapping({"players_per_team": players})
    session = SoccerSession(config, load_preset("realistic"), seed=seed)
    session.reset(seed=seed, kickoff_team=1)
    rng = np.random.default_rng(seed)
    names = robot_names(players)
    frames, output = [], session.initial()
    while True:
        for frame in output.frames:
            stamp_ns = round(frame.tick * config.rates.tick_seconds * 1e9)
            frames.append((frame.snapshot, frame.robots, stamp_ns, output.motion_period))
            if len(frames) == count:
                return config, names, frames
        for robot in range(len(names)):
            session.submit(robot, session.episode_id, output.motion_period + 1, walk=int(rng.integers(0, 5)),
                           turn=int(rng.integers(0, 3)), kick=0, head_yaw_delta=float(rng.uniform(-0.5, 0.5)))
        output = session.step()


def _timed(view: Any, frames: list[tuple[Any, Any, int, int]]) -> tuple[float, float]:
    """(CPU ms, wall ms) per frame of publishing ``frames``."""
    cpu, wall = time.process_time(), time.perf_counter()
    for snapshot, robots, stamp_ns, period in frames:
        view.publish_frame(snapshot, robots, stamp_ns, motion_period=period)
    return ((time.process_time() - cpu) * 1e3 / len(frames), (time.perf_counter() - wall) * 1e3 / len(frames))


def measure(args: Any, seed: int) -> dict[str, float]:
    from dynenv_ros.live_view.server import LiveView

    config, names, frames = _frames(args.players, args.frames, seed)
    with LiveView(config.field, names, port=0) as view:
        idle_cpu, idle_wall = _timed(view, frames)
        viewer = subprocess.Popen([sys.executable, "-c", VIEWER, view.url, SUBPROTOCOL], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)
        try:
            line = viewer.stdout.readline()
            if not line:
                raise SystemExit("dynenv-bench live-view: the viewer process did not connect (is `websockets` "
                                 "installed? it comes with the test extra)")
            deadline = time.monotonic() + 10.0
            while not (view.ground_truth.has_sinks() and all(c.has_sinks() for c in view.detections)):
                if time.monotonic() > deadline:
                    raise SystemExit("dynenv-bench live-view: the viewer's subscriptions did not reach the server")
                time.sleep(0.01)
            watched_cpu, watched_wall = _timed(view, frames)
            time.sleep(0.5)                                  # what is still queued reaches the viewer
            out, _ = viewer.communicate("", timeout=30)
        finally:
            if viewer.poll() is None:
                viewer.kill()
    received = json.loads(out.strip().splitlines()[-1])
    return {"idle_cpu_ms": idle_cpu, "idle_wall_ms": idle_wall, "watched_cpu_ms": watched_cpu,
            "watched_wall_ms": watched_wall, "kb_per_frame": received["bytes"] / 1e3 / len(frames),
            "messages_per_frame": received["messages"] / len(frames), "topics": received["topics"]}


def run(args: Any) -> int:
    if args.frames < 1:
        raise SystemExit("dynenv-bench live-view: --frames must be at least 1")
    runs = [measure(args, seed) for seed in range(args.repeat)]
    result = {"players_per_team": args.players, "frames": args.frames, "repeat": args.repeat,
              **{key: stat([r[key] for r in runs], 3) for key in runs[0]}}
    if args.json:
        print(json.dumps(result))
        return 0
    ms = "{:.3f}"
    print_table(f"dynenv-bench live-view ({args.players}v{args.players} realistic, {args.frames} vision frames per "
                f"phase; median [min–max] of {args.repeat} runs)", [
        ("no viewer: CPU / wall ms per frame", f"{format_stat(result['idle_cpu_ms'], ms)} / {format_stat(result['idle_wall_ms'], ms)}"),
        ("one viewer, every channel: CPU / wall ms per frame",
         f"{format_stat(result['watched_cpu_ms'], ms)} / {format_stat(result['watched_wall_ms'], ms)}"),
        ("sent to the viewer per frame", f"{format_stat(result['kb_per_frame'], '{:.1f}')} kB in "
         f"{format_stat(result['messages_per_frame'], '{:.1f}')} messages ({format_stat(result['topics'], '{:.0f}')} channels)")])
    return 0
