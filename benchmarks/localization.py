"""dynenv-bench localization: what the emulated self-localization (perception/localization.py) costs per motion
period, against the whole soccer env step with realistic partial observations (docs/benchmarks.md,
"Self-localization").

Per team size: the added work alone (the localization's step over the period's frames, counting each robot's
landmark sightings, flagging the world's events; each the mean of ``--calls`` calls, by wall time on one thread),
and the env step with the switch off and on (CPU time per step over ``--steps`` steps, the two interleaved,
``--repeat`` times; on a shared machine they differ by less than their spread).
"""
from __future__ import annotations

import argparse
import json
import time
from typing import Any

from benchmarks.timing import format_stat, print_table, stat


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--players-per-team", type=int, nargs="+", default=[2], choices=range(1, 6))
    parser.add_argument("--steps", type=int, default=800, help="env steps per timed run")
    parser.add_argument("--calls", type=int, default=5000, help="calls per timing of each added piece of work")
    parser.add_argument("--json", action="store_true")


def env_step_seconds(players_per_team: int, localization: bool, steps: int) -> float:
    """CPU seconds per env step (partial observations, realistic perception, random actions)."""
    from dynenv_ros.envs.robocup_v0 import parallel_env

    env = parallel_env(players_per_team=players_per_team, observation="partial")
    env.observations.localization = localization
    env.reset(seed=1)
    for k, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(k)
    actions = [{a: env.action_space(a).sample() for a in env.possible_agents} for _ in range(steps)]
    start = time.process_time()
    for action in actions:
        if not env.agents:
            env.reset()
        env.step(action)
    return (time.process_time() - start) / steps


def added_seconds(players_per_team: int, calls: int) -> tuple[float, float, float]:
    """(localization step, landmark counting, event flagging) per period, seconds."""
    import numpy as np

    from dynenv_ros.perception.params import load_preset
    from dynenv_ros.soccer.config import SoccerConfig
    from dynenv_ros.soccer.vision import SoccerVision
    from dynenv_ros.soccer.world import SoccerWorld

    world = SoccerWorld(SoccerConfig(players_per_team=players_per_team), seed=0)
    vision = SoccerVision(world, load_preset("realistic"), localization=True)
    frames = world.config.rates.frames_per_period
    for k in range(frames):
        vision.frame(k)
    perception = vision.perceive()
    n = world.n_robots
    pose, landmarks = np.zeros((frames, n, 3)), vision.landmarks_seen(perception)
    events, penalized = np.zeros((frames, n), np.uint8), np.zeros((frames, n), bool)
    out = []
    for work in (lambda: vision.localization.step(pose, landmarks, events, penalized),
                 lambda: vision.landmarks_seen(perception),
                 lambda: [vision._record_events(k) for k in range(frames)]):
        work()
        start = time.perf_counter()
        for _ in range(calls):
            work()
        out.append((time.perf_counter() - start) / calls)
    return out[0], out[1], out[2]


def measure(players_per_team: int, args: Any) -> dict[str, Any]:
    runs: dict[bool, list[float]] = {False: [], True: []}
    added: list[tuple[float, float, float]] = []
    for _ in range(args.repeat):
        for on in (False, True):
            runs[on].append(env_step_seconds(players_per_team, on, args.steps))
        added.append(added_seconds(players_per_team, args.calls))
    us = [[1e6 * a for a in row] for row in added]
    off_ms = [1e3 * s for s in runs[False]]
    return {"players_per_team": players_per_team,
            "added_us_per_period": stat([sum(row) for row in us], 1),
            "localization_step_us": stat([row[0] for row in us], 1),
            "landmark_counting_us": stat([row[1] for row in us], 1),
            "event_flagging_us": stat([row[2] for row in us], 1),
            "added_share_of_env_step_pct": stat([100 * sum(row) / (1e3 * off) for row, off in zip(us, off_ms)], 2),
            "env_step_off_ms": stat(off_ms, 3), "env_step_on_ms": stat([1e3 * s for s in runs[True]], 3)}


def run(args: Any) -> int:
    if args.steps < 1 or args.calls < 1:
        raise SystemExit("dynenv-bench localization: --steps and --calls must be at least 1")
    results = [measure(ppt, args) for ppt in args.players_per_team]
    if args.json:
        print(json.dumps({"repeat": args.repeat, "steps": args.steps, "results": results}))
        return 0
    for r in results:
        n = r["players_per_team"]
        print_table(f"dynenv-bench localization ({n}v{n}, realistic partial observations; median [min–max] of "
                    f"{args.repeat} runs)", [
            ("added per motion period", f"{format_stat(r['added_us_per_period'], '{:.1f}')} µs "
             f"({format_stat(r['added_share_of_env_step_pct'], '{:.1f}')} % of the env step)"),
            ("  localization step / landmarks / events", " / ".join(
                format_stat(r[k], "{:.1f}") for k in ("localization_step_us", "landmark_counting_us",
                                                      "event_flagging_us")) + " µs"),
            ("env step off / on (CPU ms)", f"{format_stat(r['env_step_off_ms'], '{:.3f}')} / "
             f"{format_stat(r['env_step_on_ms'], '{:.3f}')}")])
    return 0
