#!/usr/bin/env python3
"""policy_node/pretrained/README.md and policy_node/pretrained/driving/README.md from the files beside them, so that
what they say about the shipped policies can never drift from the policies.

Usage::

    .venv/bin/python tools/pretrained_readme.py           # write both READMEs
    .venv/bin/python tools/pretrained_readme.py --check   # exit 1 if a README is not what its files give

Every figure and name in the README comes from a file: the policy file's safetensors header (the agent's config,
the training metadata: variant, training config, env steps, the code revision it was trained at), the SHA-256 of
``policy.safetensors`` and ``policy.onnx``, ``train_config.json`` / ``train_summary.json`` (checked against the
header), the ``dynenv-eval`` results in ``eval/*.json`` (each must record the SHA-256 of this policy file: the
evaluation of another policy is refused), the training presets of config/train/ (which one the training config is,
and the ``--set`` overrides that make it), docs/results.md's table of runs (whether the policy is one of them), and
git (whether the code revision it was trained at includes the fixes listed in ``FIXES``). The commands that
reproduce each evaluation are built from the evaluation's own settings.

ROS-free; torch is imported only to read the safetensors header (``agent.checkpoint``).
"""
from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any, Mapping, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FOLDER = Path("policy_node") / "pretrained"
DRIVING_FOLDER = FOLDER / "driving"
FOLDERS = (FOLDER, DRIVING_FOLDER)
POLICY, ONNX = "policy.safetensors", "policy.onnx"
EVAL_DIR = "eval"
RESULTS_DOC = Path("docs") / "results.md"
PRESETS = Path("config") / "train"
OPPONENT_ORDER = ("random", "scripted", "perceiving")
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
def policy_header(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(agent config, training meta) from a policy file's safetensors header."""
    from dynenv_ros.agent.checkpoint import FORMAT, safetensors_header
    header, _ = safetensors_header(path.read_bytes())
    metadata = header.get("__metadata__") or {}
    if metadata.get("format") != FORMAT:
        raise ReadmeError(f"{path} is not a {FORMAT} policy file")
    return json.loads(metadata["config"]), json.loads(metadata.get("meta", "{}"))


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
    against another opponent), checked: the first stage's ``train`` arguments start a run (``--config``, ``--seed``,
    ``--set``), each later one resumes it (``--resume``, ``--set``), and applying them in order gives exactly the
    training config. None without the file."""
    from dynenv_ros.learning.config import load_config
    path = here / "train_stages.json"
    if not path.is_file():
        return None
    stages = json.loads(path.read_text())["stages"]
    cfg = None
    for k, stage in enumerate(stages):
        args = list(stage["train"])
        options = dict(zip(args[0::2], args[1::2]))
        overrides = [v for key, v in zip(args[0::2], args[1::2]) if key == "--set"]
        if k == 0:
            if "--config" not in options:
                raise ReadmeError(f"{path}: the first stage must start a run with --config")
            seed = [f"seed={options['--seed']}"] if "--seed" in options else []
            cfg = load_config(ROOT / PRESETS / f"{options['--config']}.yaml", [*overrides, *seed])
        else:
            if "--resume" not in options:
                raise ReadmeError(f"{path}: stage {k + 1} must resume the run (--resume)")
            cfg = load_config(None, overrides, base=cfg)
    if cfg is None or cfg.to_dict() != with_later_defaults(config):
        raise ReadmeError(f"{path}: its stages do not give the training config in {POLICY}'s header")
    return stages


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


def _opening(title: str, digest: str, onnx_digest: str, agent: str) -> list[str]:
    """A README's title, its do-not-edit line and the first lines of "What it is": the files and their sha256s."""
    return [f"# {title}", "",
            "<!-- Written by tools/pretrained_readme.py from the files of this folder; do not edit by hand. "
            "Regenerate: .venv/bin/python tools/pretrained_readme.py -->", "",
            "## What it is", "",
            f"`{POLICY}` (torch runtime; sha256 `{digest}`) and `{ONNX}` (onnxruntime; sha256 `{onnx_digest}`) hold "
            f"one trained {agent}. From the policy file's header (`train_config.json` and `train_summary.json` are "
            f"the same):", ""]


def _recipe_head(config: Mapping[str, Any], losses: Mapping[str, Any]) -> str:
    return (f"- **{config['algorithm'].upper()}, variant `{config['variant']}`** (its losses: "
            f"{', '.join(f'`{k}`' for k in losses) or 'none'})")


def _budget_line(meta: Mapping[str, Any], how: str) -> str:
    return (f"- **{_n(meta['env_steps'])} env steps** ({_n(meta['updates'])} updates, {_n(meta['episodes'])} "
            f"episodes) in {_n(meta['wall_seconds'] / 60)} minutes {how};")


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


def eval_command(path: str, result: Mapping[str, Any]) -> str:
    """The ``dynenv-eval`` command that writes ``result`` to ``path`` (from its own settings)."""
    settings = result["settings"]
    words = [".venv/bin/dynenv-eval", result["evaluated"]["path"], "--opponent", result["opponent"]["spec"],
             "--episodes", str(settings["episodes"]), "--seeds", *map(str, settings["seeds"]),
             "--players-per-team", str(settings["players_per_team"]), *_perception_words(settings),
             "--sides", settings["sides"]]
    return shlex.join([*words, *_closing_words(path, settings)])


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
    out = [f"- trained in {len(stages)} stages (`train_stages.json`, checked to give the training config; the "
           f"header records code revision `{revision}`, that of the last process that trained it):", ""]
    out += [f"  {k + 1}. {stage['why']}" for k, stage in enumerate(stages)]
    out += ["", "```bash", f"git checkout {stages[0].get('revision', revision)}"]
    for k, stage in enumerate(stages):
        if k and stage.get("revision"):         # a stage that needs code the header's revision lacks
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


def ledger_lines(root: Path, digest: str, driving: bool = False) -> list[str]:
    """The test ledger's rows in which this policy played (every one, in the order they were written)."""
    from dynenv_ros.evaluation.ledger import read_ledger, rows_of
    path = root / LEDGER
    rows = rows_of(read_ledger(path), digest) if path.exists() else []
    out = ["## The test ledger", "",
           "Every evaluation of this policy on the test split (seeds 20,000–29,999), as dynenv-eval's `--split test` "
           "appended it to `docs/results_data/test_ledger.jsonl`; the earlier tables are on seeds that choices "
           "were made on.", ""]
    if not rows:
        return out + ["No test-split evaluation of this policy yet.", ""]
    if driving:
        out += ["| date | commit | games | reward per car and episode | share of cars home | share crashed |",
                "|---|---|---:|---:|---:|---:|"]
        for row in rows:
            s = row["summary"]
            out.append(f"| {row['date'][:10]} | `{str(row['commit'])[:7]}` | {row['games']} | {s['total']:.2f} | "
                       f"{s['home_rate']:.2f} | {s['crash_rate']:.2f} |")
        return out + [""]
    out += ["| date | commit | opponent | games | W/D/L | goals for : against | goal difference a game (95 % interval) "
            "| beats it |", "|---|---|---|---:|---:|---:|---:|---|"]
    for row in rows:
        h = row["head_to_head"]
        opponent = (row.get("opponent") or {}).get("spec", "")
        interval = "" if h["interval"] is None else f" ({h['interval'][0]:+.2f} to {h['interval'][1]:+.2f})"
        out.append(f"| {row['date'][:10]} | `{str(row['commit'])[:7]}` | `{opponent}` | {h['games']} | "
                   f"{h['wins']}/{h['draws']}/{h['losses']} | {h['goals_for']} : {h['goals_against']} | "
                   f"{h['goal_difference_per_game']:+.3f}{interval} | {'yes' if h['beats'] else 'no'} |")
    return out + [""]


def render(root: Path = ROOT, folder: Path = FOLDER) -> str:
    """The README of ``root/folder``'s policy, from its files (``ReadmeError`` when they disagree): the soccer
    README or, for a driving agent, ``render_driving``'s."""
    if policy_header(root / folder / POLICY)[0].get("scenario", "robocup") == "driving":
        return render_driving(root, folder)
    from dynenv_ros.evaluation.soccer import format_table
    here = root / folder
    digest, onnx_digest, agent, meta, config = shipped_files(here)
    evaluations = load_evaluations(here, digest)
    stages = training_stages(here, config)
    revision = meta["code_revision"]
    losses = {k: v for k, v in _losses(config).as_dict().items() if v}
    teacher = config.get("teacher")
    self_play = config.get("opponent") == "self"

    out = _opening("The shipped policy", digest, onnx_digest,
                   f"agent (feature size {agent['feature_size']}, {agent['head_mode']} head)")
    out += [_recipe_head(config, losses)
            + (f", **plus imitation of the scripted `{teacher}`** (imitation weight {_n(config['imitation_coef'])}: "
               f"the {teacher} labels the states the learner reaches; not in the paper, docs/training.md)"
               if teacher else ", pure reinforcement learning (no teacher)") + ";",
            f"- {'in stages (below)' if stages else 'self-play' if self_play else 'against ' + str(config.get('opponent'))}, "
            f"{config['players_per_team']} per team, `{config['perception']}` perception, seed {config['seed']};",
            _budget_line(meta, f"on `{config['device']}` with {config['torch_threads']} torch "
                               f"thread{'s' if config['torch_threads'] != 1 else ''}")]
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

    out += ["## How it plays (seeds 100–104: train split, looked at for choices before the splits existed)", "",
            "The paper's metric (positive reward minus observation reward, per robot and episode) is the headline, "
            "the total reward beside it; mean ± sd over the evaluation seeds (the unit), goals and W/D/L summed over "
            "every game. Against `random`, the last column is the ratio of the policy's paper's metric to the "
            "random team's in the same episodes.", "",
            "| opponent | games (episodes × seeds) | W/D/L | goals for : against | paper's metric | total reward | "
            "opponent's paper's metric | × random's paper's metric |",
            "|---|---|---|---|---:|---:|---:|---:|"]
    for _path, result in evaluations:
        s, counts, settings = result["summary"], result["counts"], result["settings"]
        goals_for, goals_against = _totals(result)
        ratio = (f"{s['paper_metric']['mean'] / s['opponent_paper_metric']['mean']:.2f}x"
                 if result["opponent"]["spec"] == "random" else "")
        out.append(f"| `{result['opponent']['spec']}` | {counts['episodes']} ({settings['episodes']} × "
                   f"{len(settings['seeds'])}) | {counts['wins']}/{counts['draws']}/{counts['losses']} | "
                   f"{goals_for} : {goals_against} | **{_mean_sd(s['paper_metric'])}** | {_mean_sd(s['total'])} | "
                   f"{_mean_sd(s['opponent_paper_metric'])} | {ratio} |")
    out += ["", "Settings of each evaluation: " + "; ".join(
        f"`{path.name}`: seeds {', '.join(map(str, r['settings']['seeds']))}, {r['settings']['players_per_team']} "
        f"per team, `{r['settings']['perception']}` perception, sides `{r['settings']['sides']}`, "
        f"{'greedy' if r['settings']['greedy'] else 'sampled'} actions" for path, r in evaluations) + ".", ""]

    out += ["### Reproduce", "",
            "Each file in `eval/` is the output of one command (run from the repository root; same code, same "
            "file), and this README is regenerated from them:", "", "```bash"]
    out += [eval_command(str(folder / EVAL_DIR / path.name), result) for path, result in evaluations]
    out += [".venv/bin/python tools/pretrained_readme.py", "```", "",
            "`git log -- policy_node/pretrained/eval` gives the commit each file was made at.", "",
            "### Per seed", ""]
    for _path, result in evaluations:
        out += [format_table(result), ""]

    out += ledger_lines(root, digest)
    greedy = bool(evaluations) and all(r["settings"]["greedy"] for _, r in evaluations)
    out += ["## Play it", "",
            "`make run` (team A, through the policy node and onnxruntime, against the scripted team B), or "
            "`ros2 run dynenv_ros policy_node --ros-args -p checkpoint:=policy_node/pretrained/policy.onnx "
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
