"""The result of ``dynenv-eval`` (format ``dynenv_eval/1``) as data, for both scenarios: the reward terms every
episode record holds, per-seed means and their summary over seeds, the JSON file (written atomically, loaded with a
clear error for a foreign file), and several runs' results merged into one whose units are the runs.

A result holds ``format``, ``settings``, ``evaluated`` (and for soccer ``opponent``), ``episodes`` (every record),
``per_seed`` (one row of means per seed: the statistical unit), ``summary`` (mean, sd and n over seeds of each
per-seed number) and, for soccer, ``counts``; a driving result adds ``scenario: driving``. ROS-free, no torch.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from dynenv_ros.sim.reward_terms import RewardTerm

FORMAT = "dynenv_eval/1"
TERMS = tuple(term.name.lower() for term in RewardTerm)


# -- per-seed numbers --------------------------------------------------------------------------------------------
def float_mean(values: Iterable[float]) -> float:
    """The mean as a plain float (JSON-ready) of numbers or bools; soccer and driving per-seed rows."""
    return float(np.mean([float(v) for v in values]))


def summarize(per_seed: Sequence[Mapping[str, Any]], metrics: Sequence[str]) -> dict[str, dict[str, float]]:
    """Mean, sample standard deviation (0 for one seed) and n over seeds of every per-seed number in ``metrics``
    (each scenario passes its own: ``soccer.SEED_METRICS``, ``driving.SEED_METRICS``)."""
    out = {}
    for metric in metrics:
        values = np.array([row[metric] for row in per_seed], float)
        out[metric] = {"mean": float(values.mean()), "sd": float(values.std(ddof=1)) if len(values) > 1 else 0.0,
                       "n": int(len(values))}
    return out



# -- files -------------------------------------------------------------------------------------------------------
def write_json(result: Mapping[str, Any], path: str | os.PathLike[str]) -> None:
    """Write the result (via ``path.tmp`` and a rename)."""
    target = Path(path)
    if not target.parent.is_dir():
        raise ValueError(f"cannot write {target}: folder {target.parent} does not exist")
    if target.is_dir():
        raise ValueError(f"cannot write {target}: it is a folder (give a file name)")
    tmp = target.with_name(target.name + ".tmp")
    tmp.write_text(json.dumps(result, indent=1, allow_nan=False) + "\n")
    try:
        os.replace(tmp, target)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise


def load_evaluation(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A result written by ``write_json``; a clear ValueError for a missing, unreadable or foreign file."""
    source = Path(path)
    if not source.is_file():
        raise ValueError(f"evaluation file {source} does not exist")
    try:
        data = json.loads(source.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"evaluation file {source} is not readable JSON: {error}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("per_seed"), list):
        raise ValueError(f"evaluation file {source} is not a {FORMAT} result")
    return data



# -- runs as the unit --------------------------------------------------------------------------------------------
def merge_runs(results: Sequence[Mapping[str, Any]], names: Sequence[str]) -> dict[str, Any]:
    """One result whose per-seed rows are training runs, for BEST with the run as the unit when each run was
    evaluated on several seeds: row k is ``results[k]``'s mean over its seeds of every per-seed number (its
    ``episodes`` summed), ``seed`` k and ``unit`` ``names[k]``. The inputs must share their scenario and settings
    (episodes, seeds, players or cars, perception, ...): a clear ValueError names what differs."""
    if len(results) < 1 or len(results) != len(names):
        raise ValueError("merge needs one name per result and at least one result")
    first = results[0]
    for name, result in zip(names[1:], results[1:]):
        if result.get("scenario", "robocup") != first.get("scenario", "robocup"):
            raise ValueError(f"{name}: scenario {result.get('scenario', 'robocup')!r}, the first result's is "
                             f"{first.get('scenario', 'robocup')!r}")
        differ = sorted(k for k in set(result["settings"]) | set(first["settings"])
                        if result["settings"].get(k) != first["settings"].get(k))
        if differ:
            raise ValueError(f"{name}: settings differ from the first result's in {', '.join(differ)}")
    keys = [k for k, v in first["per_seed"][0].items() if k not in ("seed", "episodes") and
            isinstance(v, (int, float)) and not isinstance(v, bool)] if first["per_seed"] else []
    rows = []
    for k, (name, result) in enumerate(zip(names, results)):
        seeds = result["per_seed"]
        if not seeds or any(key not in row for row in seeds for key in keys):
            raise ValueError(f"{name}: its per-seed rows do not have the first result's numbers")
        row: dict[str, Any] = {"seed": k, "unit": name, "episodes": int(sum(r["episodes"] for r in seeds))}
        row.update({key: float_mean(r[key] for r in seeds) for key in keys})
        rows.append(row)
    merged = {key: value for key, value in first.items() if key not in ("episodes", "per_seed", "summary", "counts")}
    merged["evaluated"] = {"spec": "runs", "kind": "runs",
                           "units": [{"unit": name, **result["evaluated"]} for name, result in zip(names, results)]}
    merged["episodes"] = [dict(record, unit=name) for name, result in zip(names, results)
                          for record in result["episodes"]]
    merged["per_seed"] = rows
    merged["summary"] = summarize(rows, keys)
    return merged



__all__ = ["FORMAT", "TERMS", "float_mean", "summarize", "write_json", "load_evaluation", "merge_runs"]
