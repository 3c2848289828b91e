#!/usr/bin/env python3
"""Does the ros-sports route change results? (issue 41, done-when): the same games played twice through the main
job's soccer graph — team A the shipped policy (or the policy file ``--team-a`` names), team B ``perceiving`` —
once on the native route (DetectionArray in, Action out) and once with ``interfaces=ros_sports`` (the simulator
publishing soccer_vision_3d_msgs, RCGCD15 and joint states, the policy node answering with twists, kick requests
and head commands, the motion emulator executing them). Same seeds, so the comparison is paired.

    .venv/bin/python tools/ros_sports_comparison.py --games 40
    .venv/bin/python tools/ros_sports_comparison.py --games 2 --duration 10 --output /tmp/check.json   # a smoke run

Each game's result is appended to ``--output`` (JSON lines: route, seed, score, periods, actions accepted, missing,
rejected) as soon as it ends, and a game already in the file is not played again, so an interrupted run resumes.
At the end it prints, per route, the mean goal difference (A − B) with its 95 % interval, wins / draws / losses, and
the paired difference (ros_sports − native) over the seeds both routes played, with its interval (normal
approximation; the games are independent draws of the world seed). Seeds come from the validation split (10,000 …;
``evaluation/splits.py``): choices are made there, never on the test split.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ROUTES = ("native", "ros_sports")
DEFAULT_OUTPUT = ROOT / "docs" / "results_data" / "issue41" / "ros_sports_vs_native.jsonl"
FIRST_SEED = 10_000          # the validation split's first seed
SHIPPED = "policy_node/pretrained/policy.onnx"     # the main job's team A by default (main_job.SHIPPED_POLICY)


def game(route: str, seed: int, duration_s: float, players: int, work: Path, team_a: str = SHIPPED) -> dict:
    """Play one game of the main job's soccer graph (team A: the policy file ``team_a``); its result from the
    simulator's report."""
    run_dir = work / f"{route}_{seed}"
    settings = {"team_a": team_a, "policy": "perceiving", "seed": seed, "duration_s": duration_s,
                "players_per_team": players, "gif": False, "interfaces": "ros_sports" if route == "ros_sports" else "dynenv",
                "timeout_s": max(600.0, 20 * duration_s), "domain_id": -2}
    command = [sys.executable, "-m", "dynenv_ros.main_job", "--output-dir", str(run_dir)]
    for key, value in settings.items():
        command += ["--set", f"{key}={json.dumps(value) if isinstance(value, bool) else value}"]
    started = time.monotonic()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    report_path = run_dir / "sim_report.json"
    result = {"route": route, "seed": seed, "duration_s": duration_s, "players_per_team": players,
              "team_a": team_a, "ok": done.returncode == 0, "wall_s": round(time.monotonic() - started, 1)}
    if report_path.exists():
        report = json.loads(report_path.read_text())
        diagnostics = report["diagnostics"]
        score = report["episode_scores"][-1] if report["episode_scores"] else None
        result.update(score_a=score[0] if score else None, score_b=score[1] if score else None,
                      periods=int(diagnostics["periods_run"]), accepted=int(diagnostics["accepted"]),
                      missing=int(diagnostics["missing"]),
                      rejected=sum(int(v) for k, v in diagnostics.items() if k.startswith("rejected_")))
    if not result["ok"]:
        result["tail"] = (done.stdout + done.stderr)[-2000:]
    return result


def interval(values: list[float]) -> tuple[float, float, float]:
    """Mean and its 95 % interval (normal approximation); the interval is the mean itself for one value."""
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, mean, mean
    half = 1.96 * statistics.stdev(values) / math.sqrt(len(values))
    return mean, mean - half, mean + half


def summary(results: list[dict]) -> str:
    lines = []
    played = {r: {g["seed"]: g for g in results if g["route"] == r and g.get("score_a") is not None}
              for r in ROUTES}
    for route in ROUTES:
        games = list(played[route].values())
        if not games:
            lines.append(f"{route}: no games")
            continue
        diff = [g["score_a"] - g["score_b"] for g in games]
        mean, low, high = interval(diff)
        wins, draws = sum(d > 0 for d in diff), sum(d == 0 for d in diff)
        lines.append(f"{route}: {len(games)} games, goal difference {mean:+.3f} a game (95 % {low:+.3f} … "
                     f"{high:+.3f}); wins / draws / losses {wins} / {draws} / {len(games) - wins - draws}; "
                     f"actions missing {sum(g['missing'] for g in games)}, rejected "
                     f"{sum(g['rejected'] for g in games)}")
    both = sorted(set(played["native"]) & set(played["ros_sports"]))
    if both:
        paired = [(played["ros_sports"][s]["score_a"] - played["ros_sports"][s]["score_b"])
                  - (played["native"][s]["score_a"] - played["native"][s]["score_b"]) for s in both]
        mean, low, high = interval(paired)
        same = sum(p == 0 for p in paired)
        lines.append(f"paired (ros_sports − native) over {len(both)} seeds: {mean:+.3f} a game (95 % {low:+.3f} … "
                     f"{high:+.3f}); the same goal difference in {same} of {len(both)} games")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--games", type=int, default=40, help="games per route (default 40)")
    parser.add_argument("--first-seed", type=int, default=FIRST_SEED, help="the first world seed (validation)")
    parser.add_argument("--duration", type=float, default=120.0, help="sim seconds per game (default 120: an "
                        "evaluation episode)")
    parser.add_argument("--players", type=int, default=2, help="robots per team (default 2)")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, help="JSON lines of per-game results "
                        "(appended; games already there are not played again)")
    parser.add_argument("--team-a", default=SHIPPED, help="team A's policy file (default: the shipped one); the "
                        "games already in --output must be of the same policy, since a game there is not played "
                        "again (each game it plays records it as team_a)")
    parser.add_argument("--summary-only", action="store_true", help="print the summary of --output and stop")
    args = parser.parse_args(argv)
    if not 1 <= args.games <= 1000 or not 0.5 <= args.duration <= 3600 or not 1 <= args.players <= 5:
        parser.error("--games 1 … 1000, --duration 0.5 … 3600, --players 1 … 5")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    results = [json.loads(line) for line in args.output.read_text().splitlines() if line.strip()] \
        if args.output.exists() else []
    if not args.summary_only:
        done = {(r["route"], r["seed"], r["duration_s"], r["players_per_team"]) for r in results if r.get("ok")}
        with tempfile.TemporaryDirectory(prefix="ros_sports_comparison_") as scratch:
            for seed in range(args.first_seed, args.first_seed + args.games):
                for route in ROUTES:
                    if (route, seed, args.duration, args.players) in done:
                        continue
                    result = game(route, seed, args.duration, args.players, Path(scratch), args.team_a)
                    results.append(result)
                    with args.output.open("a") as handle:
                        handle.write(json.dumps(result) + "\n")
                    score = f"{result.get('score_a')}:{result.get('score_b')}"
                    print(f"seed {seed} {route:<10} {score:>5} {'ok' if result['ok'] else 'FAILED'} "
                          f"({result['wall_s']:.0f} s)", flush=True)
    print(summary([r for r in results if r["duration_s"] == args.duration and
                   r["players_per_team"] == args.players]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
