"""tools/teacher_agreement.py: agreement with the scripted teacher, split by situation."""
from __future__ import annotations

import json

import numpy as np
import pytest
from tool_scripts import load_tool

from dynenv_ros.agent.checkpoint import save_policy
from dynenv_ros.agent.network import DynEnvAgent



@pytest.fixture(scope="module")
def tool():
    return load_tool("teacher_agreement")


def test_rows_split_agreement_by_ball_sight_and_distance(tool) -> None:
    # Four states [walk, turn, kick, head]: state 0 agrees on every head, state 1 on all but the turn, state 2 on
    # none, state 3 on walk and kick only.
    teacher = np.array([[1, 2, 0, 3], [1, 2, 0, 3], [0, 0, 0, 3], [4, 1, 0, 2]])
    greedy = np.array([[1, 2, 0, 3], [1, 1, 0, 3], [2, 1, 1, 4], [4, 2, 0, 5]])
    seen = np.array([True, True, False, False])
    distance = np.array([0.2, 1.0, 0.2, 7.0])
    rows = {r["situation"]: r for r in tool.agreement_rows(greedy, teacher, seen, distance)}
    assert rows["all"]["count"] == 4 and rows["all"]["joint"] == 0.25
    assert [rows["all"][h] for h in ("walk", "turn", "kick", "head")] == [0.75, 0.25, 0.75, 0.5]
    assert rows["ball seen"]["count"] == 2 and rows["ball seen"]["joint"] == 0.5 and rows["ball seen"]["turn"] == 0.5
    assert rows["ball not seen"]["joint"] == 0.0 and rows["ball not seen"]["walk"] == 0.5
    assert rows["ball 0-0.5 m"]["count"] == 2 and rows["ball 0-0.5 m"]["joint"] == 0.5
    assert rows["ball 0.5-1.5 m"]["count"] == 1 and rows["ball 0.5-1.5 m"]["turn"] == 0.0
    assert rows["ball 1.5-3 m"]["count"] == 0 and rows["ball 1.5-3 m"]["joint"] is None
    assert rows["ball 3-inf m"]["count"] == 1 and rows["ball 3-inf m"]["kick"] == 1.0


def test_cli_plays_labels_and_writes_consistent_figures(tool, tmp_path, capsys) -> None:
    policy = tmp_path / "policy.safetensors"
    save_policy(DynEnvAgent(), policy, {})
    out = tmp_path / "agreement.json"
    assert tool.main([str(policy), "--periods", "32", "--worlds", "1", "--perception", "none",
                      "--json", str(out)]) == 0
    assert "| all |" in capsys.readouterr().out
    result = json.loads(out.read_text())
    rows = {r["situation"]: r for r in result["rows"]}
    total = rows["all"]["count"]
    assert 0 < total <= 32 * 2            # 32 periods, two learning robots (team A), only where they could act
    assert rows["ball seen"]["count"] + rows["ball not seen"]["count"] == total
    assert sum(rows[name]["count"] for name in rows if name.startswith("ball ") and name.endswith(" m")) == total
    for shares in result["teacher"] + result["greedy"]:
        assert sum(shares.values()) == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("case", ["missing policy", "corrupt policy", "unknown teacher"])
def test_cli_refuses_bad_input_with_a_reason(tool, tmp_path, capsys, case: str) -> None:
    policy, extra = tmp_path / "policy.safetensors", []
    if case == "corrupt policy":
        policy.write_bytes(b"not a safetensors file")
    elif case == "unknown teacher":
        save_policy(DynEnvAgent(), policy, {})
        extra = ["--teacher", "striker"]
    assert tool.main([str(policy), "--periods", "32", "--worlds", "1", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("teacher_agreement:")
    if case == "unknown teacher":
        assert "striker" in err and "eager_chaser" in err
