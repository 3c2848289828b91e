#!/usr/bin/env python3
"""policy_node/pretrained/README.md and policy_node/pretrained/driving/README.md from the files beside them, so that
what they say about the shipped policies can never drift from the policies; the same for each soccer policy shipped
once and kept whole in a folder of its own (``ARCHIVED``).

Usage::

    .venv/bin/python tools/pretrained_readme.py           # write every README
    .venv/bin/python tools/pretrained_readme.py --check   # exit 1 if a README is not what its files give

Every figure and name in the README comes from a file: the policy file's safetensors header (the agent's config,
the training metadata: variant, training config, env steps, the code revision it was trained at), the SHA-256 of
``policy.safetensors`` and ``policy.onnx``, ``train_config.json`` / ``train_summary.json`` (checked against the
header), the ``dynenv-eval`` results in ``eval/*.json`` (each must record the SHA-256 of this policy file: the
evaluation of another policy is refused), the training presets of config/train/ (which one the training config is,
and the ``--set`` overrides that make it), docs/results.md's table of runs (whether the policy is one of them), and
git (whether the code revision it was trained at includes the fixes listed in ``FIXES``), ``train_stages.json`` (and
the headers of the policy files its later runs started from), and the test ledger (every row of this policy's
weights, as this file, as the training checkpoint it was written from or as a committed file with the same tensor
data; which of issue 39's ``BARS`` they meet). The commands that reproduce each evaluation are built from the
evaluation's own settings; the split their seeds lie in heads their table.

ROS-free; torch is imported only to read the safetensors header (``agent.checkpoint``).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any, Mapping, NamedTuple, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FOLDER = Path("policy_node") / "pretrained"
DRIVING_FOLDER = FOLDER / "driving"
# Soccer policies that were shipped once, kept whole in a folder of their own (the same files as the shipped one's) so
# that every figure about them stays true: folder -> (the README's title, what the folder is).
ARCHIVED = {
    Path("docs") / "results_data" / "issue26" / "shipped_2fd24e79": (
        "The soccer policy shipped before the league policy",
        "This folder keeps, whole, the policy that `policy_node/pretrained/` held from 27 to 29 Nov 2026 "
        "(docs/results.md, \"Learning to play\"), so that every figure about it stays true. Issue 39's league policy "
        "replaced it there (docs/results.md, \"Learning beyond the teacher\"); the league runs started from this "
        "file (the `init_policy` of config/train/league.yaml, league_sizes.yaml and beyond_teacher.yaml)."),
    Path("docs") / "results_data" / "issue39" / "shipped_ca882145": (
        "The league policy shipped before the privileged league's",
        "This folder keeps, whole, the policy that `policy_node/pretrained/` held from 29 to 30 Nov 2026 "
        "(`league_anchor_s0` at +270,592 env steps; docs/results.md, \"Learning beyond the teacher\"), so that every "
        "figure about it stays true. It met the 2v2 bar against `perceiving` on the test split, not the one against "
        "the ground-truth team; `league_privileged_5v5_s0`'s end, which met both, replaced it there. The privileged "
        "league runs started from its weights (`docs/results_data/issue39/policies/league_anchor_s0_271k.safetensors`, "
        "the `init_policy` of config/train/league_privileged.yaml)."),
}
FOLDERS = (FOLDER, DRIVING_FOLDER, *ARCHIVED)
POLICY, ONNX = "policy.safetensors", "policy.onnx"
POLICY_SUFFIX = ".safetensors"
EVAL_DIR = "eval"
RESULTS_DOC = Path("docs") / "results.md"
PRESETS = Path("config") / "train"
OPPONENT_ORDER = ("random", "scripted", "perceiving")
# Issue 39's bars for the shipped soccer policy ("Done when"), each on the test split over at least MIN_BAR_GAMES
# games: (opponent, robots per team, whether it must also win at least twice as many games as it loses, in words).
BARS = (("perceiving", 2, True, "against `perceiving` at 2v2"),
        ("scripted", 2, False, "against the ground-truth `scripted` team at 2v2"),
        ("perceiving", 5, False, "at 5v5 against `perceiving`"))
MIN_BAR_GAMES = 100
DRIVING_POLICY_EVAL = "policy.json"      # the driving policy's evaluation; the other files: reference drivers
PAPER_DRIVING_PRED = 26.47               # the paper's Pred, reward per car and episode (its Table 2)
# Fixes to training that a policy trained at an earlier revision lacks: (commit, what was wrong, whether the policy's
# training config was affected by it).
FIXES = (
    ("066a7cb", "the trainer computed RCM's attention-weighted forward loss and dropped it (it switched the forward "
                "loss on for ICM's plain forward model only)",
     lambda config: _losses(config).rcm_attention),
)


class ReadmeError(ValueError):
    """The files do not describe one policy consistently (or cannot be read)."""


class GitUnknown(ReadmeError):
    """git cannot tell whether a revision includes a fix (no git, or a clone without that history)."""


# -- reading the files -------------------------------------------------------------------------------------------
def header_metadata(path: Path) -> dict[str, Any]:
    """A policy file's safetensors ``__metadata__``, read from the header alone (the tools scan every committed
    policy file for its ``data_sha256``; the tensor data is never needed)."""
    import struct
    from dynenv_ros.agent.checkpoint import safetensors_header
    with path.open("rb") as file:
        first = file.read(8)
        data = first + (file.read(struct.unpack("<Q", first)[0]) if len(first) == 8 else b"")
    return safetensors_header(data)[0].get("__metadata__") or {}


def policy_header(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(agent config, training meta) from a policy file's safetensors header."""
    from dynenv_ros.agent.checkpoint import FORMAT
    metadata = header_metadata(path)
    if metadata.get("format") != FORMAT:
        raise ReadmeError(f"{path} is not a {FORMAT} policy file")
    return json.loads(metadata["config"]), json.loads(metadata.get("meta", "{}"))


def data_sha256(path: Path) -> str | None:
    """The SHA-256 of a policy file's tensor data, as its safetensors header records it (None where it records
    none): two files with the same one hold the same weights."""
    return header_metadata(path).get("data_sha256")


def load_evaluations(folder: Path, digest: str) -> list[tuple[Path, dict[str, Any]]]:
    """The ``dynenv-eval`` soccer results in ``folder/eval`` (random, scripted, perceiving first), each checked to
    be an evaluation of the policy file whose SHA-256 is ``digest``."""
    from dynenv_ros.evaluation.results import load_evaluation
    found = []
    for path in sorted((folder / EVAL_DIR).glob("*.json")):
        result = load_evaluation(path)
        evaluated = result.get("evaluated", {})
        if result.get("scenario", "robocup") != "robocup" or evaluated.get("kind") != "checkpoint":
            raise ReadmeError(f"{path} is not a soccer evaluation of a policy file")
        if evaluated.get("sha256") != digest:
            raise ReadmeError(f"{path} evaluates another policy: its sha256 is {evaluated.get('sha256')}, "
                              f"{folder / POLICY}'s is {digest}; re-run its command (README) to evaluate this one")
        found.append((path, result))
    if not found:
        raise ReadmeError(f"no evaluation in {folder / EVAL_DIR}: run the dynenv-eval commands first")
    rank = {name: k for k, name in enumerate(OPPONENT_ORDER)}
    return sorted(found, key=lambda item: (rank.get(item[1]["opponent"]["spec"], len(rank)), item[0].name))


def _losses(config: Mapping[str, Any]):
    from dynenv_ros.learning.config import TrainConfig
    return TrainConfig.from_dict(config).losses()


def training_preset(root: Path, config: Mapping[str, Any]) -> tuple[str, list[str]]:
    """The preset of config/train/ that ``config`` is with the fewest overrides, and those overrides as
    ``dynenv-train`` arguments (``--seed S``, ``--set key=value``); checked by loading the preset with them."""
    from dynenv_ros.learning.config import load_config
    best: tuple[int, str, list[str]] | None = None
    for path in sorted((root / PRESETS).glob("*.yaml")):
        preset = load_config(path).to_dict()
        differ = [key for key in config if preset.get(key) != config[key]]
        if best is None or len(differ) < best[0]:
            best = (len(differ), path.stem, differ)
    if best is None:
        raise ReadmeError(f"no training presets in {root / PRESETS}")
    _, name, differ = best
    arguments = []
    for key in differ:
        arguments += ["--seed", str(config[key])] if key == "seed" else ["--set", f"{key}={_yaml(config[key])}"]
    overrides = [a for a in arguments[1::2] if "=" in a]
    rebuilt = load_config(root / PRESETS / f"{name}.yaml", overrides).to_dict()
    rebuilt["seed"] = config.get("seed", rebuilt["seed"])
    if any(rebuilt.get(key) != config[key] for key in config):
        raise ReadmeError(f"preset {name} with {' '.join(arguments)} does not give the training config")
    return name, arguments


def training_stages(here: Path, config: Mapping[str, Any]) -> list[dict[str, Any]] | None:
    """The stages of ``train_stages.json`` (a run trained on after a change of settings, e.g. self-play and then
    against another opponent, or a new run started from the policy the earlier stages made), checked by
    ``stage_runs``. None without the file."""
    runs = stage_runs(here, config)
    return None if runs is None else [stage for run in runs for stage in run.stages]


class StageRun(NamedTuple):
    """One training run of ``train_stages.json``: its stages (the first starts it, the others resume it), the
    training config they give, and the policy file it started from (``init_policy``) with that file's header meta
    (None for the first run)."""
    stages: list[dict[str, Any]]
    config: dict[str, Any]
    start: Path | None
    start_meta: dict[str, Any] | None
    start_meta_from: Path | None = None     # the file whose header gave start_meta (``recipe_meta``)


def stage_runs(here: Path, config: Mapping[str, Any]) -> list[StageRun] | None:
    """The runs of ``train_stages.json``, checked: the first stage starts a run (``--config``, ``--seed``,
    ``--set``); a later one resumes the run before it (``--resume``, ``--set``) or starts a new run from a policy
    file (``--config`` with an ``init_policy``). The last run's stages, applied in order, must give exactly the
    training config of the policy file's header; each later run must start from a committed policy file whose
    header's training config is what the runs before gave (its own ``init_policy`` aside: that is the file the run
    before started from, under the name it had then). None without the file."""
    from dynenv_ros.learning.config import load_config
    path = here / "train_stages.json"
    if not path.is_file():
        return None
    stages = json.loads(path.read_text())["stages"]
    runs: list[tuple[int, list[dict[str, Any]], Any]] = []        # (its first stage's index, its stages, config)
    for k, stage in enumerate(stages):
        args = list(stage["train"])
        options = dict(zip(args[0::2], args[1::2]))
        overrides = [v for key, v in zip(args[0::2], args[1::2]) if key == "--set"]
        if "--config" in options:
            seed = [f"seed={options['--seed']}"] if "--seed" in options else []
            cfg = load_config(ROOT / PRESETS / f"{options['--config']}.yaml", [*overrides, *seed])
            if k and not cfg.init_policy:
                raise ReadmeError(f"{path}: stage {k + 1} starts a new run without an init_policy, so it does not "
                                  f"carry on from the stages before it")
            runs.append((k, [stage], cfg))
        elif not k:
            raise ReadmeError(f"{path}: the first stage must start a run with --config")
        elif "--resume" in options:
            first, stages_of_run, cfg = runs[-1]
            runs[-1] = (first, [*stages_of_run, stage], load_config(None, overrides, base=cfg))
        else:
            raise ReadmeError(f"{path}: stage {k + 1} must resume the run (--resume) or start one (--config)")
    if not runs or runs[-1][2].to_dict() != with_later_defaults(config):
        raise ReadmeError(f"{path}: its stages do not give the training config in {POLICY}'s header")
    out = [StageRun(runs[0][1], runs[0][2].to_dict(), None, None)]
    for (first, stages_of_run, cfg), (_, _, before) in zip(runs[1:], runs):
        start = ROOT / cfg.init_policy
        if not start.is_file():
            raise ReadmeError(f"{path}: stage {first + 1} starts from {cfg.init_policy}, which is not in the "
                              f"repository")
        start_meta, meta_from = recipe_meta(start)
        given = {k: v for k, v in with_later_defaults(start_meta.get("config") or {}).items() if k != "init_policy"}
        if given != {k: v for k, v in before.to_dict().items() if k != "init_policy"}:
            raise ReadmeError(f"{path}: {cfg.init_policy}, which stage {first + 1} starts from, was not trained "
                              f"with the config the stages before it give")
        out.append(StageRun(stages_of_run, cfg.to_dict(), start, start_meta, meta_from))
    return out


def recipe_meta(path: Path) -> tuple[dict[str, Any], Path]:
    """(The training meta of the policy file ``path``, the file whose header holds it): its own header's, or — for a
    file saved with its weights alone (its meta names no training config) — that of a committed policy file with the
    same tensor data (the header's ``data_sha256``) that carries one, such as the shipped file written from the same
    checkpoint. Searched in docs/results_data/ and the shipped folder; the file's own meta where none is found."""
    _, meta = policy_header(path)
    if meta.get("config"):
        return meta, path
    mine = data_sha256(path)
    if not mine:
        return meta, path
    for candidate in _policy_files(ROOT / "docs" / "results_data", ROOT / FOLDER):
        if candidate != path and data_sha256(candidate) == mine:
            twin = policy_header(candidate)[1]
            if twin.get("config"):
                return twin, candidate
    return meta, path


def _policy_files(*folders: Path) -> list[Path]:
    """Every ``*.safetensors`` under ``folders``, sorted; linked folders followed (``Path.rglob`` does not follow
    them, and a checkout may link its data folders in, as the doc tests' scratch views do)."""
    found = [Path(top) / name for folder in folders for top, _, names in os.walk(folder, followlinks=True)
             for name in names if name.endswith(".safetensors")]
    return sorted(found)


def with_later_defaults(config: Mapping[str, Any]) -> dict[str, Any]:
    """``config`` plus the settings added to the trainer after it was written, at their defaults (a new setting's
    default keeps the behaviour from before it existed, so an older policy's recipe is unchanged by it)."""
    from dynenv_ros.learning.config import TrainConfig
    return {**{k: v for k, v in TrainConfig().to_dict().items() if k not in config}, **config}


def _yaml(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    return str(value)


def listed_sha256s(root: Path) -> list[str]:
    """The policy sha256s (12 hex digits or more, in backquotes) that docs/results.md lists, in page order."""
    doc = root / RESULTS_DOC
    return list(dict.fromkeys(re.findall(r"`([0-9a-f]{12,64})`", doc.read_text()))) if doc.is_file() else []


def _opening(title: str, digest: str, onnx_digest: str, agent: str, note: str | None = None) -> list[str]:
    """A README's title, its do-not-edit line, ``note`` (what the folder is, for an archived policy) and the first
    lines of "What it is": the files and their sha256s."""
    return [f"# {title}", "",
            "<!-- Written by tools/pretrained_readme.py from the files of this folder; do not edit by hand. "
            "Regenerate: .venv/bin/python tools/pretrained_readme.py -->", "",
            *([note, ""] if note else []),
            "## What it is", "",
            f"`{POLICY}` (torch runtime; sha256 `{digest}`) and `{ONNX}` (onnxruntime; sha256 `{onnx_digest}`) hold "
            f"one trained {agent}. From the policy file's header (`train_config.json` and `train_summary.json` are "
            f"the same):", ""]


def _league() -> str:
    """What the league opponent is, from its members (envs.league)."""
    from dynenv_ros.envs.league import LEAGUE_MEMBERS
    said = {"keeper_and_chasers": "`keeper_and_chasers` (the ground-truth `scripted` team)",
            "snapshot": "`snapshot` (a frozen copy of the learner)"}
    members = [said.get(member, f"`{member}`") for member in LEAGUE_MEMBERS]
    return (f"per world and episode one of {', '.join(members[:-1])} and {members[-1]}, drawn by prioritized "
            f"fictitious self-play: envs/league.py")


def _recipe_head(config: Mapping[str, Any], losses: Mapping[str, Any]) -> str:
    return (f"- **{config['algorithm'].upper()}, variant `{config['variant']}`** (its losses: "
            f"{', '.join(f'`{k}`' for k in losses) or 'none'})")


def _budget_line(meta: Mapping[str, Any], how: str, runs: Sequence[StageRun] = ()) -> str:
    """The env steps and minutes of training; for a policy of several runs (``stage_runs``), their sum (each
    earlier run's share from the header of the file the next one started from) and the last run's own."""
    own = (f"{_n(meta['env_steps'])} env steps** ({_n(meta['updates'])} updates, {_n(meta['episodes'])} "
           f"episodes) in {_n(meta['wall_seconds'] / 60)} minutes {how}")
    starts = [run.start_meta for run in runs if run.start_meta is not None]
    if not starts:
        return f"- **{own};"
    steps = sum(m["env_steps"] for m in starts) + meta["env_steps"]
    minutes = (sum(m["wall_seconds"] for m in starts) + meta["wall_seconds"]) / 60
    return (f"- **{_n(steps)} env steps** in all, over {len(runs)} runs ("
            + " + ".join(_n(m["env_steps"]) for m in [*starts, meta]) + f"), in {_n(minutes)} minutes; the last "
            f"run's, which the header counts: **{own};")


def recipe_and_listing(root: Path, here: Path, config: Mapping[str, Any], revision: str, digest: str) -> list[str]:
    """The training recipe, then the "What it is not" heading and whether docs/results.md is about this file."""
    return [*training_recipe(root, here, config, revision), "## What it is not", "", *results_listing(root, digest)]


def results_listing(root: Path, digest: str) -> list[str]:
    """The README's line on whether docs/results.md's figures are about this policy file (by its sha256)."""
    listed = listed_sha256s(root)
    mine = [prefix for prefix in listed if digest.startswith(prefix)]
    if mine:
        return [f"- Its sha256 is among those {RESULTS_DOC} lists (`{mine[0]}`): that page's figures for that run "
                f"are about this file."]
    if listed:
        return [f"- It is **not one of the runs of {RESULTS_DOC}**: its sha256 begins with none of the "
                f"{len(listed)} policy sha256s that page lists, so none of its figures is about this file."]
    return []


def includes_fix(root: Path, fix: str, revision: str) -> bool:
    """Whether ``revision`` has ``fix`` among its ancestors (git); GitUnknown when git cannot tell."""
    try:
        done = subprocess.run(["git", "-C", str(root), "merge-base", "--is-ancestor", fix, revision],
                              capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise GitUnknown(f"git cannot tell whether {revision} includes {fix}: {error}") from None
    if done.returncode not in (0, 1):
        raise GitUnknown(f"git cannot tell whether {revision} includes {fix}: {done.stderr.strip()}")
    return done.returncode == 0


# -- the text ----------------------------------------------------------------------------------------------------
def _n(value: float) -> str:
    """A figure as the README prints it: 3 significant digits (integers whole, with thousands separators)."""
    if float(value).is_integer() and abs(value) >= 100:
        return f"{int(value):,}"
    return f"{value:.3g}"


def _mean_sd(stats: Mapping[str, float]) -> str:
    return f"{_n(stats['mean'])} ± {_n(stats['sd'])}"


def _totals(result: Mapping[str, Any]) -> tuple[int, int]:
    return (sum(r["goals_for"] for r in result["episodes"]), sum(r["goals_against"] for r in result["episodes"]))


def eval_command(path: str, result: Mapping[str, Any], policy: str | None = None) -> str:
    """The ``dynenv-eval`` command that writes ``result`` to ``path`` (from its own settings), evaluating ``policy``
    (the file whose sha256 the result records; by default the path the result names). Seeds that are the first N
    of a validation or test split are asked for as such (``--split S --num-seeds N``: what dynenv-eval takes for
    those splits), others by number."""
    settings = result["settings"]
    words = [".venv/bin/dynenv-eval", policy or result["evaluated"]["path"], "--opponent", result["opponent"]["spec"],
             "--episodes", str(settings["episodes"]), *_seed_words(settings["seeds"]),
             "--players-per-team", str(settings["players_per_team"]), *_perception_words(settings),
             "--sides", settings["sides"]]
    return shlex.join([*words, *_closing_words(path, settings)])


def _seed_words(seeds: Sequence[int]) -> list[str]:
    from dynenv_ros.evaluation.splits import split_of, split_seeds
    split = split_of(seeds)
    if split in ("validation", "test") and list(seeds) == split_seeds(split, len(seeds)):
        return ["--split", split, "--num-seeds", str(len(seeds))]
    return ["--seeds", *map(str, seeds)]


def _seeds_text(seeds: Sequence[int]) -> str:
    """Seeds as the README prints them: a range where they are consecutive, else each one."""
    if len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{_n(seeds[0])}–{_n(seeds[-1])}"
    return ", ".join(map(str, seeds))


def evaluation_split(evaluations: Sequence[tuple[Path, Mapping[str, Any]]]) -> str:
    """The "How it plays" heading's words: which split (evaluation.splits) the evaluations' seeds lie in, and what
    that split is for, read from the seeds of the files themselves."""
    from dynenv_ros.evaluation.splits import split_of
    seeds = sorted({seed for _, result in evaluations for seed in result["settings"]["seeds"]})
    split, where = split_of(seeds), _seeds_text(seeds)
    if split == "validation":
        return (f"validation split, seeds {where}: the games choices are made on; the test split's are in the "
                f"ledger below")
    if split == "test":
        return f"test split, seeds {where}: each of these games is also in the test ledger below"
    if split == "train":
        return f"seeds {where}: train split, which choices may have looked at"
    return f"seeds {where}, of more than one split"


def _difference(head_to_head: Mapping[str, Any] | None) -> str:
    """A head-to-head's goal difference a game and its interval, or nothing for an evaluation without one."""
    if not head_to_head:
        return ""
    interval = head_to_head.get("interval")
    return f"{head_to_head['goal_difference_per_game']:+.2f}" + (
        f" ({interval[0]:+.2f} to {interval[1]:+.2f})" if interval else "")


def _perception_words(settings: Mapping[str, Any]) -> list[str]:
    perception = settings["perception"]
    if isinstance(perception, Mapping):
        return ["--perception", perception["preset"], "--noise-magnitude", _yaml(perception["noise_magnitude"])]
    return ["--perception", str(perception)]


def _closing_words(path: str, settings: Mapping[str, Any]) -> list[str]:
    """An evaluation command's episode length, greedy flag and output (``settings``: the evaluation's)."""
    words = []
    env_config = dict(settings.get("env_config") or {})
    if "episode_seconds" in env_config:
        words += ["--episode-seconds", _yaml(env_config.pop("episode_seconds"))]
    if env_config:
        raise ReadmeError(f"{path}: env_config {sorted(env_config)} has no dynenv-eval option")
    if settings.get("greedy"):
        words.append("--greedy")
    if settings.get("games_at_once", 1) > 1:
        words += ["--games-at-once", str(settings["games_at_once"])]
    return [*words, "--quiet", "--out", path]


def training_recipe(root: Path, here: Path, config: Mapping[str, Any], revision: str) -> list[str]:
    """The README's lines on how the policy was trained: its preset and overrides as one ``dynenv-train`` command,
    or the commands of ``train_stages.json``; and why they reproduce the recipe, not the file."""
    stages = training_stages(here, config)
    if stages is None:
        preset, arguments = training_preset(root, config)
        budget = ("The run stops after `max_minutes` of wall time, so the env steps it reaches (and its weights) "
                  "depend on the machine: the command reproduces the recipe, not the file."
                  if config.get("max_minutes") is not None else
                  "A budget in env steps: the command reproduces the recipe; the weights depend on the machine's "
                  "timing" + (" (the asynchronous workers' policy lag)." if config.get("runner") == "async" else "."))
        return [f"- training preset **`{preset}`** (config/train/{preset}.yaml) with these overrides, at code "
                f"revision `{revision}`:", "", "```bash",
                f"git checkout {revision}",
                shlex.join([".venv/bin/dynenv-train", "--config", preset, *arguments, "--no-progress"]),
                "```", "", f"  {budget}", ""]
    runs = stage_runs(here, config) or []
    out = [f"- trained in {len(stages)} stages"
           + (f" and {len(runs)} runs, each later run started from the policy the runs before it made"
              if len(runs) > 1 else "")
           + f" (`train_stages.json`, checked to give the training config; the header records code revision "
             f"`{revision}`, that of the last process that trained it):", ""]
    number = 0
    for run in runs:
        for stage in run.stages:
            number += 1
            preset = dict(zip(stage["train"][0::2], stage["train"][1::2])).get("--config")
            named = f"**`{preset}`** (config/train/{preset}.yaml): " if preset else ""
            counted = ("its header counts" if run.start_meta_from in (None, run.start) else
                       f"its weights alone are in that file; the header of "
                       f"`{run.start_meta_from.relative_to(ROOT)}`, the same weights, counts")
            started = (f"a new run from `{run.config['init_policy']}` ({counted} "
                       f"{_n(run.start_meta['env_steps'])} env steps); "
                       if run.start is not None and stage is run.stages[0] else "")
            out.append(f"  {number}. {named}{started}{stage['why']}")
    out += ["", "```bash", f"git checkout {stages[0].get('revision', revision)}"]
    for k, run in enumerate(runs):
        if run.start is not None:
            out.append(f"# the next run starts from the run above's policy at {_n(run.start_meta['env_steps'])} env "
                       f"steps (its init_policy, committed as {run.config['init_policy']})")
        for stage in run.stages:
            if (k or stage is not run.stages[0]) and stage.get("revision"):   # code the header's revision lacks
                out.append(f"git checkout {stage['revision']}")
            out.append(shlex.join([".venv/bin/dynenv-train", *stage["train"], "--no-progress"]))
    return out + ["```", "", "  A budget in env steps: the commands reproduce the recipe; the weights depend on the "
                  "machine's timing (the asynchronous workers' policy lag).", ""]


def shipped_files(here: Path) -> tuple[str, str, dict[str, Any], dict[str, Any], dict[str, Any]]:
    """(policy sha256, ONNX sha256, agent config, training meta, training config) of the policy in ``here``,
    with ``train_config.json`` and ``train_summary.json`` checked against the policy file's header."""
    from dynenv_ros.agent.checkpoint import sha256
    digest, onnx_digest = sha256(here / POLICY), sha256(here / ONNX)
    agent, meta = policy_header(here / POLICY)
    config = json.loads((here / "train_config.json").read_text())
    summary = json.loads((here / "train_summary.json").read_text())
    if meta.get("config") != config:
        raise ReadmeError(f"train_config.json is not the training config in {POLICY}'s header")
    for key in ("env_steps", "updates", "episodes"):
        if meta.get(key) != summary.get(key):
            raise ReadmeError(f"train_summary.json's {key} {summary.get(key)} is not the header's {meta.get(key)}")
    return digest, onnx_digest, agent, meta, config


LEDGER = Path("docs") / "results_data" / "test_ledger.jsonl"


class SamePolicy(NamedTuple):
    """Another sha256 under which this policy's weights were evaluated, and what it is: the training checkpoint the
    file was written from, or a committed policy file with the same tensor data."""
    digest: str
    short: str           # the ledger table's "evaluated as"
    what: str            # the sentence above the table


def same_policy(root: Path, here: Path, meta: Mapping[str, Any]) -> list[SamePolicy]:
    """The other digests of this policy's weights that the test ledger may hold: the ``model.safetensors`` of the
    training checkpoint the file was written from (its header's ``source_checkpoint``: what ``dynenv-eval`` of that
    checkpoint records), and each committed policy file that a ledger row names whose header's ``data_sha256`` (the
    tensor data) is this file's, found under the repository by the row's path and checked by its sha256."""
    from dynenv_ros.agent.checkpoint import sha256
    from dynenv_ros.evaluation.ledger import read_ledger
    out = []
    source = meta.get("source_checkpoint") or {}
    if source.get("model_sha256"):
        out.append(SamePolicy(source["model_sha256"], "the training checkpoint it was written from",
                              f"evaluated as the training checkpoint this file was written from (`{source['path']}`, "
                              f"{_n(source['step'])} env steps; the sha256 of its `model.safetensors`, "
                              f"`{source['model_sha256'][:12]}`, is what those rows record)"))
    path = root / LEDGER
    if not path.exists():
        return out
    mine = data_sha256(here / POLICY)
    seen = {sha256(here / POLICY), *(same.digest for same in out)}
    for row in read_ledger(path):
        digest, spec = row["evaluated"].get("sha256"), str(row["evaluated"].get("spec", ""))
        if not digest or digest in seen or not spec.endswith(POLICY_SUFFIX):
            continue
        seen.add(digest)
        file = _committed_file(root, spec, digest)
        if file is None:
            continue
        if mine and data_sha256(root / file) == mine:
            out.append(SamePolicy(digest, f"`{file.name}`", f"evaluated as `{file}`, a committed policy file with the "
                                  f"same weights (its header's `data_sha256` is this file's)"))
    return out


def _committed_file(root: Path, spec: str, digest: str) -> Path | None:
    """The file under ``root`` that a ledger row's path names (the row may name it from another checkout: the
    longest tail of the path that is a file here), if its sha256 is ``digest``; else None."""
    from dynenv_ros.agent.checkpoint import sha256
    parts = Path(spec).parts
    for start in range(len(parts)):
        if Path(parts[start]).is_absolute():
            continue
        relative = Path(*parts[start:])
        if (root / relative).is_file():
            return relative if sha256(root / relative) == digest else None
    return None


def _rows(root: Path, digests: Sequence[str]) -> list[tuple[dict[str, Any], int]]:
    """The ledger rows in which a policy with one of ``digests`` played, in ledger order, each with the index of
    the digest it played under."""
    from dynenv_ros.evaluation.ledger import read_ledger, rows_of
    path = root / LEDGER
    if not path.exists():
        return []
    rows = read_ledger(path)
    found = {id(row): k for k, digest in reversed(list(enumerate(digests))) for row in rows_of(rows, digest)}
    return [(row, found[id(row)]) for row in rows if id(row) in found]


def ledger_lines(root: Path, digest: str, driving: bool = False, same_policy: Sequence[SamePolicy] = ()) -> list[str]:
    """The test ledger's rows in which this policy played (every one, in the order they were written), as this
    file or under one of ``same_policy``'s digests (each row says which)."""
    rows = _rows(root, [digest, *(same.digest for same in same_policy)])
    out = ["## The test ledger", "",
           "Every evaluation of this policy on the test split (seeds 20,000–29,999), as dynenv-eval's `--split test` "
           "appended it to `docs/results_data/test_ledger.jsonl`; the earlier tables are on seeds that choices "
           "were made on.", ""]
    if not rows:
        return out + ["No test-split evaluation of this policy yet.", ""]
    if driving:
        out += ["| date | commit | games | reward per car and episode | share of cars home | share crashed |",
                "|---|---|---:|---:|---:|---:|"]
        for row, _ in rows:
            s = row["summary"]
            out.append(f"| {row['date'][:10]} | `{str(row['commit'])[:7]}` | {row['games']} | {s['total']:.2f} | "
                       f"{s['home_rate']:.2f} | {s['crash_rate']:.2f} |")
        return out + [""]
    used = sorted({k for _, k in rows if k})
    if used:
        out += ["The same weights were also " + "; and ".join(same_policy[k - 1].what for k in used) + ". Those rows "
                "are this policy's too; the column *evaluated as* says which each row is.", ""]
    out += ["| date | commit | evaluated as | opponent | robots a side | games | W/D/L | goals for : against | goal "
            "difference a game (95 % interval) | beats it |", "|---|---|---|---|---:|---:|---:|---:|---:|---|"]
    for row, k in rows:
        h = row["head_to_head"]
        opponent = (row.get("opponent") or {}).get("spec", "")
        interval = "" if h["interval"] is None else f" ({h['interval'][0]:+.2f} to {h['interval'][1]:+.2f})"
        size = (row.get("settings") or {}).get("players_per_team", "")
        out.append(f"| {row['date'][:10]} | `{str(row['commit'])[:7]}` | {same_policy[k - 1].short if k else 'this file'}"
                   f" | `{opponent}` | {size} | {h['games']} | {h['wins']}/{h['draws']}/{h['losses']} | "
                   f"{h['goals_for']} : {h['goals_against']} | {h['goal_difference_per_game']:+.3f}{interval} | "
                   f"{'yes' if h['beats'] else 'no'} |")
    return out + [""]


def bar_lines(root: Path, digest: str, same_policy: Sequence[SamePolicy] = ()) -> list[str]:
    """Which of issue 39's bars (``BARS``) this policy meets, from its test-ledger rows (``ledger_lines``'s): a bar
    is met when every row of its opponent and team size, over at least MIN_BAR_GAMES games, has its interval of the
    goal difference above 0 (and, where the bar asks it, at least twice as many wins as losses); with no such row
    it is not tried."""
    digests = [digest, *(same.digest for same in same_policy)]
    rows = [row for row, k in _rows(root, digests) if row["evaluated"].get("sha256") == digests[k]]  # not as opponent
    out = ["### Issue 39's bars", "",
           f"On the test split, over at least {MIN_BAR_GAMES} games, greedy (issue 39, \"Done when\"); from the rows "
           f"above:", ""]
    for opponent, size, twice, words in BARS:
        mine = [row for row in rows if (row.get("opponent") or {}).get("spec") == opponent
                and (row.get("settings") or {}).get("players_per_team") == size
                and row["head_to_head"]["games"] >= MIN_BAR_GAMES]
        if not mine:
            out.append(f"- **not tried** — {words}: no test-split row.")
            continue
        verdicts = [_bar_verdict(row["head_to_head"], twice) for row in mine]
        met = all(ok for ok, _ in verdicts)
        out.append(f"- **{'met' if met else 'not met'}** — {words}: " + "; ".join(text for _, text in verdicts) + ".")
    return out + [""]


def _bar_verdict(h: Mapping[str, Any], twice: bool) -> tuple[bool, str]:
    """(whether one row meets a bar, the row in words)."""
    low, high = h["interval"] if h["interval"] is not None else (float("nan"), float("nan"))
    where = ("the interval above 0" if low > 0 else "beaten: the interval below 0" if high < 0 else
             "level: the interval includes 0")
    text = (f"{h['wins']} wins, {h['draws']} draws, {h['losses']} losses in {h['games']} games, "
            f"{h['goal_difference_per_game']:+.2f} goals a game ({low:+.2f} to {high:+.2f}), {where}")
    ok = low > 0
    if twice:
        enough = h["wins"] >= 2 * h["losses"]
        text += (", and at least twice as many wins as losses" if enough else
                 ", but fewer than twice as many wins as losses")
        ok = ok and enough
    return ok, text


def render(root: Path = ROOT, folder: Path = FOLDER) -> str:
    """The README of ``root/folder``'s policy, from its files (``ReadmeError`` when they disagree): the soccer
    README (the shipped policy's, or an archived one's: ``ARCHIVED``) or, for a driving agent, ``render_driving``'s."""
    if policy_header(root / folder / POLICY)[0].get("scenario", "robocup") == "driving":
        return render_driving(root, folder)
    from dynenv_ros.evaluation.soccer import format_table
    here = root / folder
    archived = ARCHIVED.get(folder)
    digest, onnx_digest, agent, meta, config = shipped_files(here)
    evaluations = load_evaluations(here, digest)
    runs = stage_runs(here, config)
    revision = meta["code_revision"]
    losses = {k: v for k, v in _losses(config).as_dict().items() if v}
    teacher = config.get("teacher")
    self_play = config.get("opponent") == "self"
    sizes = config.get("team_sizes")

    out = _opening(archived[0] if archived else "The shipped policy", digest, onnx_digest,
                   f"agent (feature size {agent['feature_size']}, {agent['head_mode']} head)",
                   archived[1] if archived else None)
    out += [_recipe_head(config, losses)
            + (f", **plus imitation of the scripted `{teacher}`** (imitation weight {_n(config['imitation_coef'])}: "
               f"the {teacher} labels the states the learner reaches; not in the paper, docs/training.md)"
               if teacher else ", pure reinforcement learning (no teacher)") + ";",
            f"- {'in stages (below)' if runs else 'self-play' if self_play else 'against ' + str(config.get('opponent'))}"
            + (f"; the last run against **the league** ({_league()})" if runs and config.get("opponent") == "league"
               else "")
            + f", {config['players_per_team']} per team"
            + (f" (and {', '.join(str(n) for n in sizes if n != config['players_per_team'])}: one network for every "
               f"team size, `team_sizes`, the objects padded to the largest)" if sizes and len(sizes) > 1 else "")
            + f", `{config['perception']}` perception, seed {config['seed']};",
            _budget_line(meta, f"on `{config['device']}` with {config['torch_threads']} torch "
                               f"thread{'s' if config['torch_threads'] != 1 else ''}", runs or ())]
    out += recipe_and_listing(root, here, config, revision, digest)
    for fix, what, applies in FIXES:
        if applies(config) and not includes_fix(root, fix, revision):
            out.append(f"- It was trained **before the fix of `{fix}`**, at `{revision[:7]}`: {what}. It is a "
                       f"first-pass model of its variant.")
    for _path, result in evaluations:
        goals_for, goals_against = _totals(result)
        if result["opponent"]["spec"] != "random" and goals_for <= goals_against:
            out.append(f"- It is **not a match for the `{result['opponent']['spec']}` team**: {goals_for} goals for, "
                       f"{goals_against} against in {result['counts']['episodes']} games (below).")
    out.append("")

    out += [f"## How it plays ({evaluation_split(evaluations)})", "",
            "The paper's metric (positive reward minus observation reward, per robot and episode) is the headline, "
            "the total reward beside it; mean ± sd over the evaluation seeds (the unit), goals and W/D/L summed over "
            "every game; the goal difference a game with its 95 % interval (a bootstrap over seeds) where the "
            "evaluation has it. Against `random`, the last column is the ratio of the policy's paper's metric to "
            "the random team's in the same episodes.", "",
            "| opponent | games (episodes × seeds) | W/D/L | goals for : against | goal difference a game (95 % "
            "interval) | paper's metric | total reward | opponent's paper's metric | × random's paper's metric |",
            "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for _path, result in evaluations:
        s, counts, settings = result["summary"], result["counts"], result["settings"]
        goals_for, goals_against = _totals(result)
        ratio = (f"{s['paper_metric']['mean'] / s['opponent_paper_metric']['mean']:.2f}x"
                 if result["opponent"]["spec"] == "random" else "")
        out.append(f"| `{result['opponent']['spec']}` | {counts['episodes']} ({settings['episodes']} × "
                   f"{len(settings['seeds'])}) | {counts['wins']}/{counts['draws']}/{counts['losses']} | "
                   f"{goals_for} : {goals_against} | {_difference(result.get('head_to_head'))} | "
                   f"**{_mean_sd(s['paper_metric'])}** | {_mean_sd(s['total'])} | "
                   f"{_mean_sd(s['opponent_paper_metric'])} | {ratio} |")
    out += ["", "Settings of each evaluation: " + "; ".join(
        f"`{path.name}`: seeds {_seeds_text(r['settings']['seeds'])}, {r['settings']['players_per_team']} "
        f"per team, `{r['settings']['perception']}` perception, sides `{r['settings']['sides']}`, "
        f"{'greedy' if r['settings']['greedy'] else 'sampled'} actions" for path, r in evaluations) + ".", ""]

    out += ["### Reproduce", "",
            "Each file in `eval/` is the output of one command (run from the repository root; same code, same "
            "file), and this README is regenerated from them:", "", "```bash"]
    out += [eval_command(str(folder / EVAL_DIR / path.name), result, str(folder / POLICY))
            for path, result in evaluations]
    out += [".venv/bin/python tools/pretrained_readme.py", "```", "",
            (f"`git log -- {folder / EVAL_DIR} {FOLDER / EVAL_DIR}` gives the commit each file was made at (in "
             f"`{FOLDER / EVAL_DIR}`, while this policy was shipped; then copied here)." if archived else
             f"`git log -- {folder / EVAL_DIR}` gives the commit each file was made at."), "",
            "### Per seed", ""]
    for _path, result in evaluations:       # named by this folder's file (the one whose sha256 the result records)
        out += [format_table({**result, "evaluated": {**result["evaluated"], "spec": str(folder / POLICY)}}), ""]

    others = same_policy(root, here, meta)
    out += ledger_lines(root, digest, same_policy=others)
    out += bar_lines(root, digest, others)
    greedy = bool(evaluations) and all(r["settings"]["greedy"] for _, r in evaluations)
    onnx = folder / ONNX
    out += ["## Play it", "",
            (f"`make run ARGS=\"--set team_a={onnx}\"` (team A, through the policy node and onnxruntime, against "
             f"the scripted team B; `make run` alone plays the shipped policy, `{FOLDER}`)" if archived else
             "`make run` (team A, through the policy node and onnxruntime, against the scripted team B)")
            + f", or `ros2 run dynenv_ros policy_node --ros-args -p checkpoint:={onnx} "
            "-p runtime:=onnxruntime" + (" -p greedy:=true" if greedy else "") + "`."
            + (" It was evaluated on its most likely actions (`greedy`), as `make run` plays it (its `greedy` "
               "setting, true by default); sampled actions play worse (docs/results.md)." if greedy else ""), ""]
    return "\n".join(out)


# -- the driving policy ------------------------------------------------------------------------------------------
def load_driving_evaluations(folder: Path, digest: str) -> tuple[tuple[Path, dict[str, Any]],
                                                                  list[tuple[Path, dict[str, Any]]]]:
    """(the policy's evaluation ``eval/policy.json``, the reference drivers' evaluations: every other file in
    ``eval/``), each a driving evaluation; the policy's must be of the file whose SHA-256 is ``digest``, and every
    reference must have driven the same episodes (seeds, episodes, cars, perception, episode settings)."""
    from dynenv_ros.evaluation.results import load_evaluation
    policy, references = None, []
    for path in sorted((folder / EVAL_DIR).glob("*.json")):
        result = load_evaluation(path)
        if result.get("scenario") != "driving":
            raise ReadmeError(f"{path} is not a driving evaluation")
        evaluated = result.get("evaluated", {})
        if path.name == DRIVING_POLICY_EVAL:
            if evaluated.get("kind") != "checkpoint" or evaluated.get("sha256") != digest:
                raise ReadmeError(f"{path} evaluates another policy: its sha256 is {evaluated.get('sha256')}, "
                                  f"{folder / POLICY}'s is {digest}; re-run its command (README) to evaluate this one")
            policy = (path, result)
        elif evaluated.get("kind") == "checkpoint":
            raise ReadmeError(f"{path}: a reference must be a scripted or random driver, not a policy file "
                              f"(this policy's evaluation is {DRIVING_POLICY_EVAL})")
        else:
            references.append((path, result))
    if policy is None:
        raise ReadmeError(f"no {DRIVING_POLICY_EVAL} in {folder / EVAL_DIR}: run the dynenv-eval commands first")
    same = ("episodes", "seeds", "n_cars", "perception", "env_config")
    for path, result in references:
        differ = [key for key in same if result["settings"].get(key) != policy[1]["settings"].get(key)]
        if differ:
            raise ReadmeError(f"{path} drove other episodes than {DRIVING_POLICY_EVAL}: its {', '.join(differ)} "
                              f"differ")
    return policy, references


def driving_eval_command(path: str, result: Mapping[str, Any]) -> str:
    """The ``dynenv-eval --scenario driving`` command that writes ``result`` to ``path`` (from its own settings)."""
    settings = result["settings"]
    words = [".venv/bin/dynenv-eval", "--scenario", "driving", result["evaluated"].get("path") or
             result["evaluated"]["spec"], "--episodes", str(settings["episodes"]), "--seeds",
             *map(str, settings["seeds"]), "--cars", str(settings["n_cars"])]
    if result["evaluated"].get("kind") != "checkpoint":       # a checkpoint brings its own action mode
        words += ["--action-mode", settings["action_mode"]]
    return shlex.join([*words, *_perception_words(settings), *_closing_words(path, settings)])


def render_driving(root: Path = ROOT, folder: Path = DRIVING_FOLDER) -> str:
    """The README of a shipped driving policy, from its files (``ReadmeError`` when they disagree)."""
    from dynenv_ros.evaluation.driving import format_driving_table
    here = root / folder
    digest, onnx_digest, agent, meta, config = shipped_files(here)
    (policy_path, policy), references = load_driving_evaluations(here, digest)
    revision = meta["code_revision"]
    losses = {k: v for k, v in _losses(config).as_dict().items() if v}
    teacher = config.get("teacher")
    settings = policy["settings"]
    summary = policy["summary"]

    out = _opening("The shipped driving policy", digest, onnx_digest,
                   f"driving agent (feature size {agent['feature_size']}, {agent['action_mode']} actions)")
    out += [_recipe_head(config, losses)
            + (f", **plus imitation of {'the scripted driver' if teacher == 'scripted' else f'the scripted `{teacher}`'}"
               f", which reads the ground truth** (imitation "
               f"weight {_n(config['imitation_coef'])}): not the paper's pure-RL Pred, and not a policy that learned "
               f"to drive from reward alone" if teacher else
               ", **pure reinforcement learning** (no teacher, no imitation), as the paper's Pred") + ";",
            f"- {config['n_cars']} cars per world, every car learning, `{config['perception']}` perception, seed "
            f"{config['seed']};",
            _budget_line(meta, f"of wall time on `{config['device']}` (the sum over its training processes, resumes "
                               f"included)")]
    out += recipe_and_listing(root, here, config, revision, digest)
    home, crashed = summary["home_rate"]["mean"], summary["crash_rate"]["mean"]
    out.append(f"- Not a solved task: on the evaluation episodes below {home * 100:.0f} % of its cars get home and "
               f"{crashed * 100:.0f} % crash.")
    out.append(f"- Its figure below is an evaluation on unseen episodes, not the paper's statistic (the best 10-episode "
               f"moving average during training, a friendlier one): the paper's Pred reached "
               f"{PAPER_DRIVING_PRED} per car and episode that way.")
    out.append("")

    out += ["## How it drives (seeds of the train split, looked at for choices before the splits existed)", "",
            f"Each driver drives all {settings['n_cars']} cars of the same {len(policy['episodes'])} "
            f"episodes ({settings['episodes']} per seed, seeds {', '.join(map(str, settings['seeds']))}), "
            f"`{settings['perception']}` perception; reward per car and episode (driving's paper's metric is its "
            f"total: it has no observation reward), mean ± sd over the seeds (the unit).", "",
            "| driver | actions | reward per car and episode | share of cars home | share of cars crashed |",
            "|---|---|---:|---:|---:|"]
    for _path, result in [(policy_path, policy), *references]:
        s = result["summary"]
        spec = result["evaluated"]["spec"]
        name = ("this policy" if result is policy else f"`{spec}`" + (" (reads the ground truth)"
                                                                       if spec == "scripted" else ""))
        acting = ("greedy" if result["settings"].get("greedy") else "sampled") if result is policy else "—"
        bold = "**" if result is policy else ""
        out.append(f"| {name} | {acting} | {bold}{_mean_sd(s['total'])}{bold} | {_mean_sd(s['home_rate'])} | "
                   f"{_mean_sd(s['crash_rate'])} |")
    out += ["", "### Reproduce", "",
            "Each file in `eval/` is the output of one command (run from the repository root; same code, same "
            "file), and this README is regenerated from them:", "", "```bash"]
    out += [driving_eval_command(str(folder / EVAL_DIR / path.name), result)
            for path, result in [(policy_path, policy), *references]]
    out += [".venv/bin/python tools/pretrained_readme.py", "```", "",
            f"`git log -- {folder / EVAL_DIR}` gives the commit each file was made at.", "", "### Per seed", ""]
    for _, result in [(policy_path, policy), *references]:
        out += [format_driving_table(result), ""]

    out += ledger_lines(root, digest, driving=True)
    out += ["## Play it", "",
            '`make run ARGS="--set scenario=driving"`: a policy node drives `car_0` with `policy.onnx` '
            "(onnxruntime), a `scripted_driver` node the other cars (`--set car_0=scripted` for scripted drivers "
            "only" + ("; the main job refuses this discrete policy with `--set action_mode=continuous`)."
                      if agent["action_mode"] == "discrete" else ")."), ""]
    return "\n".join(out)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the README is not what the files give")
    args = parser.parse_args(argv)
    stale = 0
    for folder in FOLDERS:
        target = ROOT / folder / "README.md"
        try:
            text = render(ROOT, folder)
        except (ReadmeError, OSError) as error:
            print(f"pretrained_readme: {folder}: {error}", file=sys.stderr)
            return 2
        if not args.check:
            target.write_text(text)
            print(f"wrote {target}")
        elif not target.is_file() or target.read_text() != text:
            print(f"{target} is not what the files give: run .venv/bin/python tools/pretrained_readme.py",
                  file=sys.stderr)
            stale = 1
        else:
            print(f"{target} is up to date")
    return stale


if __name__ == "__main__":
    sys.exit(main())
