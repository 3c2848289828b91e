"""tools/original_benchmark.py's table: each side's median and range of its runs' medians, and the ratio of the
medians with its extremes (ours' lowest over the original's highest, and the other way round)."""
import json

import pytest
from tool_scripts import load_tool

original_benchmark = load_tool("original_benchmark")


def _record(side, median, round_):
    return {"round": round_, "side": side, "env_steps_per_cpu_s": {"median": median}}


def test_the_table_gives_medians_ranges_and_the_ratio(tmp_path, capsys):
    # ours 900 / 1000 / 1100, the original 40 / 50 / 60: ratio 1000 / 50 = 20.0x, extremes 900 / 60 = 15.0x and
    # 1100 / 40 = 27.5x; CPU ms per step 1 and 20
    records = [_record("ours", 1000.0, 1), _record("original", 50.0, 1), _record("original", 40.0, 2),
               _record("ours", 1100.0, 2), _record("ours", 900.0, 3), _record("original", 60.0, 3)]
    table = original_benchmark.summary(records)
    assert "| ours | 3 | 1,000.0 [900.0–1,100.0] | 1.000 |" in table
    assert "| original | 3 | 50.0 [40.0–60.0] | 20.000 |" in table
    assert "ratio of the medians: 20.0x (extremes: 15.0x–27.5x)" in table
    out = tmp_path / "runs.jsonl"
    out.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert original_benchmark.main(["interleave", "--summary-only", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == table


def test_interleave_needs_the_original(tmp_path):
    with pytest.raises(SystemExit):
        original_benchmark.main(["interleave", "--out", str(tmp_path / "runs.jsonl")])
