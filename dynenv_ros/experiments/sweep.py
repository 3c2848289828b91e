"""dynenv-sweep: a grid of training runs (variants x seeds) as Ray tasks — on an embedded local Ray or a cluster —
each run evaluated when it ends, the evaluations merged into one result per variant with the run as BEST's unit.

    dynenv-sweep --config async --variants baseline pred --seeds 0 1 2 3 4 --set max_minutes=30 --out runs/sweep_pred
    dynenv-sweep --config async --variants pred --seeds 0 1 --ray-address 10.0.0.5:6379 --out runs/sweep_cluster
    dynenv-sweep --config driving_quick --variants pred --seeds 0 1 2 --reference random --best --out runs/sweep_drive

Each run is one task with ``--cpus-per-run`` CPUs (default: the async runner's workers plus one for its learner,
else one): it trains ``--config`` with ``variant`` and ``seed`` set (and every ``--set``) in a scratch folder of the
node it lands on, evaluates its policy there (soccer: ``--eval-episodes`` episodes per seed against ``--opponent`` on the
evaluation seeds, sides alternating; driving: the policy drives every car; actions sampled, or the most likely ones
with ``--greedy``), and sends back its small files: config,
summary, metrics, the policy and the evaluation. They are written to ``OUT/<variant>_s<seed>/``, so a sweep over a
cluster leaves everything on the machine that started it, and a sweep run again skips the runs already there.

After the grid: ``OUT/<variant>.json`` merges each variant's evaluations (``dynenv-eval merge``: one row per run),
``--reference TEAM`` evaluates a scripted or random team on the same seeds (``OUT/<team>.json``), ``--best`` runs
BEST between every variant and the reference (or the first variant), and ``OUT/table.md`` holds the table, headlined by
the paper's metric (soccer; driving: the reward per car and episode). A run that fails is reported with its reason
and the others go on; the exit status is 1 if any failed, 2 for bad arguments (checked before Ray starts).

``--scratch DIR`` trains each run in ``DIR/<variant>_s<seed>/`` instead of a temporary folder, and keeps it: a sweep
killed mid-run (a machine reboot, a session's end) run again resumes each unfinished run from its last checkpoint
(``dynenv-train --resume``) rather than starting it over. Local sweeps only: on a cluster the folder would be on
whichever node the task lands.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, NoReturn, Sequence

PROG = "dynenv-sweep"
RUN_FILES = ("config.json", "summary.json", "metrics.csv", "policy.safetensors")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROG, description=__doc__.split("\n\n")[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True, help="training preset (config/train/) or YAML, as dynenv-train")
    parser.add_argument("--variants", nargs="+", required=True, help="paper rows to train (baseline icm rcm pred "
                        "recon)")
    parser.add_argument("--seeds", type=int, nargs="+", required=True, help="training seeds (one run per seed)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a training setting of every run (repeatable)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the runs, merged results and table")
    parser.add_argument("--scratch", type=Path, help="train each run in SCRATCH/<variant>_s<seed> and keep it, so a "
                        "sweep run again resumes unfinished runs from their checkpoints (local sweeps only)")
    parser.add_argument("--ray-address", help="HOST:PORT of a Ray cluster's head (default: an embedded local Ray)")
    parser.add_argument("--ray-timeout", type=float, default=10.0, help="seconds to wait for --ray-address")
    parser.add_argument("--cpus-per-run", type=int, help="CPUs each run reserves (default: the async runner's "
                        "workers + 1, else 1)")
    parser.add_argument("--opponent", default="random", help="soccer: the team each policy is evaluated against "
                        "(random, scripted, chaser, ...; default random)")
    parser.add_argument("--eval-episodes", type=int, default=10, help="evaluation episodes per seed (default 10)")
    parser.add_argument("--eval-seeds", type=int, nargs="+", default=[0], help="evaluation seeds of every run "
                        "(default 0: every run plays the same episodes)")
    parser.add_argument("--greedy", action="store_true", help="evaluate each run's policy on its most likely "
                        "actions (dynenv-eval --greedy) instead of sampling them, as it was trained")
    parser.add_argument("--reference", help="also evaluate this team (soccer: random, scripted, ...; driving: "
                        "random or scripted) on the same seeds")
    parser.add_argument("--best", action="store_true", help="BEST between each variant and the reference (or the "
                        "first variant), runs as units (PyMC; about a minute each)")
    return parser


def _configs(args: argparse.Namespace) -> dict[str, Any]:
    """Every run's TrainConfig, checked before anything starts (ValueError naming the first bad setting)."""
    from dynenv_ros.learning.config import load_config
    from dynenv_ros.learning.train_cli import preset_path
    if len(set(args.seeds)) != len(args.seeds) or any(s < 0 for s in args.seeds):
        raise ValueError(f"--seeds must be distinct non-negative integers, got {args.seeds}")
    if len(set(args.variants)) != len(args.variants):
        raise ValueError(f"--variants must be distinct, got {args.variants}")
    if args.eval_episodes < 1:
        raise ValueError(f"--eval-episodes must be at least 1, got {args.eval_episodes}")
    path = preset_path(args.config)
    configs = {}
    for variant in args.variants:
        for seed in args.seeds:
            cfg = load_config(path, [*args.overrides, f"variant={variant}", f"seed={seed}"])
            configs[f"{variant}_s{seed}"] = cfg
    return configs


def cpus_for(cfg: Any, cpus_per_run: int | None) -> tuple[int, Any]:
    """(CPUs a run reserves, its config adjusted to them): an async run gets ``workers`` = CPUs − 1 unless set; a
    sync run on one CPU steps its worlds in-process."""
    if cfg.runner == "async":
        if cfg.backend == "ray":
            raise ValueError("a sweep's runs are Ray tasks already: use backend auto for their workers")
        workers = cfg.workers if cfg.workers is not None else max(1, (cpus_per_run or 2) - 1)
        cpus = cpus_per_run or workers + 1
        if cpus < workers + 1:
            raise ValueError(f"--cpus-per-run {cpus}: an async run with {workers} workers needs {workers + 1}")
        return cpus, cfg.replace(workers=min(workers, cfg.num_envs))
    cpus = cpus_per_run or 1
    return cpus, (cfg.replace(backend="inprocess") if cpus == 1 else cfg)


def train_and_evaluate(cfg_dict: dict[str, Any], name: str, evaluation: dict[str, Any],
                       scratch: str | None = None) -> dict[str, Any]:
    """One run, where the task landed: train in a scratch folder (``scratch``/name, kept and resumed from its last
    checkpoint, or a temporary one), evaluate the policy, return the small files."""
    from dynenv_ros.learning.run.checkpoints import list_checkpoints
    from dynenv_ros.learning.config import TrainConfig
    from dynenv_ros.learning.trainer import Trainer
    cfg = TrainConfig.from_dict(cfg_dict)
    started = time.time()
    with tempfile.TemporaryDirectory(prefix=f"dynenv-sweep-{name}-") as temporary:
        run_dir = Path(scratch or temporary) / name
        resume = run_dir.is_dir() and bool(list_checkpoints(run_dir))
        if run_dir.is_dir() and not resume:          # killed before its first checkpoint: nothing to keep
            shutil.rmtree(run_dir)
        summary = Trainer(cfg, run_dir, resume=resume, progress=False).run()
        result = _evaluate(cfg, run_dir / "policy.safetensors", evaluation)
        files = {f: (run_dir / f).read_bytes() for f in RUN_FILES if (run_dir / f).is_file()}
    import platform

    import ray
    node = ray.get_runtime_context().get_node_id() if ray.is_initialized() else None
    return {"name": name, "summary": summary, "evaluation": result, "files": files, "host": platform.node(),
            "node": node, "seconds": time.time() - started}


def _evaluate(cfg: Any, policy: str | Path, evaluation: dict[str, Any]) -> dict[str, Any]:
    """``policy`` evaluated in the scenario of the run ``cfg`` (each scenario's games: ``_EVALUATIONS``)."""
    return _EVALUATIONS[cfg.world.name](cfg, policy, evaluation)


def _evaluate_driving(cfg: Any, policy: str | Path, evaluation: dict[str, Any]) -> dict[str, Any]:
    from dynenv_ros.evaluation.driving import evaluate_driving
    seeds, greedy = evaluation["seeds"], bool(evaluation.get("greedy", False))    # (greedy: policy files only)
    reference = str(policy) in ("random", "scripted")
    return evaluate_driving(str(policy), episodes=evaluation["episodes"], seeds=seeds, n_cars=cfg.n_cars,
                            perception=cfg.perception, action_mode=cfg.action_mode if reference else None,
                            greedy=greedy and not reference)


def _evaluate_soccer(cfg: Any, policy: str | Path, evaluation: dict[str, Any]) -> dict[str, Any]:
    from dynenv_ros.evaluation.soccer import evaluate
    seeds, greedy = evaluation["seeds"], bool(evaluation.get("greedy", False))
    return evaluate(str(policy), evaluation["opponent"], episodes=evaluation["episodes"], seeds=seeds,
                    players_per_team=cfg.players_per_team, perception=cfg.perception, sides="alternate",
                    greedy=greedy)


# Each scenario's evaluation, by its name (docs/decisions.md, "A scenario registry": pieces above the registry).
_EVALUATIONS = {"soccer": _evaluate_soccer, "driving": _evaluate_driving}


def run_evaluation(args: argparse.Namespace) -> dict[str, Any]:
    """How this sweep evaluates each run (``_evaluate``'s settings)."""
    return {"episodes": args.eval_episodes, "opponent": args.opponent, "seeds": args.eval_seeds,
            "greedy": args.greedy}


def _check_done_runs(args: argparse.Namespace, planned: dict[str, Any]) -> None:
    """The runs already in ``--out`` (skipped, then merged) must have been evaluated as this sweep evaluates."""
    from dynenv_ros.evaluation.results import load_evaluation
    for name in planned:
        path = args.out / name / "eval.json"
        if path.is_file():
            differ = evaluated_otherwise(load_evaluation(path), run_evaluation(args))
            if differ:
                raise ValueError(f"{path} was evaluated with other settings ({differ}): a sweep's runs must be "
                                 f"evaluated alike; use another --out")


def evaluated_otherwise(result: dict[str, Any], evaluation: dict[str, Any]) -> str:
    """How an evaluation already in the sweep's folder differs from the one this sweep makes ('' when alike)."""
    settings = {"greedy": False, **result.get("settings", {})}
    differ = [f"{key} {settings.get(key)!r}, not {evaluation[key]!r}" for key in ("episodes", "seeds", "greedy")
              if settings.get(key) != evaluation[key]]
    opponent = (result.get("opponent") or {}).get("spec")
    from dynenv_ros.scenarios import get_scenario
    if get_scenario(result.get("scenario", "robocup")).sides > 1 and opponent != evaluation["opponent"]:
        differ.append(f"opponent {opponent!r}, not {evaluation['opponent']!r}")
    return "; ".join(differ)


def _write_run(out: Path, done: dict[str, Any]) -> None:
    from dynenv_ros.evaluation.results import write_json
    folder = out / done["name"]
    folder.mkdir(parents=True, exist_ok=True)
    for filename, data in done["files"].items():
        (folder / filename).write_bytes(data)
    write_json(done["evaluation"], folder / "eval.json")
    (folder / "sweep.json").write_text(json.dumps({"host": done["host"], "node": done["node"],
                                                   "seconds": round(done["seconds"], 1)}, indent=1) + "\n")


def metric_of(result: dict[str, Any]) -> str:
    from dynenv_ros.scenarios import get_scenario
    return get_scenario(result.get("scenario", "robocup")).headline_metric


def _table(rows: list[tuple[str, dict[str, Any]]]) -> str:
    """Markdown: a row per group — runs, the headline metric's mean ± sd over runs, and the total beside it."""
    lines = []
    for name, result in rows:
        metric = metric_of(result)
        stats, total = result["summary"][metric], result["summary"]["total"]
        line = f"| {name} | {len(result['per_seed'])} | {stats['mean']:.3f} ± {stats['sd']:.3f} | " \
               f"{total['mean']:.3f} ± {total['sd']:.3f} |"
        lines.append(line)
    header = f"| group | runs | {metric_of(rows[0][1])} (mean ± sd over runs) | total reward |\n|---|---:|---:|---:|"
    return header + "\n" + "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from dynenv_ros.learning.config import ConfigError
    try:
        configs = _configs(args)
        planned = {name: cpus_for(cfg, args.cpus_per_run) for name, cfg in configs.items()}
        args.out.mkdir(parents=True, exist_ok=True)
        if args.scratch and args.ray_address:
            raise ValueError("--scratch is for local sweeps: on a cluster each run lands on another node's disk")
        if args.scratch:
            args.scratch.mkdir(parents=True, exist_ok=True)
        _check_done_runs(args, planned)
    except (ConfigError, ValueError, OSError) as error:
        print(f"{PROG}: {error}".splitlines()[0], file=sys.stderr)
        return 2
    from dynenv_ros.learning.distributed.ray_connection import RayConnectionError, connect
    try:
        ray, started = connect(args.ray_address, args.ray_timeout)
    except RayConnectionError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return 2
    try:
        return _sweep(ray, args, configs, planned)
    finally:
        if started:
            ray.shutdown()


def _sweep(ray: Any, args: argparse.Namespace, configs: dict[str, Any], planned: dict[str, Any]) -> int:
    from dynenv_ros.evaluation.results import load_evaluation, merge_runs, write_json
    from dynenv_ros.learning.distributed.ray_connection import cluster_cpus
    cpus = cluster_cpus(ray)
    largest = max(c for c, _ in planned.values())
    if largest > cpus:
        print(f"{PROG}: a run needs {largest} CPUs, the Ray cluster has {cpus}", file=sys.stderr)
        return 2
    task = ray.remote(max_retries=2)(train_and_evaluate)
    pending, failed = {}, []
    evaluation = run_evaluation(args)
    for name, (run_cpus, cfg) in planned.items():
        if (args.out / name / "eval.json").is_file():
            print(f"{name}: already in {args.out / name}, skipped")
            continue
        scratch = str(args.scratch.resolve()) if args.scratch else None
        pending[task.options(num_cpus=run_cpus).remote(cfg.to_dict(), name, evaluation, scratch)] = name
    print(f"{len(pending)} runs on {cpus} CPUs ({'cluster ' + args.ray_address if args.ray_address else 'local'})",
          flush=True)
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        name = pending.pop(ready[0])
        try:
            done = ray.get(ready[0])
        except Exception as error:          # the run's own error, or its node lost beyond the retries
            cause = getattr(error, "cause", None) or error
            reason = " ".join(str(cause).split())[:300] or type(cause).__name__
            print(f"{name}: FAILED: {type(cause).__name__}: {reason}", flush=True)
            failed.append(name)
            continue
        _write_run(args.out, done)
        s = done["summary"]
        print(f"{name}: {s['env_steps']} env steps in {s['wall_seconds']:.0f} s on {done['host']} -> "
              f"{args.out / name}", flush=True)
    groups: list[tuple[str, dict[str, Any]]] = []
    for variant in args.variants:
        names = [f"{variant}_s{seed}" for seed in args.seeds if (args.out / f"{variant}_s{seed}" / "eval.json").is_file()]
        if not names:
            continue
        merged = merge_runs([load_evaluation(args.out / n / "eval.json") for n in names], names)
        write_json(merged, args.out / f"{variant}.json")
        groups.append((variant, merged))
    if args.reference and groups:
        reference = _reference(ray, args, configs)
        write_json(reference, args.out / f"{args.reference}.json")
        groups.insert(0, (args.reference, reference))
    if groups:
        table = _table(groups)
        if args.best and len(groups) > 1:
            table += _best_lines(args, groups)
        (args.out / "table.md").write_text(table)
        print(table)
    return 1 if failed else 0


def _reference(ray: Any, args: argparse.Namespace, configs: dict[str, Any]) -> dict[str, Any]:
    """The reference team evaluated like the runs, on one evaluation seed per training seed (its seeds are its
    units, as the runs are theirs)."""
    cfg = next(iter(configs.values()))
    return _evaluate(cfg, args.reference, {"episodes": args.eval_episodes, "opponent": args.opponent,
                                           "seeds": list(args.seeds)})


def _best_lines(args: argparse.Namespace, groups: list[tuple[str, dict[str, Any]]]) -> str:
    from dynenv_ros.evaluation.best import best, seed_values
    base_name, base = groups[0]
    metric = metric_of(base)
    lines = [f"\nBEST on {metric}, runs as units, against {base_name}:\n"]
    for name, result in groups[1:]:
        outcome = best(seed_values(base, metric), seed_values(result, metric), draws=2000, tune=1000, chains=2,
                       random_seed=0)
        summary = outcome.as_dict()
        (args.out / f"best_{name}_vs_{base_name}.json").write_text(json.dumps(summary, indent=1) + "\n")
        lines.append(f"- {name}: P({name} > {base_name}) = {summary['p_improvement']:.3f}, difference of means "
                     f"{summary['difference_mean']:.3f}, 95 % HDI [{summary['difference_hdi'][0]:.3f}, "
                     f"{summary['difference_hdi'][1]:.3f}]\n")
    return "".join(lines)


if __name__ == "__main__":
    sys.exit(main())
