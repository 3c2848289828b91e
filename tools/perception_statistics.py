#!/usr/bin/env python3
"""The perception figures docs/perception.md records: detections per robot and frame by class, false reports, the
observation reward, the leak audit (how well a learner can tell false reports from real ones) and how often the
padded layout's maxima are reached.

Usage: ``.venv/bin/python tools/perception_statistics.py [--periods 240] [--audit-periods 2000]``

Random 2v2 play (seeded), one 120 s episode per preset for the counts, longer for the audit (it needs thousands of
false reports).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from dynenv_ros.core.object_classes import ObjectClass  # noqa: E402
from dynenv_ros.envs.padded_layout import LANDMARK_CLASSES, OBJECT_CLASSES, PaddedLayout  # noqa: E402
from dynenv_ros.envs.soccer_observations import perception_params  # noqa: E402
from dynenv_ros.perception.audit import auc, false_reports, leak_check  # noqa: E402
from dynenv_ros.soccer.config import SoccerConfig  # noqa: E402
from dynenv_ros.soccer.vision import SoccerVision  # noqa: E402
from dynenv_ros.soccer.world import SoccerWorld  # noqa: E402

CASES = (("none", "none", None), ("dynenv, magnitude 1", "dynenv", None),
         ("realistic, magnitude 1", "realistic", None), ("realistic, magnitude 3", "realistic", 3.0))
COUNTED = (("ball", ObjectClass.BALL), ("robots", ObjectClass.ROBOT), ("posts", ObjectClass.GOALPOST),
           ("penalty crosses", ObjectClass.PENALTY_CROSS), ("line crossings", ObjectClass.LINE_CROSSING),
           ("lines", ObjectClass.FIELD_LINE), ("circle", ObjectClass.CENTER_CIRCLE))


def play(preset: str, magnitude: float | None, periods: int, seed: int):
    """(all rows, global view id per row, views, observation reward per robot summed over the periods)."""
    setting = {"preset": preset} if magnitude is None else {"preset": preset, "noise_magnitude": magnitude}
    world = SoccerWorld(SoccerConfig.from_mapping({"players_per_team": 2}), seed=seed)
    vision = SoccerVision(world, perception_params(setting))
    rng = np.random.default_rng(seed + 1)
    rows, views, base, reward = [], [], 0, np.zeros(world.n_robots)
    for t in range(periods):
        if t % world.config.episode_periods == 0:
            world.reset(seed=int(rng.integers(2**31)))
            vision.reset()
        actions = [[rng.integers(5), rng.integers(3), rng.integers(3), rng.integers(7)] for _ in range(4)]
        world.step(actions, on_frame=vision.frame)
        perception = vision.perceive()
        reward += vision.observation_rewards(perception)
        rows.append(perception.detections)
        views.append(base + np.repeat(np.arange(len(perception)), np.diff(perception.offsets)))
        base += len(perception)
    return np.concatenate(rows), np.concatenate(views), base, reward


def counts_table(periods: int) -> None:
    print(f"## Mean detections per robot and frame ({periods} periods, 2v2, random play, seed 1)\n")
    print("| preset | " + " | ".join(name for name, _ in COUNTED)
          + " | false positives | confusions | observation reward per robot and episode |")
    print("|---|" + "---|" * (len(COUNTED) + 3))
    for title, preset, magnitude in CASES:
        rows, _, views, reward = play(preset, magnitude, periods, seed=1)
        cells = [f"{(rows['class_id'] == cls).sum() / views:.2f}" for _, cls in COUNTED]
        fps = (rows["true_id"] == -1).sum() / views
        confusions = ((rows["true_id"] != -1) & (rows["true_class"] != rows["class_id"])).sum() / views
        episodes = periods / SoccerConfig().episode_periods
        print(f"| {title} | " + " | ".join(cells) + f" | {fps:.3f} | {confusions:.3f} | "
              f"{reward.mean() / episodes:.2f} |")
    print()


def audit_table(periods: int) -> None:
    print(f"## Can false reports be told from real ones? ({periods} periods, 2v2, random play, seed 11)\n")
    print("| preset | reports | false | AUC geometry alone | + every other feature but the confidence "
          "| difference (SE) | confidence alone, ball / robot / post |")
    print("|---|---|---|---|---|---|---|")
    for title, preset, magnitude in CASES[1:3]:
        rows, view_ids, _, _ = play(preset, magnitude, periods, seed=11)
        check = leak_check(rows, view_ids)
        label = false_reports(rows)
        by_class = []
        for cls in (ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.GOALPOST):
            of = rows["class_id"] == cls
            by_class.append("—" if np.ptp(rows["confidence"][of]) == 0 else
                            f"{auc(-rows['confidence'][of].astype(float), label[of]):.3f}")
        print(f"| {title} | {check.reports} | {check.false_reports} | {check.geometry_auc:.3f} | "
              f"{check.extended_auc:.3f} | {check.extended_auc - check.geometry_auc:+.4f} "
              f"({check.difference_se:.4f}) | {' / '.join(by_class)} |")
    print(f"\nExpected AUC of the calibrated confidence with d' = 1.5: Φ(1.5/√2) = "
          f"{0.5 * (1 + math.erf(1.5 / 2)):.3f}.\n")


def layout_table(periods: int) -> None:
    layout = PaddedLayout.for_players(2, frames=5)
    print(f"## Padded layout: rows per frame against the maxima ({layout.max_landmarks} landmarks, "
          f"{layout.max_objects} objects for 2v2; {periods} periods)\n")
    print("| preset | most landmarks in a frame | most objects | frames with a dropped row |")
    print("|---|---|---|---|")
    for title, preset, magnitude in CASES:
        rows, view_ids, views, _ = play(preset, magnitude, periods, seed=2)
        landmarks = np.bincount(view_ids[np.isin(rows["class_id"], LANDMARK_CLASSES)], minlength=views)
        objects = np.bincount(view_ids[np.isin(rows["class_id"], OBJECT_CLASSES)], minlength=views)
        dropped = ((landmarks > layout.max_landmarks) | (objects > layout.max_objects)).mean()
        print(f"| {title} | {landmarks.max()} | {objects.max()} | {100 * dropped:.3f} % |")
    print()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=240, help="periods for the counts (240 = one episode)")
    parser.add_argument("--audit-periods", type=int, default=2000, help="periods for the leak audit")
    parser.add_argument("--layout-periods", type=int, default=1000, help="periods for the layout maxima")
    args = parser.parse_args(argv)
    for name in ("periods", "audit_periods", "layout_periods"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    counts_table(args.periods)
    audit_table(args.audit_periods)
    layout_table(args.layout_periods)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
