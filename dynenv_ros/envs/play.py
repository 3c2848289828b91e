"""dynenv-play: a soccer game between scripted teams, in-process, with a summary and optional recordings.

    dynenv-play --players-per-team 2 --policy keeper_and_chasers --seconds 60 --gif game.gif --png-dir frames/

Frames are taken at every vision instant (10 Hz), so the GIF plays in real time at --fps 10.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Sequence

import numpy as np

from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.scripted import act_all, team_policies
from dynenv_ros.soccer.world import SoccerWorld

POLICIES = ("keeper_and_chasers", "chaser", "random")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="dynenv-play", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--players-per-team", type=int, default=2)
    parser.add_argument("--policy", choices=POLICIES, default="keeper_and_chasers")
    parser.add_argument("--seconds", type=float, default=120.0, help="game length (s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gif", type=Path, help="write the game as an animated GIF")
    parser.add_argument("--png-dir", type=Path, help="write every frame as a PNG into this existing folder")
    parser.add_argument("--fps", type=float, default=10.0, help="GIF playback rate (10 = real time)")
    parser.add_argument("--pixels-per-metre", type=float, default=40.0)
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    return parser.parse_args(argv)


def play(args: argparse.Namespace) -> dict:
    config = SoccerConfig.from_mapping({"players_per_team": args.players_per_team, "episode_seconds": args.seconds})
    world = SoccerWorld(config, seed=args.seed)
    policies = team_policies(config.players_per_team, args.policy, np.random.default_rng(args.seed),
                             field=config.field, motion=config.motion)
    recorder = None
    if args.gif or args.png_dir:
        from dynenv_ros.render.topdown import EpisodeRecorder
        recorder = EpisodeRecorder(config.field, pixels_per_metre=args.pixels_per_metre,
                                   ball_radius=config.ball.radius)
    totals = np.zeros((len(RewardTerm), config.n_robots))
    events: Counter[str] = Counter()
    while True:
        actions = act_all(policies, world.snapshot())
        on_frame = (lambda k: recorder.add(world.snapshot())) if recorder is not None else None
        result = world.step(actions, on_frame=on_frame)
        totals += result.rewards
        events.update(e.kind if e.kind != "penalty" else f"penalty: {e.detail.split(' (')[0]}"
                      for e in result.events if e.kind != "touch")
        if result.truncated or result.terminated:
            break
    if recorder is not None:
        if args.gif:
            recorder.save_gif(args.gif, fps=args.fps)
        if args.png_dir:
            from dynenv_ros.render.topdown import save_png
            if not args.png_dir.is_dir():
                raise ValueError(f"--png-dir {args.png_dir} is not an existing folder")
            for k, frame in enumerate(recorder.frames):
                save_png(frame, args.png_dir / f"frame_{k:05d}.png")
    return {"score": [world.state.score[1], world.state.score[-1]], "periods": world.period,
            "seconds": round(world.game_time, 3), "events": dict(sorted(events.items())),
            "reward_per_robot": {term.name.lower(): [round(v, 3) for v in totals[term]] for term in RewardTerm},
            "frames": len(recorder) if recorder is not None else 0}


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        summary = play(args)
    except ValueError as exc:
        print(f"dynenv-play: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"score {summary['score'][0]}:{summary['score'][1]} after {summary['seconds']} s")
        for kind, count in summary["events"].items():
            print(f"  {kind}: {count}")
        for term, values in summary["reward_per_robot"].items():
            print(f"  {term:<12} " + " ".join(f"{v:8.2f}" for v in values))
    return 0


if __name__ == "__main__":
    sys.exit(main())
