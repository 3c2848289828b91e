"""Figures docs/perception.md ("Driving") records: reports per car and frame, the share of correct reports per class
(the calibrated confidence's priors), the leak audit's chance level, and the perception cost per period.

    .venv/bin/python tools/driving_perception_statistics.py            # everything (about a minute)
    .venv/bin/python tools/driving_perception_statistics.py --timing   # only the cost per period
    .venv/bin/python tools/driving_perception_statistics.py --maxima   # only the padded layout's rows per frame
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from dynenv_ros.driving.config import DrivingConfig  # noqa: E402
from dynenv_ros.driving.vision import DrivingVision, driving_state  # noqa: E402
from dynenv_ros.driving.world import DrivingWorld  # noqa: E402
from dynenv_ros.perception.driving_params import load_driving_preset  # noqa: E402

NAMES = {20: "car", 21: "pedestrian", 22: "obstacle", 23: "lane"}


def play(preset, n_cars, periods, seed, magnitude=1.0):
    world = DrivingWorld(DrivingConfig(n_cars=n_cars), seed=seed)
    vision = DrivingVision(world, load_driving_preset(preset, noise_magnitude=magnitude) if preset != "none"
                           else load_driving_preset("none"), rng=np.random.default_rng(seed + 1))
    rng = np.random.default_rng(seed + 2)
    rows, views = [], 0
    for _ in range(periods):
        if world.done:
            world.reset()
            vision.reset()
        world.step(rng.integers(0, 3, (n_cars, 2)))
        out = vision.perceive()
        rows.append(out.detections)
        views += len(out)
    return np.concatenate(rows), views


def counts():
    print("| preset | cars | pedestrians | obstacles | lanes | false positives | confusions |")
    print("|---|---|---|---|---|---|---|")
    for preset, m in (("none", 0), ("dynenv", 1.0), ("realistic", 1.0), ("realistic", 3.0)):
        rows, views = play(preset, 2, 2000, seed=5, magnitude=m)
        cls = rows["class_id"]
        per = [f"{(cls == c).sum() / views:.2f}" for c in (20, 21, 22, 23)]
        fp = (rows["true_id"] == -1).sum() / views
        conf = ((rows["true_id"] >= 0) & (rows["true_class"] != cls)).sum() / views
        print(f"| {preset}{', magnitude %g' % m if m else ''} | " + " | ".join(per) + f" | {fp:.3f} | {conf:.3f} |")


def shares():
    rows, _ = play("realistic", 2, 4000, seed=7)
    correct = (rows["true_id"] != -1) & (rows["true_class"] == rows["class_id"])
    for c, name in NAMES.items():
        of = rows["class_id"] == c
        print(f"{name}: share correct {correct[of].mean():.3f} of {of.sum()}, mean confidence "
              f"{rows['confidence'][of].mean():.3f}")


def timing():
    print("| cars | none | dynenv | realistic |  (ms per period, perception only, best of 5 × 300)")
    print("|---|---|---|---|")
    for n in (2, 4, 10):
        cells = []
        for preset in ("none", "dynenv", "realistic"):
            world = DrivingWorld(DrivingConfig(n_cars=n), seed=0)
            vision = DrivingVision(world, preset, rng=np.random.default_rng(0))
            rng = np.random.default_rng(1)
            states = []
            for _ in range(300):
                if world.done:
                    break
                world.step(rng.integers(0, 3, (n, 2)))
                states.append(driving_state(world))
            best = np.inf
            for _ in range(5):
                t0 = time.perf_counter()
                for s in states:
                    vision.perceiver.perceive(s, vision.rng)
                best = min(best, (time.perf_counter() - t0) / len(states))
            cells.append(f"{best * 1e3:.3f}")
        print(f"| {n} | " + " | ".join(cells) + " |")


def maxima(periods=1000):
    """The most rows of each padded stream in one car's frame (every detection of ``periods`` periods), random and
    scripted play, each preset; beside them the default maxima (envs.driving_observations.default_maxima)."""
    from dynenv_ros.driving.scripted import ScriptedDriver
    from dynenv_ros.envs.driving_observations import default_maxima
    lanes_ids, object_ids = (23, 24), (0, 20, 21, 22)
    print("| cars | play | preset | lanes (SELF + LANE) | objects | of which false positives | default maxima |")
    print("|---|---|---|---|---|---|---|")
    for n_cars in (2, 4, 10):
        for policy in ("random", "scripted"):
            for preset in ("none", "dynenv", "realistic"):
                config = DrivingConfig(n_cars=n_cars)
                world = DrivingWorld(config, seed=11)
                vision = DrivingVision(world, load_driving_preset(preset))
                rng, driver = np.random.default_rng(3), ScriptedDriver(config)
                most = np.zeros(3, np.int64)
                for _ in range(periods):
                    if world.done:
                        world.reset()
                        vision.reset()
                    world.step(rng.integers(0, 3, (n_cars, 2)) if policy == "random" else driver.actions(world))
                    out = vision.perceive()
                    cls, view = out.detections["class_id"], np.repeat(np.arange(len(out)), np.diff(out.offsets))
                    for k, chosen in enumerate((np.isin(cls, lanes_ids), np.isin(cls, object_ids),
                                                out.detections["true_id"] == -1)):
                        most[k] = max(most[k], np.bincount(view[chosen], minlength=len(out)).max())
                print(f"| {n_cars} | {policy} | {preset} | {most[0]} | {most[1]} | {most[2]} | "
                      f"{' / '.join(map(str, default_maxima(config)))} |", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timing", action="store_true", help="only the cost per period")
    parser.add_argument("--maxima", action="store_true", help="only the padded layout's most rows per frame")
    args = parser.parse_args()
    if args.maxima:
        maxima()
        return
    if not args.timing:
        counts()
        shares()
        import test_driving_perception_leaks as leaks      # the test's reports: the figures it asserts
        from dynenv_ros.perception.audit import driving_leak_check
        check = driving_leak_check(*leaks.reports.__wrapped__())
        print(f"leak audit (realistic, magnitude 3, 4 cars, 1500 periods): {check.reports} reports, "
              f"{check.false_reports} false; AUC geometry {check.geometry_auc:.3f}, + other features "
              f"{check.extended_auc:.3f}, difference {check.extended_auc - check.geometry_auc:+.4f} "
              f"(SE {check.difference_se:.4f})")
    timing()


if __name__ == "__main__":
    main()
