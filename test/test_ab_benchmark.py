"""tools/ab_benchmark.py: the suites' JSON read into figures, the spread verdict, the table, the saved runs read back,
and a whole A/B run over a throw-away git repository whose two commits hold a tiny ``benchmarks`` package printing
known figures (so the worktrees, PYTHONPATH, interleaving and JSON lines are checked without timing anything real).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from tool_scripts import load_tool


@pytest.fixture(scope="module")
def tool():
    return load_tool("ab_benchmark")


def figure(median: float, low: float, high: float) -> dict:
    """A repeated figure as benchmarks/timing.py's stat writes it."""
    return {"median": median, "min": low, "max": high, "runs": [low, median, high]}


# ------------------------------------------------------------------------------------------------------- parsing
def test_the_last_json_object_starting_a_line_is_read_past_other_output(tool) -> None:
    text = ("loading presets {not json}\n"
            '{"first": 1}\n'
            "a log line\n"
            '{\n  "repeat": 1,\n  "results": {"async": {"env_steps_per_s": 447.5}}\n}\n')
    assert tool.last_json_object(text) == {"repeat": 1, "results": {"async": {"env_steps_per_s": 447.5}}}
    assert tool.last_json_object('{"steps": 50}') == {"steps": 50}
    assert tool.last_json_object('{"steps": 50}\n{"cut off": \n') == {"steps": 50}
    with pytest.raises(ValueError, match="no JSON object"):
        tool.last_json_object("measures: robocup 2v2\n  env_steps_per_s  1,105 [1,080–1,120]\n")


def test_sim_figures_are_the_medians_of_its_rates(tool) -> None:
    obj = {"steps": 2000, "repeat": 3, "env_steps_per_s": figure(1105.2, 1080.0, 1120.4),
           "env_steps_per_cpu_s": figure(1200.0, 1190.5, 1250.0), "wall_s": figure(1.8, 1.7, 1.9)}
    assert tool.sim_figures(obj) == {"env_steps_per_s": 1105.2, "env_steps_per_cpu_s": 1200.0}
    with pytest.raises(ValueError, match="no 'env_steps_per_cpu_s'"):
        tool.sim_figures({"env_steps_per_s": figure(1.0, 1.0, 1.0)})
    with pytest.raises(ValueError, match="expected a number"):
        tool.sim_figures({"env_steps_per_s": "fast", "env_steps_per_cpu_s": 3.0})


def test_train_figures_are_the_async_presets(tool) -> None:
    obj = {"repeat": 1, "results": {"async": {"config": "async", "num_envs": 32,
                                              "env_steps_per_s": figure(447.0, 447.0, 447.0),
                                              "env_steps_per_cpu_s": 229.0}}}
    assert tool.train_figures(obj) == {"env_steps_per_s": 447.0, "env_steps_per_cpu_s": 229.0}
    with pytest.raises(ValueError, match="no 'async'"):
        tool.train_figures({"results": {"ppo": obj["results"]["async"]}})


def test_learner_figures_are_its_rate_and_fraction_and_not_a_default_suite(tool) -> None:
    obj = {"config": "async", "flops_per_robot_step": 10.9e6, "robot_steps_per_cpu_second": figure(2253.0, 2170.0, 2351.0),
           "fraction_of_gemm": figure(0.28, 0.27, 0.30), "cpu_seconds_per_update": figure(0.9, 0.87, 0.95)}
    assert tool.learner_figures(obj) == {"robot_steps_per_cpu_second": 2253.0, "fraction_of_gemm": 0.28}
    with pytest.raises(ValueError, match="no 'fraction_of_gemm'"):
        tool.learner_figures({"robot_steps_per_cpu_second": 1.0})
    assert "learner" in tool.SUITES and "learner" not in tool.DEFAULT_SUITES


def test_policy_figures_name_each_runtime_and_robot_count(tool) -> None:
    obj = {"decisions": 300, "cases": [
        {"robots": 10, "runtime": "torch", "decisions_per_s": figure(74.0, 70.0, 75.5),
         "decisions_per_cpu_s": figure(75.0, 71.0, 76.0)},
        {"robots": 10, "runtime": "onnxruntime", "decisions_per_s": figure(317.5, 300.0, 320.0),
         "decisions_per_cpu_s": figure(320.0, 310.0, 330.0)}]}
    assert tool.policy_figures(obj) == {
        "torch, 10 robots: decisions_per_s": 74.0, "torch, 10 robots: decisions_per_cpu_s": 75.0,
        "onnxruntime, 10 robots: decisions_per_s": 317.5, "onnxruntime, 10 robots: decisions_per_cpu_s": 320.0}
    with pytest.raises(ValueError, match="non-empty list"):
        tool.policy_figures({"cases": []})


# ------------------------------------------------------------------------------------------------------ verdicts
def test_the_verdict_follows_the_documented_rule(tool) -> None:
    base = tool.spread([100.0, 90.0, 110.0])
    assert (base.median, base.low, base.high, base.runs) == (100.0, 90.0, 110.0, 3)
    # the head's median inside the base's range
    assert tool.verdict(base, tool.spread([95.0, 105.0, 120.0])) == "within spread"
    # the head's median above the base's range, but the ranges overlap (108 <= 110)
    assert tool.verdict(base, tool.spread([108.0, 115.0, 130.0])) == "within spread"
    # ranges that touch at one value overlap
    assert tool.verdict(base, tool.spread([80.0, 85.0, 90.0])) == "within spread"
    assert tool.verdict(base, tool.spread([111.0, 115.0, 130.0])) == "head faster (outside spread)"
    assert tool.verdict(base, tool.spread([60.0, 70.0, 89.9])) == "head slower (outside spread)"
    assert tool.verdict(tool.spread([100.0]), tool.spread([100.0])) == "no spread (1 run): not judged"
    assert tool.verdict(base, tool.spread([200.0])) == "no spread (1 run): not judged"


def record(side: str, suite: str, round_: int, figures: dict | None, error: str | None = None) -> dict:
    commits = {"base": ("3cd871e", "3cd871e" + "0" * 33), "head": ("HEAD", "66743e2" + "1" * 33)}
    out = {"side": side, "ref": commits[side][0], "commit": commits[side][1], "suite": suite, "round": round_,
           "position": 1, "wall_s": 10.0, "load_before": [0.5 + round_ / 10, 0.4, 0.3], "returncode": 0}
    if figures is not None:
        out["figures"] = figures
    if error:
        out.update(error=error, returncode=1)
    return out


RECORDS = [
    record("base", "sim", 1, {"env_steps_per_s": 1000.0}), record("head", "sim", 1, {"env_steps_per_s": 1050.0}),
    record("head", "sim", 2, {"env_steps_per_s": 1100.0}), record("base", "sim", 2, {"env_steps_per_s": 900.0}),
    record("base", "sim", 3, {"env_steps_per_s": 1100.0}), record("head", "sim", 3, {"env_steps_per_s": 1000.0}),
    record("base", "train", 1, {"env_steps_per_s": 500.0}), record("head", "train", 1, {"env_steps_per_s": 400.0}),
    record("base", "train", 2, {"env_steps_per_s": 520.0}), record("head", "train", 2, None, "exit status 1: boom"),
    record("base", "train", 3, {"env_steps_per_s": 510.0}), record("head", "train", 3, {"env_steps_per_s": 410.0}),
]


def table_row(table: str, suite: str) -> list[str]:
    return next([c.strip() for c in line.strip("|").split("|")] for line in table.splitlines()
                if line.startswith(f"| {suite} |"))


def test_the_table_gives_both_spreads_the_ratio_and_the_verdict(tool) -> None:
    table = tool.markdown_table(RECORDS)
    assert table.splitlines()[0] == ("base `3cd871e` (3cd871e00000) · head `HEAD` (66743e211111) · 3 round(s)")
    assert "load average (1 min) before each run: 0.60–0.80" in table
    # sim: base 900/1000/1100, head 1000/1050/1100: median 1,050 inside [900, 1,100]; 1050 / 1000
    assert table_row(table, "sim") == ["sim", "env_steps_per_s", "1,000 [900–1,100]", "1,050 [1,000–1,100]",
                                       "1.050", "3, 3", "within spread"]
    # train: base 500/510/520, head 400/410 (one run failed): 405 / 510
    assert table_row(table, "train") == ["train", "env_steps_per_s", "510 [500–520]", "405 [400–410]", "0.794",
                                         "3, 2", "head slower (outside spread)"]
    assert "1 run(s) failed (not in the table):" in table
    assert "- round 2 train head (66743e211111): exit status 1: boom" in table


def test_summary_only_reprints_the_saved_runs_and_refuses_bad_lines(tool, tmp_path, capsys) -> None:
    (tmp_path / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in RECORDS))
    assert tool.main(["--summary-only", "--out", str(tmp_path)]) == 0
    assert capsys.readouterr().out == tool.markdown_table(RECORDS)
    (tmp_path / "runs.jsonl").write_text(json.dumps(RECORDS[0]) + "\nnot json\n")
    with pytest.raises(SystemExit, match="runs.jsonl:2: not a JSON line"):
        tool.main(["--summary-only", "--out", str(tmp_path)])
    (tmp_path / "runs.jsonl").write_text(json.dumps({"side": "base", "suite": "sim"}) + "\n")
    with pytest.raises(SystemExit, match="runs.jsonl:1: not a run record .missing commit, ref, round"):
        tool.main(["--summary-only", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="nothing measured there yet"):
        tool.main(["--summary-only", "--out", str(tmp_path / "elsewhere")])


def test_a_measurement_needs_a_base_and_a_new_out(tool, tmp_path, capsys) -> None:
    with pytest.raises(SystemExit) as exited:
        tool.main(["--out", str(tmp_path)])
    assert exited.value.code == 2 and "--base is required" in capsys.readouterr().err
    (tmp_path / "runs.jsonl").write_text(json.dumps(RECORDS[0]) + "\n")
    with pytest.raises(SystemExit) as exited:
        tool.main(["--base", "HEAD", "--out", str(tmp_path)])
    assert exited.value.code == 2 and "already holds runs" in capsys.readouterr().err
    assert (tmp_path / "runs.jsonl").read_text() == json.dumps(RECORDS[0]) + "\n"     # nothing lost
    with pytest.raises(SystemExit) as exited:
        tool.main(["--base", "HEAD", "--out", str(tmp_path / "new"), "--policy-decisions", "100"])
    assert exited.value.code == 2 and "--policy-decisions at least 200" in capsys.readouterr().err


# ----------------------------------------------------------------------------------------- a whole run, for real
# Each commit's benchmarks/__main__.py prints its sim figures after a line of other output, in the shape of the real
# suite's --json; the head's sim is 10 % faster. policy passes its warm-up (--warmup 0) and then fails; train fails.
FAKE_MAIN = '''
import json, sys
suite, rate = sys.argv[1], {rate}
print("a line before the JSON")
if suite == "sim":
    print(json.dumps({{"env_steps_per_s": {{"median": rate, "min": rate - 1, "max": rate + 1}},
                      "env_steps_per_cpu_s": rate / 2, "argv": sys.argv[1:]}}))
elif suite == "policy" and sys.argv[sys.argv.index("--warmup") + 1] == "0":
    print(json.dumps({{"cases": [{{"robots": 10, "runtime": "torch", "decisions_per_s": rate,
                                  "decisions_per_cpu_s": rate}}]}}))
elif suite == "policy":
    sys.exit("policy broke after its warm-up")
else:
    sys.exit("no such suite here: " + suite)
'''


def git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.name=test", "-c", "user.email=test@example.com", *args], cwd=cwd,
                          check=True, capture_output=True, text=True).stdout.strip()


def fake_repository(root: Path) -> tuple[Path, str, str]:
    """A git repository with two commits of a fake ``benchmarks`` package (sim at 1,000 and at 1,100 env steps/s)."""
    repo = root / "repo"
    (repo / "benchmarks").mkdir(parents=True)
    (repo / "dynenv_ros").mkdir()
    (repo / "dynenv_ros" / "__init__.py").write_text("")
    (repo / "benchmarks" / "__init__.py").write_text("")
    git(repo, "init", "-q")
    commits = []
    for rate in (1000.0, 1100.0):
        (repo / "benchmarks" / "__main__.py").write_text(FAKE_MAIN.format(rate=rate))
        git(repo, "add", "-A")
        git(repo, "commit", "-qm", f"sim at {rate}")
        commits.append(git(repo, "rev-parse", "HEAD"))
    return repo, commits[0], commits[1]


def test_a_run_measures_each_commit_in_its_worktree_interleaved(tool, tmp_path, monkeypatch, capsys) -> None:
    repo, base, head = fake_repository(tmp_path)
    monkeypatch.setattr(tool, "ROOT", repo)
    out, trees = tmp_path / "out", tmp_path / "trees"
    argv = ["--base", base[:7], "--head", head, "--rounds", "2", "--suites", "sim", "--sim-steps", "50",
            "--out", str(out), "--worktrees", str(trees), "--python", sys.executable]
    assert tool.main(argv) == 0
    lines = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    # round 1: base then head; round 2: head then base
    assert [(r["round"], r["side"], r["position"]) for r in lines] == [
        (1, "base", 1), (1, "head", 2), (2, "head", 1), (2, "base", 2)]
    assert {r["commit"] for r in lines if r["side"] == "base"} == {base}
    assert {r["commit"] for r in lines if r["side"] == "head"} == {head}
    for r in lines:
        rate = 1000.0 if r["side"] == "base" else 1100.0
        assert r["figures"] == {"env_steps_per_s": rate, "env_steps_per_cpu_s": rate / 2}
        assert r["returncode"] == 0 and len(r["load_before"]) == 3 and r["wall_s"] >= 0
        assert r["command"][1:] == ["-m", "benchmarks", "sim", "--players-per-team", "2", "--observation", "partial",
                                    "--steps", "50", "--repeat", "3", "--cores", "1", "--json"]
        raw = (out / r["raw"]).read_text()
        assert f"PYTHONPATH={trees / r['commit'][:12]}" in raw and "a line before the JSON" in raw
    for side in ("base", "head"):    # each tree warmed up once, at the smallest sim, before round 1
        warm = (out / "raw" / f"warmup_sim_{side}.txt").read_text()
        assert "sim --players-per-team 2 --observation partial --steps 10 --repeat 1" in warm
    assert sorted(p.name for p in (out / "raw").iterdir()) == [
        "r1_sim_base.txt", "r1_sim_head.txt", "r2_sim_base.txt", "r2_sim_head.txt", "warmup_sim_base.txt",
        "warmup_sim_head.txt"]
    assert git(trees / base[:12], "rev-parse", "HEAD") == base
    assert git(trees / head[:12], "rev-parse", "HEAD") == head
    printed = capsys.readouterr().out
    assert table_row(printed, "sim")[2:] == ["1,000 [1,000–1,000]", "1,100 [1,100–1,100]", "1.100", "2, 2",
                                             "head faster (outside spread)"]
    assert (out / "summary.md").read_text() == tool.markdown_table(lines)

    # a second measurement reuses both trees; a tree with a changed file is refused, nothing run
    assert tool.main([*argv[:-6], "--out", str(tmp_path / "again"), *argv[-4:], "--rounds", "1"]) == 0
    (trees / head[:12] / "benchmarks" / "__main__.py").write_text("print('changed')\n")
    with pytest.raises(SystemExit, match="has changed files"):
        tool.main([*argv[:-6], "--out", str(tmp_path / "third"), *argv[-4:]])
    assert not (tmp_path / "third" / "runs.jsonl").exists()


def test_a_failing_suite_is_recorded_and_the_exit_status_says_so(tool, tmp_path, monkeypatch, capsys) -> None:
    repo, base, head = fake_repository(tmp_path)
    monkeypatch.setattr(tool, "ROOT", repo)
    out = tmp_path / "out"
    code = tool.main(["--base", base, "--head", base, "--rounds", "1", "--suites", "policy", "--out", str(out),
                      "--worktrees", str(tmp_path / "trees"), "--python", sys.executable])
    assert code == 1
    lines = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    refused = "exit status 1: policy broke after its warm-up"
    assert [(r["side"], r["returncode"], r["error"]) for r in lines] == [("base", 1, refused), ("head", 1, refused)]
    assert "2 run(s) failed" in capsys.readouterr().out
    assert not (tmp_path / "trees" / head[:12]).exists()    # an A/A run makes one tree, warmed up once
    assert sorted(p.name for p in (out / "raw").iterdir()) == [
        "r1_policy_base.txt", "r1_policy_head.txt", "warmup_policy_base.txt"]


def test_a_suite_failing_its_warm_up_stops_the_run_before_anything_is_measured(tool, tmp_path, monkeypatch) -> None:
    repo, base, head = fake_repository(tmp_path)
    monkeypatch.setattr(tool, "ROOT", repo)
    out = tmp_path / "out"
    with pytest.raises(SystemExit, match=f"the warm-up run of train at base {base[:12]} failed, nothing was "
                                         "measured: exit status 1: no such suite here: train"):
        tool.main(["--base", base, "--head", head, "--suites", "sim", "train", "--out", str(out),
                   "--worktrees", str(tmp_path / "trees"), "--python", sys.executable])
    assert not (out / "runs.jsonl").exists()
    assert "--updates 1 --warmup 0" in (out / "raw" / "warmup_train_base.txt").read_text()


def test_a_tree_that_is_not_a_worktree_of_the_commit_is_refused(tool, tmp_path, monkeypatch) -> None:
    repo, base, head = fake_repository(tmp_path)
    monkeypatch.setattr(tool, "ROOT", repo)
    trees = tmp_path / "trees"
    (trees / base[:12]).mkdir(parents=True)
    with pytest.raises(SystemExit, match="exists but is not a git worktree"):
        tool.worktree(trees, base)
    tree = tool.worktree(trees, head)
    git(tree, "checkout", "-q", "--detach", base)
    with pytest.raises(SystemExit, match=f"is at {base[:12]}, not {head[:12]}"):
        tool.worktree(trees, head)
    with pytest.raises(SystemExit, match="'no-such-ref' is not a commit of"):
        tool.resolve("no-such-ref")
