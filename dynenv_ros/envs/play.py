"""dynenv-play: a soccer game between scripted teams, or a drive of scripted cars, in-process, with a summary and
optional recordings.

    dynenv-play --players-per-team 2 --policy keeper_and_chasers --seconds 60 --gif game.gif --png-dir frames/
    dynenv-play --watch 0 --perception realistic --noise-magnitude 2 --seconds 20 --gif robot0.gif
    dynenv-play --scenario driving --cars 3 --seconds 30 --gif drive.gif
    dynenv-play --scenario driving --cars 3 --watch 0 --seconds 20 --gif car0.gif

Driving: every car is driven by the scripted lane-keeping driver (``driving.scripted.ScriptedDriver``); the GIF
shows the map top-down (``render.driving``, 3 px per metre unless --pixels-per-metre says otherwise).

Frames are taken at every vision instant (10 Hz), so the GIF plays in real time at --fps 10. With --watch, each
frame also shows that robot's field of view (driving: that car's 360° range) and its detections (red X: false
positive, red ring: confusion, white circle: in view but missed), from the --perception preset.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np

from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.scripted import act_all, team_policies
from dynenv_ros.soccer.world import SoccerWorld

POLICIES = ("keeper_and_chasers", "chaser", "random")
SCENARIOS = ("robocup", "driving")       # --scenario's choices, each with its game (GAMES)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="dynenv-play", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", choices=SCENARIOS, default="robocup")
    parser.add_argument("--players-per-team", type=int, default=2)
    parser.add_argument("--cars", type=int, default=2, help="driving: number of cars (1-10)")
    parser.add_argument("--action-mode", choices=("discrete", "continuous"), default="discrete",
                        help="driving: the action format the scripted driver answers in")
    parser.add_argument("--policy", choices=POLICIES, default="keeper_and_chasers")
    parser.add_argument("--seconds", type=float, help="game length (s; default 120 for soccer, 60 for driving)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gif", type=Path, help="write the game as an animated GIF")
    parser.add_argument("--png-dir", type=Path, help="write every frame as a PNG into this existing folder")
    parser.add_argument("--fps", type=float, default=10.0, help="GIF playback rate (10 = real time)")
    parser.add_argument("--pixels-per-metre", type=float, help="default 40 (soccer), 3 (driving)")
    parser.add_argument("--watch", type=int, help="robot (driving: car) id whose field of view and detections are drawn")
    parser.add_argument("--perception", choices=("realistic", "dynenv", "none"), default="realistic")
    parser.add_argument("--noise-magnitude", type=float, help="0..5 (default: the preset's)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    return parser.parse_args(argv)


def play(args: argparse.Namespace) -> dict:
    """The game of ``args.scenario`` played to its end (``GAMES``): its summary."""
    return GAMES[args.scenario].play(args)


def play_soccer(args: argparse.Namespace) -> dict:
    """Both teams scripted until the game ends; score, events and each robot's reward terms."""
    seconds = 120.0 if args.seconds is None else args.seconds
    if args.pixels_per_metre is None:
        args.pixels_per_metre = 40.0
    config = SoccerConfig.from_mapping({"players_per_team": args.players_per_team, "episode_seconds": seconds})
    world = SoccerWorld(config, seed=args.seed)
    policies = team_policies(config.players_per_team, args.policy, np.random.default_rng(args.seed),
                             field=config.field, motion=config.motion)
    recorder = None
    if args.gif or args.png_dir:
        from dynenv_ros.render.topdown import EpisodeRecorder
        recorder = EpisodeRecorder(config.field, pixels_per_metre=args.pixels_per_metre,
                                   ball_radius=config.ball.radius)
    watcher = _Watcher(world, args) if args.watch is not None else None
    totals = np.zeros((len(RewardTerm), config.n_robots))
    events: Counter[str] = Counter()
    while True:
        actions = act_all(policies, world.snapshot())
        if watcher is not None:
            on_frame = watcher.frame
        elif recorder is not None:
            on_frame = lambda k: recorder.add(world.snapshot())  # noqa: E731
        else:
            on_frame = None
        result = world.step(actions, on_frame=on_frame)
        if watcher is not None:
            result.rewards[RewardTerm.OBSERVATION] += watcher.end_period(recorder)
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


def play_driving(args: argparse.Namespace) -> dict:
    """Every car scripted until the episode ends; events, cars home / crashed and each car's reward terms."""
    from dynenv_ros.driving.config import DrivingConfig
    from dynenv_ros.driving.scripted import ScriptedDriver
    from dynenv_ros.driving.world import DrivingWorld
    settings = {"n_cars": args.cars, "action_mode": args.action_mode}
    if args.seconds is not None:
        settings["episode_seconds"] = args.seconds
    config = DrivingConfig.from_mapping(settings)
    world = DrivingWorld(config, seed=args.seed)
    driver = ScriptedDriver(config)
    watcher = _DrivingWatcher(world, args) if args.watch is not None else None
    recorder = None
    if args.gif or args.png_dir:
        if args.png_dir and not args.png_dir.is_dir():
            raise ValueError(f"--png-dir {args.png_dir} is not an existing folder")
        from dynenv_ros.render.driving import DrivingRecorder
        recorder = DrivingRecorder(world.map, pixels_per_metre=3.0 if args.pixels_per_metre is None
                                   else args.pixels_per_metre)
    pngs = 0

    def on_frame(k: int) -> None:
        nonlocal pngs
        snapshot = world.snapshot()
        image = recorder.add(snapshot if watcher is None else watcher.draw(recorder, snapshot))
        if args.png_dir:
            from dynenv_ros.render.topdown import save_png
            save_png(image, args.png_dir / f"frame_{pngs:05d}.png")
            pngs += 1

    if recorder is not None:
        on_frame(0)                                     # the start, before the first period
    totals = np.zeros((len(RewardTerm), config.n_cars))
    events: Counter[str] = Counter()
    result = None
    while not world.done:
        result = world.step(driver.actions(world), on_frame=on_frame if recorder is not None else None)
        totals += result.rewards
        events.update(e.kind if e.kind != "crash" else f"crash: {e.detail.split(' ')[0]}" for e in result.events)
    if recorder is not None and args.gif:
        recorder.save_gif(args.gif, fps=args.fps)
    cars = world.cars
    return {"scenario": "driving", "cars": config.n_cars, "periods": world.period,
            "seconds": round(world.game_time, 3), "home": sum(c.at_goal for c in cars),
            "crashed": sum(c.crashed for c in cars), "terminated": bool(result and result.terminated),
            "events": dict(sorted(events.items())),
            "reward_per_car": {term.name.lower(): [round(v, 3) for v in totals[term]] for term in RewardTerm},
            "frames": len(recorder) if recorder is not None else 0}


class _DrivingWatcher:
    """Perceives at every vision instant and draws one car's detections (its 360° range as a circle) over the frame.
    Perception draws from its own generator (seeded from --seed), so the drive is the same with or without --watch."""

    def __init__(self, world, args: argparse.Namespace) -> None:
        from dynenv_ros.driving.vision import DrivingVision
        from dynenv_ros.perception.driving_params import load_driving_preset
        if not 0 <= args.watch < world.n_cars:
            raise ValueError(f"--watch must be a car id in 0..{world.n_cars - 1}, got {args.watch}")
        overrides = {} if args.noise_magnitude is None else {"noise_magnitude": args.noise_magnitude}
        self.params = load_driving_preset(args.perception, **overrides)
        self.world, self.car = world, args.watch
        self.vision = DrivingVision(world, self.params, rng=np.random.default_rng([args.seed, 1]))

    def draw(self, recorder, snapshot):
        from dynenv_ros.render.driving import overlay_driving_detections
        perception = self.vision.perceive()
        v = self.car
        missed = (perception.visible[v] & ~perception.seen[v]).nonzero()[0]
        me = snapshot.objects[v]
        image = recorder.render(snapshot)
        overlay_driving_detections(image, recorder.view, (me.x, me.y, me.yaw), perception.of_view(v),
                                   truth=[(snapshot.objects[j].x, snapshot.objects[j].y) for j in missed],
                                   observer_team=self.world.cars[v].team, view_radius=self.params.view_range)
        return image


class _Watcher:
    """Perceives every period and draws one robot's view and detections onto each frame."""

    def __init__(self, world: SoccerWorld, args: argparse.Namespace) -> None:
        from dynenv_ros.perception.params import load_preset
        from dynenv_ros.soccer.vision import SoccerVision
        if not 0 <= args.watch < world.n_robots:
            raise ValueError(f"--watch must be a robot id in 0..{world.n_robots - 1}, got {args.watch}")
        overrides = {} if args.noise_magnitude is None else {"noise_magnitude": args.noise_magnitude}
        self.params = load_preset(args.perception, **overrides)
        self.world, self.robot, self.ppm = world, args.watch, args.pixels_per_metre
        self.vision = SoccerVision(world, self.params)
        self.snapshots: list = []

    def frame(self, k: int) -> None:
        self.vision.frame(k)
        self.snapshots.append(self.world.snapshot())

    def end_period(self, recorder) -> np.ndarray:
        from dynenv_ros.render.detections import field_view, missed_positions, overlay_detections
        from dynenv_ros.render.topdown import render_snapshot
        perception = self.vision.perceive()
        n, geometry = self.world.n_robots, self.world.config.field
        view = field_view(geometry, self.ppm)
        for k, snapshot in enumerate(self.snapshots):
            me = snapshot.objects[self.robot]
            v = k * n + self.robot
            x, y = self.vision.positions(k)
            image = render_snapshot(snapshot, geometry, pixels_per_metre=self.ppm,
                                    ball_radius=self.world.config.ball.radius,
                                    fov=(self.robot, self.params.field_of_view / 2))  # wedge + its legend entry
            missed = missed_positions(perception.visible[v], perception.of_view(v), self.vision.objects.object_id, x, y)
            overlay_detections(image, view, (me.x, me.y, me.yaw + me.head_yaw), perception.of_view(v), truth=missed,
                               fov_half_angle=None,
                               observer_team=me.team)
            if recorder is not None:
                recorder.frames.append(image)
        self.snapshots = []
        return self.vision.observation_rewards(perception)


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
        GAMES[args.scenario].report(summary)
    return 0


def report_soccer(summary: dict) -> None:
    """A soccer game's summary in lines: the score, the events, each robot's reward terms."""
    print(f"score {summary['score'][0]}:{summary['score'][1]} after {summary['seconds']} s")
    for kind, count in summary["events"].items():
        print(f"  {kind}: {count}")
    for term, values in summary["reward_per_robot"].items():
        print(f"  {term:<12} " + " ".join(f"{v:8.2f}" for v in values))


def report_driving(summary: dict) -> None:
    """A drive's summary in lines: cars home and crashed, the events, each car's reward terms."""
    print(f"{summary['home']} of {summary['cars']} cars home, {summary['crashed']} crashed after "
          f"{summary['seconds']} s")
    for kind, count in summary["events"].items():
        print(f"  {kind}: {count}")
    for term, values in summary["reward_per_car"].items():
        print(f"  {term:<12} " + " ".join(f"{v:8.2f}" for v in values))


class Game(NamedTuple):
    """What dynenv-play does for one ``--scenario``: play its game, and print its summary (without ``--json``)."""
    play: Callable[[argparse.Namespace], dict]
    report: Callable[[dict], None]


# The game of each --scenario choice (SCENARIOS): a new scenario adds a row.
GAMES = {"robocup": Game(play_soccer, report_soccer), "driving": Game(play_driving, report_driving)}


if __name__ == "__main__":
    sys.exit(main())
