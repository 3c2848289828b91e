"""Evaluation that cannot flatter: named seed splits, the test ledger dynenv-eval appends itself, head-to-head
intervals with seeds as units, and the paper's ratio of means with its interval."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dynenv_ros.evaluation.cli import main
from dynenv_ros.evaluation.head_to_head import bootstrap_interval, head_to_head
from dynenv_ros.evaluation.ledger import read_ledger, rows_of
from dynenv_ros.evaluation.ratios import group_mean, ratio_of_means
from dynenv_ros.evaluation.results import FORMAT
from dynenv_ros.evaluation.splits import SPLITS, split_of, split_seeds

# The documented ranges (docs/results.md, "Seed splits"), written out here.
DOCUMENTED = {"train": (0, 9_999), "validation": (10_000, 19_999), "test": (20_000, 29_999)}


def test_the_splits_are_the_documented_disjoint_ranges():
    for name, (first, last) in DOCUMENTED.items():
        assert (SPLITS[name].start, SPLITS[name].stop - 1) == (first, last)
    assert split_seeds("validation", 3) == [10_000, 10_001, 10_002]
    assert split_of([20_000, 29_999]) == "test" and split_of([9_999, 10_000]) is None
    names = list(SPLITS)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not set(SPLITS[a]) & set(SPLITS[b])


def test_the_bootstrap_interval_matches_the_normal_one_on_many_seeds():
    rng = np.random.default_rng(7)
    values = rng.normal(0.4, 1.0, size=400)
    low, high = bootstrap_interval(values)
    half = 1.96 * values.std(ddof=1) / math.sqrt(values.size)     # the normal 95 % half-width
    # the percentile bootstrap's half-width matches the normal one to within a few percent at n = 400
    assert (high - low) / 2 == pytest.approx(half, rel=0.08)
    assert (low + high) / 2 == pytest.approx(values.mean(), abs=0.2 * half)


def _record(seed: int, gf: int, ga: int) -> dict:
    return {"seed": seed, "goals_for": gf, "goals_against": ga,
            "result": "win" if gf > ga else "loss" if gf < ga else "draw"}


def test_a_head_to_head_counts_the_games_and_beats_only_with_the_interval_above_zero():
    # 10 seeds x 4 games: every seed wins 2 : 0, draws twice and loses once 0 : 1 → +0.25 goals a game, every seed
    winning = [_record(s, *g) for s in range(10) for g in ((1, 0), (1, 0), (0, 0), (0, 1))]
    h = head_to_head({"episodes": winning})
    assert (h["games"], h["seeds"], h["wins"], h["draws"], h["losses"]) == (40, 10, 20, 10, 10)
    assert (h["goals_for"], h["goals_against"]) == (20, 10)
    assert h["goal_difference_per_game"] == pytest.approx(0.25)
    assert h["interval"] == pytest.approx([0.25, 0.25]) and h["beats"]     # every seed alike: no spread
    # seeds that differ: half the seeds +1 a game, half −0.5 a game → mean +0.25 and an interval that holds 0
    mixed = [_record(s, *((1, 0) if s % 2 else (0, 0) if g % 2 else (0, 1))) for s in range(10) for g in range(4)]
    m = head_to_head({"episodes": mixed})
    assert m["goal_difference_per_game"] == pytest.approx(0.25)
    assert m["interval"][0] < 0 < m["interval"][1] and not m["beats"]
    clear = [_record(s, 2, 0) if g < 3 else _record(s, 0, 1) for s in range(10) for g in range(4)]
    c = head_to_head({"episodes": clear})
    assert c["interval"][0] > 0 and c["beats"]


def _result(per_seed: dict[int, float]) -> dict:
    return {"per_seed": [{"seed": s, "paper_metric": v} for s, v in per_seed.items()]}


def test_the_ratio_is_of_means_over_the_same_seeds_with_an_interval_over_runs_and_seeds():
    reference = _result({1: 2.0, 2: 4.0})                     # mean 3
    group = [_result({1: 6.0, 2: 12.0}), _result({1: 9.0, 2: 15.0})]   # means 9 and 12 → 10.5
    r = ratio_of_means(group, reference)
    assert r["ratio"] == pytest.approx(10.5 / 3.0)
    assert r["per_run_ratio"] == pytest.approx([3.0, 4.0])
    assert r["interval"][0] <= r["ratio"] <= r["interval"][1]
    with pytest.raises(ValueError, match="same games"):
        ratio_of_means([_result({1: 1.0, 3: 1.0})], reference)


def _driving(per_seed: dict[int, float]) -> dict:
    return {"per_seed": [{"seed": s, "total": v} for s, v in per_seed.items()]}


def test_a_group_mean_is_over_runs_and_their_common_seeds_with_an_interval_over_both(tmp_path, capsys):
    group = [_driving({1: 10.0, 2: 30.0}), _driving({1: 20.0, 2: 40.0})]      # run means 20 and 30 → 25
    m = group_mean(group, "total")
    assert m["group_mean"] == pytest.approx(25.0) and m["per_run_mean"] == pytest.approx([20.0, 30.0])
    # the extremes a draw can reach: run 0 on seed 1 only (10), run 1 on seed 2 only (40)
    assert 10.0 <= m["interval"][0] < 25.0 < m["interval"][1] <= 40.0
    alike = group_mean([_driving({1: 5.0, 2: 5.0})] * 3, "total")
    assert alike["interval"] == pytest.approx([5.0, 5.0])                       # no spread, no width
    # many runs and seeds: the two-level bootstrap's half-width is about the normal one of the run means
    rng = np.random.default_rng(3)
    many = [_driving({s: float(v) for s, v in enumerate(rng.normal(mean, 1.0, size=50))})
            for mean in rng.normal(20.0, 4.0, size=40)]
    wide = group_mean(many, "total")
    run_means = np.array(wide["per_run_mean"])
    half = 1.96 * run_means.std(ddof=1) / math.sqrt(run_means.size)
    assert (wide["interval"][1] - wide["interval"][0]) / 2 == pytest.approx(half, rel=0.2)
    with pytest.raises(ValueError, match="same games"):
        group_mean([_driving({1: 1.0, 2: 1.0}), _driving({1: 1.0, 3: 1.0})], "total")
    # the command line says where the interval lies against the paper's figure
    paths = []
    for k, result in enumerate(group):
        path = tmp_path / f"run{k}.json"
        path.write_text(json.dumps({"format": FORMAT, **result}))
        paths.append(str(path))
    assert main(["mean", *paths, "--bar", "5"]) == 0
    assert "lies above 5" in capsys.readouterr().out
    assert main(["mean", *paths, "--bar", "26.47"]) == 0
    assert "includes 26.47" in capsys.readouterr().out
    written = tmp_path / "mean.json"
    assert main(["mean", *paths, "--out", str(written)]) == 0
    summary = json.loads(written.read_text())
    assert summary["format"] == "dynenv_group_mean/1" and summary["group_mean"] == pytest.approx(25.0)
    assert main(["mean", *paths, "--out", str(tmp_path / "missing" / "mean.json")]) != 0    # no folder: refused


def _eval(tmp_path, *extra: str) -> int:
    return main(["random", "--opponent", "random", "--episodes", "2", "--episode-seconds", "4", "--quiet", *extra])


def test_a_test_split_evaluation_appends_one_ledger_row(tmp_path, capsys):
    ledger = tmp_path / "ledger.jsonl"
    out = tmp_path / "r.json"
    assert _eval(tmp_path, "--split", "test", "--num-seeds", "2", "--ledger", str(ledger), "--out", str(out)) == 0
    assert _eval(tmp_path, "--split", "test", "--seeds", "20005", "20009", "--ledger", str(ledger)) == 0
    rows = read_ledger(ledger)
    assert [r["seeds"] for r in rows] == [[20_000, 20_001], [20_005, 20_009]]
    assert rows[0]["games"] == 4 and rows[0]["head_to_head"]["games"] == 4
    assert rows[0]["out"] == str(out) and rows[0]["evaluated"]["spec"] == "random"
    assert json.loads(out.read_text())["head_to_head"]["games"] == 4
    assert "head-to-head: 4 games" in capsys.readouterr().out


def test_seeds_of_the_test_split_need_split_test_and_other_splits_write_no_ledger(tmp_path, capsys):
    ledger = tmp_path / "ledger.jsonl"
    assert _eval(tmp_path, "--seeds", "20000") == 2
    assert "--split test" in capsys.readouterr().err
    assert _eval(tmp_path, "--split", "validation", "--seeds", "20000") == 2
    assert _eval(tmp_path, "--split", "validation", "--num-seeds", "1", "--ledger", str(ledger)) == 2
    assert _eval(tmp_path, "--split", "validation", "--num-seeds", "1") == 0
    assert not ledger.exists()


def test_a_failed_test_evaluation_writes_no_row(tmp_path):
    ledger = tmp_path / "ledger.jsonl"
    code = main([str(tmp_path / "missing.safetensors"), "--opponent", "random", "--split", "test", "--num-seeds", "1",
                 "--episodes", "1", "--quiet", "--ledger", str(ledger)])
    assert code == 2 and not ledger.exists()


def test_the_repository_ledger_is_readable_and_rows_are_found_by_policy(tmp_path):
    ledger = tmp_path / "ledger.jsonl"
    assert _eval(tmp_path, "--split", "test", "--num-seeds", "2", "--ledger", str(ledger)) == 0
    rows = read_ledger(ledger)
    assert rows_of(rows, "0123") == []
    ledger.write_text(ledger.read_text() + "not json\n")
    with pytest.raises(ValueError, match=":2: not JSON"):
        read_ledger(ledger)


def test_without_ledger_the_suite_writes_to_its_scratch_ledger_not_the_repositorys(tmp_path, monkeypatch):
    from dynenv_ros.evaluation.ledger import REPOSITORY_LEDGER, default_ledger
    before = REPOSITORY_LEDGER.read_bytes() if REPOSITORY_LEDGER.exists() else b""
    scratch = tmp_path / "scratch_ledger.jsonl"
    monkeypatch.setenv("DYNENV_TEST_LEDGER", str(scratch))
    assert default_ledger() == scratch
    assert _eval(tmp_path, "--split", "test", "--num-seeds", "2") == 0
    assert len(read_ledger(scratch)) == 1
    assert (REPOSITORY_LEDGER.read_bytes() if REPOSITORY_LEDGER.exists() else b"") == before


def test_a_driving_test_split_evaluation_is_in_the_ledger_too(tmp_path):
    ledger = tmp_path / "ledger.jsonl"
    assert main(["--scenario", "driving", "random", "--episodes", "1", "--episode-seconds", "2", "--quiet",
                 "--split", "test", "--num-seeds", "2", "--ledger", str(ledger)]) == 0
    (row,) = read_ledger(ledger)
    assert row["scenario"] == "driving" and row["seeds"] == [20_000, 20_001] and row["opponent"] is None
    assert "home_rate" in row["summary"] and "head_to_head" not in row


def test_seeds_take_inclusive_ranges_and_refuse_bad_or_repeated_ones(tmp_path, capsys):
    ledger = tmp_path / "ledger.jsonl"
    assert _eval(tmp_path, "--split", "test", "--seeds", "20003-20005", "20009", "--ledger", str(ledger)) == 0
    assert read_ledger(ledger)[0]["seeds"] == [20_003, 20_004, 20_005, 20_009]
    for bad in ("20005-20003", "a-b", "1-2-3", "-3"):
        with pytest.raises(SystemExit):
            _eval(tmp_path, "--split", "validation", "--seeds", bad)
        assert "--seeds" in capsys.readouterr().err
    assert _eval(tmp_path, "--split", "validation", "--seeds", "10000-10002", "10001") == 2
    assert "twice: [10001]" in capsys.readouterr().err
