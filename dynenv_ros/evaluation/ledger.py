"""The test ledger: every evaluation on the ``test`` split, appended by dynenv-eval itself as one JSON line, so a
reader sees every time a policy lineage met the test games, not only the last and best one. The repository's
ledger is ``docs/results_data/test_ledger.jsonl`` (committed); a row is written only after the evaluation finished,
with fsync, and a row never changes.
"""
from __future__ import annotations

import json
import os
import shlex
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

from dynenv_ros.core.revision import code_revision

LEDGER_FORMAT = "dynenv_test_ledger/1"
REPOSITORY_LEDGER = Path(__file__).resolve().parents[2] / "docs" / "results_data" / "test_ledger.jsonl"


def default_ledger() -> Path | None:
    """``$DYNENV_TEST_LEDGER`` if set (the test suite points it at a scratch file), else the repository's ledger
    when this package runs from a checkout that has its folder, else None."""
    if os.environ.get("DYNENV_TEST_LEDGER"):
        return Path(os.environ["DYNENV_TEST_LEDGER"])
    return REPOSITORY_LEDGER if REPOSITORY_LEDGER.parent.is_dir() else None


def ledger_row(result: Mapping[str, Any], out: Path | None, head: Mapping[str, Any] | None) -> dict[str, Any]:
    """What the ledger keeps of one test evaluation (soccer: with its head-to-head numbers; driving: per car)."""
    settings = result["settings"]
    row: dict[str, Any] = {
        "format": LEDGER_FORMAT,
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "commit": code_revision(),
        "scenario": result.get("scenario", "robocup"),
        "evaluated": _who(result["evaluated"]),
        "opponent": _who(result["opponent"]) if "opponent" in result else None,
        "seeds": settings["seeds"], "episodes_per_seed": settings["episodes"],
        "games": len(result["episodes"]),
        "settings": {k: v for k, v in settings.items() if k not in ("seeds", "episodes", "seeding")},
        "summary": {k: v["mean"] for k, v in result["summary"].items()},
        "out": None if out is None else str(out),
        "command": shlex.join(["dynenv-eval", *sys.argv[1:]]),
    }
    if head is not None:
        row["head_to_head"] = dict(head)
    return row


def _who(side: Mapping[str, Any]) -> dict[str, Any]:
    return {k: side[k] for k in ("spec", "kind", "sha256", "greedy", "team") if k in side}


def append_row(path: Path, row: Mapping[str, Any]) -> None:
    """One line at the end of ``path`` (created if missing), synced to disk before returning."""
    line = json.dumps(row, sort_keys=True, allow_nan=False) + "\n"
    with open(path, "a", encoding="utf-8") as handle:
        handle.write(line)
        handle.flush()
        os.fsync(handle.fileno())


def read_ledger(path: Path) -> list[dict[str, Any]]:
    """Every row; ValueError naming the line of a row that is not one of ours."""
    rows = []
    for number, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as error:
            raise ValueError(f"{path}:{number}: not JSON ({error})") from None
        if not isinstance(row, dict) or row.get("format") != LEDGER_FORMAT:
            raise ValueError(f"{path}:{number}: not a {LEDGER_FORMAT} row")
        rows.append(row)
    return rows


def rows_of(rows: list[dict[str, Any]], sha256: str) -> list[dict[str, Any]]:
    """The rows in which the policy with this sha256 (or a prefix of it) played, as either side."""
    def played(side: Mapping[str, Any] | None) -> bool:
        return bool(side) and str(side.get("sha256", "")).startswith(sha256)
    return [r for r in rows if played(r["evaluated"]) or played(r.get("opponent"))]
