"""tools/paper_comparison.py on a fixture of fake finished runs: evaluations cached and reused, tables that agree
with the evaluation JSONs, BEST with a skipped comparison, the PNGs and the equivalent commands.

One 3 s episode per evaluation (12 evaluations), one tiny BEST run (pytensor's C cache warm: ~20 s in all).
"""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from tool_scripts import load_tool

from dynenv_ros.agent.checkpoint import save_policy, sha256
from dynenv_ros.agent.network import DynEnvAgent

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def tool():
    return load_tool("paper_comparison")


def fake_run(root: Path, variant: str, seed: int, finished: bool = True) -> Path:
    run = root / f"ppo_{variant}_s{seed}"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"algorithm": "ppo", "variant": variant, "seed": seed}))
    torch.manual_seed(100 * seed + len(variant))
    save_policy(DynEnvAgent(), run / "policy.safetensors", {"variant": variant, "seed": seed})
    rng = np.random.default_rng(seed)
    with open(run / "metrics.csv", "w", newline="") as handle:
        out = csv.writer(handle)
        out.writerow(("env_steps", "update", "wall_seconds", "name", "value"))
        steps = [256 * (k + 1) for k in range(6 + seed)]
        steps = steps[:4] + steps[2:]         # a resume: steps 768.. repeated, the later rows win
        for k, step in enumerate(steps):
            for name in ("episode/return", "episode/paper_metric", "speed/env_steps_per_second",
                         "train/policy_loss"):
                out.writerow((step, k, f"{k:.3f}", name, f"{rng.normal():.6g}"))
    if finished:
        (run / "summary.json").write_text(json.dumps({"env_steps": steps[-1], "wall_seconds": 60.0}))
    return run


def parse_row(markdown: str, heading: str, group: str) -> list[str]:
    section = markdown.split(heading, 1)[1]
    for line in section.splitlines():
        if line.startswith(f"| {group} |"):
            return [cell.strip() for cell in line.strip("|").split("|")]
    raise AssertionError(f"no row {group} under {heading}")


def first_number(cell: str) -> float:
    return float(re.match(r"-?[\d.]+(e[-+]?\d+)?", cell)[0])


def test_paper_comparison_on_fixture_runs(tool, tmp_path):
    runs = tmp_path / "runs"
    fake_run(runs, "baseline", 0)
    fake_run(runs, "baseline", 1)
    fake_run(runs, "pred", 0)
    fake_run(runs, "pred", 1, finished=False)
    out, images, md = tmp_path / "eval", tmp_path / "images", tmp_path / "eval" / "tables.md"
    argv = ["--runs", str(runs), "--episodes", "1", "--episode-seconds", "3", "--out", str(out), "--images",
            str(images), "--markdown", str(md), "--draws", "60", "--tune", "60", "--chains", "2"]
    lines: list[str] = []
    report = tool.main(argv, log=lines.append)

    assert [r.name for r in report["runs"]] == ["ppo_baseline_s0", "ppo_baseline_s1", "ppo_pred_s0"]
    assert report["skipped"] == [("ppo_pred_s1", "unfinished (no summary.json)")]
    assert set(report["status"].values()) == {"evaluated"} and len(report["status"]) == 12
    text = md.read_text()
    assert "ppo_pred_s1 (unfinished (no summary.json))" in text

    # every evaluation: one seed = the training seed (random: 0, 1, 2), the settings asked for
    def load(name):
        return json.loads((out / f"{name}.json").read_text())
    for unit, seed in (("ppo_baseline_s0", 0), ("ppo_baseline_s1", 1), ("ppo_pred_s0", 0), ("random_s0", 0),
                       ("random_s1", 1), ("random_s2", 2)):
        for opponent in ("random", "scripted"):
            data = load(f"{unit}_vs_{opponent}")
            assert data["settings"]["seeds"] == [seed] and data["settings"]["episodes"] == 1
            assert data["settings"]["perception"] == "realistic" and data["settings"]["players_per_team"] == 2
            assert data["settings"]["sides"] == "alternate" and data["settings"]["greedy"] is False
            assert data["opponent"]["spec"] == opponent
            assert f"--seeds {seed} " in text and f"{unit}_vs_{opponent}.json" in text
    # common random numbers: a policy and random with the same seed met the same env seeds
    assert load("ppo_pred_s0_vs_random")["episodes"][0]["env_seed"] == \
        load("random_s0_vs_random")["episodes"][0]["env_seed"]

    # table (a): means over seeds and the ratio to random, recomputed from the JSONs
    per_group = {"random": ["random_s0", "random_s1", "random_s2"], "baseline": ["ppo_baseline_s0", "ppo_baseline_s1"],
                 "pred": ["ppo_pred_s0"]}
    random_total = np.mean([load(f"{u}_vs_random")["per_seed"][0]["total"] for u in per_group["random"]])
    for group, units in per_group.items():
        row = parse_row(text, "## (a)", group)
        rows = [load(f"{u}_vs_random")["per_seed"][0] for u in units]
        assert int(row[1]) == len(units)
        for cell, metric in zip(row[2:8], ("total", "primary", "rule", "auxiliary", "observation", "paper_metric")):
            assert first_number(cell) == pytest.approx(np.mean([r[metric] for r in rows]), rel=1e-3, abs=1e-9)
        if len(units) > 1:
            sd = float(row[2].split("±")[1])
            assert sd == pytest.approx(np.std([r["total"] for r in rows], ddof=1), rel=0.06, abs=1e-9)
        total = np.mean([r["total"] for r in rows])
        assert float(row[8]) == pytest.approx(total / random_total, rel=5e-3)
    assert "| recon |" not in text.split("## (b)")[0]
    assert "No finished runs for: recon, pred+teacher." in text

    # table (b): goals and W/D/L summed over seeds and episodes
    row = parse_row(text, "## (b)", "baseline")
    episodes = [e for u in per_group["baseline"] for e in load(f"{u}_vs_scripted")["episodes"]]
    assert int(row[3]) == sum(e["goals_for"] for e in episodes)
    assert int(row[4]) == sum(e["goals_against"] for e in episodes)
    assert row[5] == "/".join(str(sum(e["result"] == r for e in episodes)) for r in ("win", "draw", "loss"))

    # (c) BEST: random → baseline ran (2 and 3 seeds); pred has one seed, recon none: skipped and said so
    done = {c.label: c for c in report["comparisons"]}
    assert done["random → baseline"].result is not None
    assert done["random → baseline"].result.n1 == 3 and done["random → baseline"].result.n2 == 2
    for label in ("random → pred", "baseline → pred", "pred → recon"):
        assert done[label].result is None and "pred has 1 seed" in done[label].skipped
    assert "pred → recon (total vs random): skipped — pred has 1 seed; recon has 0 seeds" in text
    assert "| random → baseline | total vs random | 3, 2 |" in text
    best_json = json.loads((out / "best_random_vs_baseline.json").read_text())
    group_random = json.loads((out / "group_random_vs_random.json").read_text())
    assert best_json["values_a"] == [r["total"] for r in group_random["per_seed"]]
    assert "dynenv-eval compare " + str(out / "group_random_vs_random.json") in text

    # PNGs
    for name in ("best_random_vs_baseline.png", "training_curves.png"):
        path = images / name
        assert path.read_bytes()[:8] == PNG_MAGIC
        with Image.open(path) as image:
            assert image.format == "PNG" and image.size[0] > 400
    assert not (images / "best_baseline_vs_pred.png").exists()

    # a re-run reuses every evaluation; a changed policy file is evaluated again
    settings = tool.Settings(episodes=1, episode_seconds=3.0)
    jobs = tool.plan_jobs(tool.find_runs(runs)[0], out)
    assert jobs == report["jobs"]
    assert set(tool.run_jobs(jobs, settings, workers=2, log=lines.append).values()) == {"cached"}
    torch.manual_seed(7)
    save_policy(DynEnvAgent(), runs / "ppo_pred_s0" / "policy.safetensors", {})
    job = next(j for j in jobs if j.unit == "ppo_pred_s0")
    assert tool.cache_problem(job, settings, sha256(runs / "ppo_pred_s0" / "policy.safetensors")) == \
        "the policy file changed"
    assert tool.cache_problem(job, tool.Settings(episodes=2, episode_seconds=3.0), None) == "episodes was 1, now 2"


def test_clean_series_and_mean_curve(tool):
    steps, vals = tool.clean_series([1, 2, 3, 4, 3, 4, 5], [1, 2, 3, 4, 30, 40, 50])
    assert steps.tolist() == [1, 2, 3, 4, 5] and vals.tolist() == [1, 2, 30, 40, 50]
    grid, mean = tool.mean_curve([(np.array([0.0, 10.0]), np.array([0.0, 10.0])),
                                  (np.array([2.0, 8.0]), np.array([4.0, 4.0]))], points=4)
    assert grid.tolist() == [2.0, 4.0, 6.0, 8.0]
    assert mean.tolist() == pytest.approx([3.0, 4.0, 5.0, 6.0])
