"""What the emulated self-localization (perception/localization.py) costs per motion period, against the whole
soccer env step with realistic partial observations (docs/benchmarks.md, "Self-localization").

    taskset -c 1 .venv/bin/python tools/localization_timing.py --players-per-team 2 5

Per team size: the added work alone (the localization's step over the period's 5 frames, counting each robot's
landmark sightings, flagging the world's events; each the mean of many calls), and the env step with the switch off
and on (CPU time per step, median of --repeat interleaved runs of --steps steps; on a shared machine the two differ
by less than their spread).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from dynenv_ros.envs.robocup_v0 import parallel_env  # noqa: E402
from dynenv_ros.perception.params import load_preset  # noqa: E402
from dynenv_ros.soccer.config import SoccerConfig  # noqa: E402
from dynenv_ros.soccer.vision import SoccerVision  # noqa: E402
from dynenv_ros.soccer.world import SoccerWorld  # noqa: E402


def env_step_seconds(players_per_team: int, localization: bool, steps: int) -> float:
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


def added_seconds(players_per_team: int, calls: int = 5000) -> tuple[float, float, float]:
    """(localization step, landmark counting, event flagging) per period, seconds."""
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
    return tuple(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--players-per-team", type=int, nargs="+", default=[2])
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--repeat", type=int, default=4)
    args = parser.parse_args(argv)
    for ppt in args.players_per_team:
        runs: dict[bool, list[float]] = {False: [], True: []}
        for _ in range(args.repeat):
            for on in (False, True):
                runs[on].append(env_step_seconds(ppt, on, args.steps))
        off, on = float(np.median(runs[False])), float(np.median(runs[True]))
        step, count, flag = added_seconds(ppt)
        added = step + count + flag
        print(f"{ppt}v{ppt}: added {added * 1e6:.1f} µs per period (step {step * 1e6:.1f}, landmarks "
              f"{count * 1e6:.1f}, events {flag * 1e6:.1f}) = {100 * added / off:.1f} % of the env step; env step "
              f"off {off * 1e3:.3f} ms [{min(runs[False]) * 1e3:.3f}, {max(runs[False]) * 1e3:.3f}], on "
              f"{on * 1e3:.3f} ms [{min(runs[True]) * 1e3:.3f}, {max(runs[True]) * 1e3:.3f}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
