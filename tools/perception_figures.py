#!/usr/bin/env python3
"""Pictures of the perception model for the docs: one fixed 2v2 scene seen by robot 0 under each preset.

Usage: ``.venv/bin/python tools/perception_figures.py [--out docs/images]``

Robot 0 (team A, blue) looks from its own half toward the ball and the goal it attacks; an opponent stands partly in
its line of sight, the opponent keeper stands in the goal. The world runs one motion period with every robot idle
(falls disabled), and robot 0's detections of all five vision frames of that period are drawn onto one picture, so
the spread of position errors and the rarer misses and false positives show together. For each noisy preset the
world seed is the first one from 0 whose period shows the errors that picture is meant to show (deterministic: the
same seeds every run); the caption names it.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from PIL import Image, ImageDraw, ImageFont  # noqa: E402

from dynenv_ros.perception.model import Perception  # noqa: E402
from dynenv_ros.perception.params import PerceptionParams, load_preset  # noqa: E402
from dynenv_ros.render.detections import (field_view, missed_positions,  # noqa: E402
                                          overlay_detections)
from dynenv_ros.render.topdown import STRIP, TEXT, render_snapshot, save_png  # noqa: E402
from dynenv_ros.soccer.actions import IDLE  # noqa: E402
from dynenv_ros.soccer.config import SoccerConfig  # noqa: E402
from dynenv_ros.soccer.vision import SoccerVision  # noqa: E402
from dynenv_ros.soccer.world import SoccerWorld  # noqa: E402

PIXELS_PER_METRE = 50
OBSERVER = 0
MAX_SEEDS = 500
# (x, y, body yaw) per robot: 0, 1 team A (blue, attacks +x); 2, 3 team B (red). Robot 0's head turns right so its
# camera looks along 0.15 rad: the ball, the opponent in front of it and the goal at x = 4.5 are all in view.
POSES = ((0.8, -0.6, 0.45), (-1.6, 1.4, 0.0), (2.0, -0.5, math.pi), (4.1, 0.15, math.pi))
HEAD_YAW = -0.3
BALL = (2.7, -0.15)


@dataclass(frozen=True)
class Figure:
    filename: str
    title: str
    preset: str
    noise_magnitude: float | None = None
    needs_errors: bool = True          # a miss and a false positive must show
    needs_confusion: bool = False


FIGURES = (
    Figure("perception_none.png", "none (exact)", "none", needs_errors=False),
    Figure("perception_realistic.png", "realistic, magnitude 1", "realistic", 1.0),
    Figure("perception_realistic_m3.png", "realistic, magnitude 3", "realistic", 3.0, needs_confusion=True),
    Figure("perception_dynenv.png", "dynenv", "dynenv"),
)


@dataclass
class Period:
    """One motion period of the scene: what robot 0 detected and missed in each of its vision frames."""
    seed: int
    world: SoccerWorld
    params: PerceptionParams
    poses: list[tuple[float, float, float]]           # robot 0's camera pose per frame
    detections: list[np.ndarray]                      # robot 0's rows per frame
    missed: list[list[tuple[float, float]]]           # field positions of visible, undetected objects per frame

    @property
    def counts(self) -> tuple[int, int, int]:
        """(missed, false positives, confusions) over the period."""
        rows = np.concatenate(self.detections)
        confused = (rows["true_class"] != 0) & (rows["class_id"] != rows["true_class"])
        return sum(map(len, self.missed)), int((rows["true_id"] == -1).sum()), int(confused.sum())


def scene_positions(world: SoccerWorld) -> np.ndarray:
    """(N, 2) field positions in the order of ``soccer_scene``: robots, ball, goalposts, marks, crossings, circle."""
    f = world.config.field
    moving = [(r.x, r.y) for r in world.robots] + [world.ball_xy]
    return np.vstack([moving, f.goalposts, f.penalty_marks, [[c.x, c.y] for c in f.line_crossings], [[0.0, 0.0]]])


def run_period(params: PerceptionParams, seed: int) -> Period:
    """Place the scene in a fresh world seeded ``seed``, run one idle period, perceive, keep robot 0's views."""
    world = SoccerWorld(SoccerConfig.from_mapping({"falls": {"enabled": False}}), seed=seed)
    for i, pose in enumerate(POSES):
        world.place_robot(i, *pose)
    world.robots[OBSERVER].head_yaw = HEAD_YAW
    world.place_ball(*BALL)
    vision = SoccerVision(world, params)
    poses, positions = [], []

    def on_frame(k: int) -> None:
        vision.frame(k)
        robot = world.robots[OBSERVER]
        poses.append((robot.x, robot.y, robot.yaw + robot.head_yaw))
        positions.append(scene_positions(world))

    world.step([IDLE] * world.n_robots, on_frame=on_frame)
    perception: Perception = vision.perceive()
    views = [k * world.n_robots + OBSERVER for k in range(len(poses))]
    detections = [perception.of_view(v) for v in views]
    missed = [missed_positions(perception.visible[v], perception.of_view(v), vision.objects.object_id,
                               positions[k][:, 0], positions[k][:, 1]) for k, v in enumerate(views)]
    return Period(seed, world, params, poses, detections, missed)


def pick_period(figure: Figure) -> Period:
    """The first seed from 0 whose period shows what the figure is for (deterministic across runs)."""
    overrides = {} if figure.noise_magnitude is None else {"noise_magnitude": figure.noise_magnitude}
    params = load_preset(figure.preset, **overrides)
    best: Period | None = None
    for seed in range(MAX_SEEDS if figure.needs_errors else 1):
        period = run_period(params, seed)
        missed, false_positives, confused = period.counts
        if (not figure.needs_errors or missed and false_positives) and (not figure.needs_confusion or confused):
            return period
        score = (missed > 0) + (false_positives > 0) + (confused > 0)
        if best is None or score > sum(c > 0 for c in best.counts):
            best = period
    assert best is not None
    print(f"warning: {figure.filename}: no seed below {MAX_SEEDS} shows every error; using seed {best.seed}",
          file=sys.stderr)
    return best


def draw_figure(figure: Figure, period: Period) -> Image.Image:
    """Field, robot 0's view wedge, its detections of the period, a caption in the strip and a legend below."""
    world, params = period.world, period.params
    geometry = world.config.field
    image = render_snapshot(world.snapshot(), geometry, pixels_per_metre=PIXELS_PER_METRE,
                            ball_radius=world.config.ball.radius, fov=(OBSERVER, params.field_of_view / 2))
    view = field_view(geometry, PIXELS_PER_METRE)
    team = world.robots[OBSERVER].team
    missed = list(dict.fromkeys(p for frame in period.missed for p in frame))   # an object missed in any frame
    for k, (pose, rows) in enumerate(zip(period.poses, period.detections)):
        overlay_detections(image, view, pose, rows, truth=missed if k == 0 else None, observer_team=team,
                           fov_half_angle=None, legend=k == 0)      # the wedge: render_snapshot's, at frame 0
    n_missed, n_fp, n_confused = period.counts
    frames = len(period.detections)
    caption = (f"{figure.title} | robot {OBSERVER}, seed {period.seed}, {frames} frames: {n_missed} misses, "
               f"{n_fp} false pos., {n_confused} confusions")
    draw = ImageDraw.Draw(image)
    draw.rectangle((0, 0, view.size[0] - 1, view.strip_height - 1), fill=STRIP)
    font = ImageFont.load_default(size=max(8, view.strip_height - 7))
    draw.text((4, view.strip_height / 2), caption, fill=TEXT, font=font, anchor="lm")
    return image


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images", help="folder for the PNGs")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for figure in FIGURES:
        period = pick_period(figure)
        path = args.out / figure.filename
        save_png(draw_figure(figure, period), path)
        missed, false_positives, confused = period.counts
        print(f"{path}: seed {period.seed}, {missed} missed, {false_positives} false positives, "
              f"{confused} confusions")
    return 0


if __name__ == "__main__":
    sys.exit(main())
