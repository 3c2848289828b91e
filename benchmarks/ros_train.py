"""dynenv-bench ros-train: the trainer node's throughput over ROS (issue 13), not run in CI.

For each number of games (``--games``, default 1 2 4): that many stepped games (``--players`` per team, each with
its policy node playing both teams with the trainer's weights) and one trainer node — the main job's train graph
(``graph/train_graph.py``, its trainer settings) without the recorder — for ``--minutes`` of wall time. Reports
from the trainer's summary:

- experience reaching the learner: robot-periods assembled into sequences per second, and those learnt from;
- learner updates per second, the policy lag at the last update;
- what was lost or dropped: missing periods, late / duplicate / malformed messages, sequences dropped as stale
  (older than ``max_policy_lag`` versions), queue overflow.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path
from types import SimpleNamespace
from typing import Any



def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--games", type=int, nargs="+", default=[1, 2, 4], help="numbers of games to measure")
    parser.add_argument("--players", type=int, default=2, choices=range(1, 6), help="robots per team")
    parser.add_argument("--minutes", type=float, default=2.0, help="trainer wall minutes per measurement")
    parser.add_argument("--keep", metavar="DIR", help="keep logs and run directories in DIR")
    parser.add_argument("--json", action="store_true")


def measure(games: int, args: Any, work: Path) -> dict[str, Any]:
    from dynenv_ros.graph.process_graph import run_graph
    from dynenv_ros.graph.train_graph import train_graph
    # train_updates 0: no update budget, the trainer runs for --minutes of wall time (what is measured)
    config = SimpleNamespace(players_per_team=args.players, seed=0, perception="realistic", games=games,
                             train_updates=0, train_minutes=args.minutes, episode_seconds=10.0)
    nodes = [n for n in train_graph(config, work) if n.name != "recorder"]
    outcome = run_graph(nodes, work, 1 + (os.getpid() + games) % 100, 60.0 * args.minutes + 120.0)
    summary = json.loads((work / "trainer" / "summary.json").read_text())
    diag = summary["diagnostics"]
    wall = float(summary["wall_seconds"])
    return {"games": games, "robots": int(diag["robots"]), "ok": outcome.ok, "wall_s": round(wall, 1),
            "assembled_per_s": round(int(diag["steps"]) / wall, 1),
            "learnt_per_s": round(summary["env_steps"] / wall, 1),
            "updates_per_s": round(summary["updates"] / wall, 3),
            "lag_versions": float(diag["lag_versions_mean"]), "lag_s": float(diag["lag_seconds_mean"]),
            "missing": int(diag["missing"]), "late": int(diag["late"]), "duplicate": int(diag["duplicate"]),
            "malformed": int(diag["malformed"]), "stale_sequences": int(diag.get("stale_sequences", 0)),
            "queue_dropped": int(diag.get("queue_dropped", 0)), "sequences": int(diag["sequences"])}


def run(args: argparse.Namespace) -> int:
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        base = Path(args.keep or scratch)
        for games in args.games:
            rows.append(measure(games, args, base / f"games_{games}"))
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print(f"trainer node over ROS: stepped {args.players}v{args.players} games, {args.minutes:g} wall min each")
    header = ["games", "robots", "assembled/s", "learnt/s", "updates/s", "lag (versions, s)", "missing",
              "late+dup+malformed", "stale seq.", "queue dropped"]
    table = [[str(v) for v in (r["games"], r["robots"], r["assembled_per_s"], r["learnt_per_s"], r["updates_per_s"],
                               f"{r['lag_versions']:.1f}, {r['lag_s']:.1f}", r["missing"],
                               r["late"] + r["duplicate"] + r["malformed"],
                               f"{r['stale_sequences']}/{r['sequences']}", r["queue_dropped"])] for r in rows]
    widths = [max(len(h), *(len(row[i]) for row in table)) for i, h in enumerate(header)]
    for row in [header, *table]:
        print("  ".join(cell.rjust(w) for cell, w in zip(row, widths)))
    return 0
