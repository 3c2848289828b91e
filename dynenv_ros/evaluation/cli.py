"""dynenv-eval: evaluate a soccer team policy or a driving policy over seeds, and compare two evaluations with BEST.

    dynenv-eval CHECKPOINT --opponent scripted --episodes 10 --seeds 0 1 2 3 4 --out agent.json
    dynenv-eval random --opponent scripted --episodes 10 --seeds 0 1 2 3 4 --out random.json
    dynenv-eval compare random.json agent.json --metric paper_metric --png best.png

    dynenv-eval --scenario driving CHECKPOINT --episodes 4 --seeds 0 1 2 --out pred.json
    dynenv-eval --scenario driving random --episodes 4 --seeds 0 1 2 --out random.json
    dynenv-eval --scenario driving scripted --episodes 4 --seeds 0 1 2 --out scripted.json
    dynenv-eval compare random.json pred.json --metric total
    dynenv-eval merge pred_s0.json pred_s1.json pred_s2.json --out pred.json   # the runs as BEST's units
    dynenv-eval training-best runs/driving/pred_s0     # the paper's statistic: best moving average in training
    dynenv-eval ratio pred_s0.json pred_s1.json --reference random.json --bar 2.3   # the paper's ratio, interval
    dynenv-eval mean pred_s0.json pred_s1.json --metric total --bar 26.47   # a group's mean, interval

Seed splits (evaluation/splits.py): --split train | validation | test picks a named, disjoint seed range; choices
are made on validation, and every --split test evaluation is appended to the test ledger
(docs/results_data/test_ledger.jsonl). Seeds of the test range are refused without --split test. A soccer result
carries its head-to-head: W/D/L, goals and a 95 % bootstrap interval (seeds as units) of the per-game goal
difference; "beats" means the interval lies above 0.

Driving: the policy ("random", "scripted" or a driving checkpoint) drives every car (--cars) of the same seeded
episodes; there is no opponent (--opponent is refused): "against random / scripted" is the comparison of the
evaluations of the same episodes (evaluation/driving.py).

The evaluated team and the opponent are each a checkpoint path, "random", "scripted" (= keeper_and_chasers),
"chaser", "eager_chaser", "keeper_and_chasers" (these read the ground truth), "perceiving" (keeper_and_chasers on
each robot's own detections and self-pose estimate) or "perceiving_chasers" (the same, chasers in every slot). The
evaluated team plays team A in the even episodes of each seed and team B in the odd ones (--sides). Seeds are the statistical unit: the per-seed means go into the JSON and
the table, and "compare" runs BEST on them (the second file is the proposal: P(improvement) = P(mean of B > mean of A)).
Bad arguments exit with code 2 and a one-line reason.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any, Callable, Mapping, NoReturn, Sequence

PROG = "dynenv-eval"
PERCEPTIONS = ("realistic", "dynenv", "none")


class _Parser(argparse.ArgumentParser):
    """Errors as one line on stderr and exit code 2 (no usage block)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _eval_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policy", help="checkpoint path, or random / scripted / chaser / eager_chaser / "
                                       "keeper_and_chasers / perceiving / perceiving_chasers (driving: random / scripted / "
                                       "a driving checkpoint)")
    parser.add_argument("--scenario", choices=("robocup", "driving"), default="robocup",
                        help="robocup (default) or driving (the policy drives every car; no opponent)")
    parser.add_argument("--opponent", default=None,
                        help="checkpoint path, or random / scripted / chaser / eager_chaser / keeper_and_chasers "
                             "/ perceiving / perceiving_chasers (default scripted; robocup only)")
    parser.add_argument("--cars", type=int, help="driving: cars per world (default 2)")
    parser.add_argument("--action-mode", choices=("discrete", "continuous"),
                        help="driving: the env's action mode for random / scripted (a checkpoint brings its own)")
    parser.add_argument("--episodes", type=int, default=4, help="episodes per seed (default 4)")
    parser.add_argument("--seeds", type=seed_items, nargs="+", help="seeds, each N or an inclusive range A-B "
                        "(default 0 1 2, or the split's first --num-seeds); each the statistical unit")
    parser.add_argument("--split", choices=("train", "validation", "test"),
                        help="evaluate on this named seed range (train 0-9999, validation 10000-19999, test "
                             "20000-29999); --split test appends a row to the test ledger")
    parser.add_argument("--num-seeds", type=int, help="with --split and no --seeds: its first N seeds (default 25)")
    parser.add_argument("--ledger", type=Path, help="--split test: the ledger to append to (default "
                        "docs/results_data/test_ledger.jsonl of this checkout)")
    parser.add_argument("--players-per-team", type=int, help="robocup: robots per team (default 2)")
    parser.add_argument("--perception", choices=PERCEPTIONS, default="realistic")
    parser.add_argument("--noise-magnitude", type=float, help="perception noise 0..5 (default: the preset's)")
    parser.add_argument("--episode-seconds", type=float, help="episode length (default: the env's 120 s)")
    parser.add_argument("--sides", choices=("alternate", "a", "b"),
                        help="robocup: the evaluated team's side (default: alternate, A in even episodes)")
    parser.add_argument("--greedy", action="store_true", help="checkpoints take their most likely action")
    parser.add_argument("--out", type=Path, help="write the full result (JSON) here")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch threads while a checkpoint plays (default 1: a team's batch is tiny)")
    parser.add_argument("--games-at-once", type=int, default=1,
                        help="robocup: games played side by side, a checkpoint's robots of all of them in one "
                             "forward (default 1; 20 at once took 2.5x less CPU time; the same games, up to the "
                             "float rounding of a larger batch)")
    parser.add_argument("--quiet", action="store_true", help="no per-episode progress on stderr")
    return parser


def _compare_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"{PROG} compare", description="BEST (Kruschke 2013) on the per-seed values of a "
                     "metric in two dynenv-eval results; B is the proposal, A the baseline.")
    parser.add_argument("a", type=Path, help="baseline result JSON")
    parser.add_argument("b", type=Path, help="proposal result JSON")
    parser.add_argument("--metric", default="total", help="per-seed metric (default total; e.g. paper_metric, "
                        "goal_difference, win_rate)")
    parser.add_argument("--png", type=Path, help="write the posterior plot here")
    parser.add_argument("--out", type=Path, help="write the posterior summary (JSON) here")
    parser.add_argument("--draws", type=int, default=1000)
    parser.add_argument("--tune", type=int, default=1000)
    parser.add_argument("--chains", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="sampler seed")
    return parser


def _merge_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"{PROG} merge", description="One result whose per-seed rows are training runs: each "
                     "input's mean over its seeds (BEST with the run as the unit, when every run was evaluated on "
                     "several seeds).")
    parser.add_argument("results", type=Path, nargs="+", help="dynenv-eval result JSONs, one per training run")
    parser.add_argument("--out", type=Path, required=True, help="write the merged result (JSON) here")
    return parser


def _ratio_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"{PROG} ratio", description="A group's metric over a reference's (the random team's) "
                     "on the same seeds, as a ratio of means with a bootstrap interval over runs and seeds.")
    parser.add_argument("results", type=Path, nargs="+", help="dynenv-eval result JSONs, one per training run")
    parser.add_argument("--reference", type=Path, required=True, help="the reference's result on the same seeds")
    parser.add_argument("--metric", default="paper_metric", help="per-seed metric (default paper_metric)")
    parser.add_argument("--bar", type=float, help="say whether the interval lies above this ratio")
    parser.add_argument("--out", type=Path, help="write the ratio (JSON) here")
    return parser


def _mean_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"{PROG} mean", description="A group's mean of a per-seed metric over its runs and their "
                     "common seeds, with a bootstrap interval over runs and seeds (the paper's absolute figures, "
                     "e.g. driving's reward per car and episode).")
    parser.add_argument("results", type=Path, nargs="+", help="dynenv-eval result JSONs, one per training run")
    parser.add_argument("--metric", default="total", help="per-seed metric (default total)")
    parser.add_argument("--bar", type=float, help="say whether the interval lies above, below or around this figure")
    parser.add_argument("--out", type=Path, help="write the mean (JSON) here")
    return parser


def _write_summary(out: Path | None, summary: dict[str, Any]) -> int:
    """Write a group summary (ratio, mean) to ``--out`` when given; the exit status."""
    from dynenv_ros.evaluation.results import write_json
    if out is None:
        return 0
    try:
        write_json(summary, out)
    except (ValueError, OSError) as error:
        return _fail(f"--out {out}: cannot write: {error}")
    print(f"wrote {out}")
    return 0


def run_mean(args: argparse.Namespace) -> int:
    from dynenv_ros.evaluation.ratios import format_mean, group_mean
    from dynenv_ros.evaluation.results import load_evaluation
    try:
        _check_folder(args.out, "--out")
        result = group_mean([load_evaluation(p) for p in args.results], args.metric,
                            names=[str(p) for p in args.results])
    except (ValueError, OSError) as error:
        return _fail(str(error))
    print(format_mean(result, args.bar))
    return _write_summary(args.out, {"format": "dynenv_group_mean/1", "results": [str(p) for p in args.results],
                                     **result})


def run_ratio(args: argparse.Namespace) -> int:
    from dynenv_ros.evaluation.ratios import format_ratio, ratio_of_means
    from dynenv_ros.evaluation.results import load_evaluation
    try:
        _check_folder(args.out, "--out")
        group = [load_evaluation(p) for p in args.results]
        result = ratio_of_means(group, load_evaluation(args.reference), args.metric,
                                names=[str(p) for p in args.results])
    except (ValueError, OSError) as error:
        return _fail(str(error))
    print(format_ratio(result, args.bar))
    return _write_summary(args.out, {"format": "dynenv_ratio/1", "results": [str(p) for p in args.results],
                                     "reference": str(args.reference), **result})


def _training_best_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"{PROG} training-best", description="The paper's driving statistic from a run's "
                     "training log: the best moving average of an episode metric during training, over consecutive "
                     "logging windows (evaluation/training_statistic.py). It flatters; quote it beside a held-out "
                     "evaluation, never instead.")
    parser.add_argument("runs", type=Path, nargs="+", help="run folders (or their metrics.csv)")
    parser.add_argument("--metric", default="episode/return", help="logged episode metric (default episode/return)")
    parser.add_argument("--window", type=int, default=10, help="logging windows per average (default 10)")
    return parser


def run_training_best(args: argparse.Namespace) -> int:
    import statistics
    from dynenv_ros.evaluation.training_statistic import training_statistic
    try:
        found = [training_statistic(path, args.metric, args.window) for path in args.runs]
    except (ValueError, OSError) as error:
        return _fail(str(error))
    for result in found:
        print(f"{result['path']}: best {result['window']}-window moving average of {result['metric']} "
              f"{result['best']:.4g} (at {result['at_env_steps']:,} env steps; {result['windows']} windows)")
    if len(found) > 1:
        values = [r["best"] for r in found]
        print(f"mean over {len(found)} runs: {statistics.mean(values):.4g} ± {statistics.stdev(values):.2g} (sd)")
    return 0


def run_merge(args: argparse.Namespace) -> int:
    from dynenv_ros.evaluation.results import load_evaluation, merge_runs, write_json
    try:
        _check_folder(args.out, "--out")
        results = [load_evaluation(path) for path in args.results]
        merged = merge_runs(results, [str(path) for path in args.results])
        write_json(merged, args.out)
    except (ValueError, OSError) as error:
        return _fail(str(error))
    for row in merged["per_seed"]:
        print(f"unit {row['seed']}: {row['unit']} ({row['episodes']} episodes), total {row['total']:.4g}")
    print(f"wrote {args.out}")
    return 0


def _fail(message: str) -> int:
    print(f"{PROG}: {message}".splitlines()[0], file=sys.stderr)
    return 2


def _check_folder(path: Path | None, flag: str) -> None:
    """``path`` (an output file) can be written: its folder exists and takes a probe file (a read-only or full file
    system is refused here, before any evaluation runs)."""
    if path is not None:
        from dynenv_ros.core.writable import check_writable_file
        check_writable_file(path, flag)


def _evaluate_and_report(out: Path | None, evaluate: Callable[[], Mapping[str, Any]],
                         table: Callable[[Mapping[str, Any]], str], ledger: Path | None = None) -> int:
    """Run ``evaluate`` (after checking ``--out``'s folder and the ledger, so a long run cannot end unwritable),
    print its ``table``, append the test ledger's row (``ledger``: a test-split evaluation) and write the result
    to ``out``; shared by the soccer and driving evaluations. Exit status."""
    from dynenv_ros.evaluation.head_to_head import format_head_to_head, head_to_head
    from dynenv_ros.evaluation.ledger import append_row, ledger_row
    from dynenv_ros.evaluation.results import write_json
    try:
        _check_folder(out, "--out")
        _check_folder(ledger, "--ledger")
        result = dict(evaluate())
    except (ValueError, OSError) as error:     # a missing or corrupt checkpoint, a bad setting
        return _fail(str(error))
    head = None
    if "opponent" in result:                   # soccer: the head-to-head as a claim can be made from it
        head = result["head_to_head"] = head_to_head(result)
    print(table(result))
    if head is not None:
        print(format_head_to_head(head))
    if ledger is not None:
        try:
            append_row(ledger, ledger_row(result, out, head))
        except (ValueError, OSError) as error:
            return _fail(f"--ledger {ledger}: cannot append: {error}")
        print(f"appended the test ledger {ledger}")
    if out is not None:
        try:
            write_json(result, out)
        except (ValueError, OSError) as error:   # the disk filled or went read-only while it ran
            return _fail(f"--out {out}: cannot write: {error}")
        print(f"wrote {out}")
    return 0


def run_driving_eval(args: argparse.Namespace, perception, progress) -> int:
    from dynenv_ros.evaluation.driving import evaluate_driving, format_driving_table
    if args.opponent is not None:
        return _fail("--opponent: driving has no opponent; the policy drives every car. Evaluate random and "
                     "scripted the same way and compare the files")
    for flag, value in (("--players-per-team", args.players_per_team), ("--sides", args.sides)):
        if value is not None:
            return _fail(f"{flag} applies to --scenario robocup only (driving: --cars)")
    if args.games_at_once != 1:
        return _fail("--games-at-once applies to --scenario robocup only (driving plays its episodes one by one)")
    cars = 2 if args.cars is None else args.cars
    if not 1 <= cars <= 10:
        return _fail(f"--cars must be in 1..10, got {cars}")
    env_config = {} if args.episode_seconds is None else {"episode_seconds": args.episode_seconds}
    return _evaluate_and_report(args.out, lambda: evaluate_driving(
        args.policy, episodes=args.episodes, seeds=args.seeds, n_cars=cars, perception=perception,
        action_mode=args.action_mode, greedy=args.greedy, env_config=env_config, progress=progress,
        torch_threads=args.torch_threads), format_driving_table, _ledger(args)[0])


def seed_items(text: str) -> list[int]:
    """One ``--seeds`` item: a seed ``N`` or an inclusive range ``A-B`` (``10100-10124``: 25 seeds), so that a
    block of a split is written as it is meant, not as 25 numbers."""
    if text.startswith("-"):
        raise argparse.ArgumentTypeError(f"seeds are non-negative, got {text}")
    first, dash, last = text.partition("-")
    try:
        if not dash:
            return [int(text)]
        low, high = int(first), int(last)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a seed nor a range A-B of seeds") from None
    if high < low:
        raise argparse.ArgumentTypeError(f"range {text!r} ends before it starts")
    return list(range(low, high + 1))


def _resolve_seeds(args: argparse.Namespace) -> str | None:
    """``args.seeds`` from ``--split`` / ``--num-seeds`` / ``--seeds``; None, or the reason they are refused. Seeds
    of the test split are evaluated only under ``--split test``, which the ledger records."""
    from dynenv_ros.evaluation.splits import SPLITS, check_in_split, split_seeds
    if args.seeds is not None:          # items of seed_items: one list each
        args.seeds = [seed for item in args.seeds for seed in item]
        repeated = sorted(seed for seed, n in Counter(args.seeds).items() if n > 1)
        if repeated:
            return f"--seeds names a seed twice: {repeated}"
    if args.num_seeds is not None and (args.split is None or args.seeds is not None):
        return "--num-seeds takes the first seeds of --split; give it with --split and without --seeds"
    try:
        if args.split is not None:
            if args.seeds is None:
                args.seeds = split_seeds(args.split, 25 if args.num_seeds is None else args.num_seeds)
            else:
                check_in_split(args.split, args.seeds)
    except ValueError as error:
        return str(error)
    if args.seeds is None:
        args.seeds = [0, 1, 2]
    test = SPLITS["test"]
    if args.split != "test" and any(s in test for s in args.seeds):
        return (f"seeds {test.start}-{test.stop - 1} are the test split: evaluate them with --split test, which "
                f"appends the evaluation to the test ledger")
    if args.ledger is not None and args.split != "test":
        return "--ledger applies to --split test only"
    return None


def _ledger(args: argparse.Namespace) -> tuple[Path | None, str | None]:
    """The ledger a test-split evaluation appends to, or the reason there is none."""
    if args.split != "test":
        return None, None
    from dynenv_ros.evaluation.ledger import default_ledger
    ledger = args.ledger or default_ledger()
    if ledger is None:
        return None, ("--split test: this installation has no docs/results_data/ to hold the test ledger; give "
                      "--ledger PATH")
    return ledger, None


def run_eval(args: argparse.Namespace) -> int:
    refused = _resolve_seeds(args)
    if refused is not None:
        return _fail(refused)
    ledger, refused = _ledger(args)
    if refused is not None:
        return _fail(refused)
    if args.episodes < 1:
        return _fail(f"--episodes must be at least 1, got {args.episodes}")
    if args.torch_threads < 1:
        return _fail(f"--torch-threads must be at least 1, got {args.torch_threads}")
    if args.games_at_once < 1:
        return _fail(f"--games-at-once must be at least 1, got {args.games_at_once}")
    perception = args.perception if args.noise_magnitude is None else {
        "preset": args.perception, "noise_magnitude": args.noise_magnitude}
    progress = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    return _EVALUATIONS[args.scenario](args, perception, progress, ledger)


def run_soccer_eval(args: argparse.Namespace, perception: Any, progress: Any, ledger: Any) -> int:
    from dynenv_ros.evaluation.soccer import evaluate, format_table
    for flag, value in (("--action-mode", args.action_mode), ("--cars", args.cars)):
        if value is not None:
            return _fail(f"{flag} applies to --scenario driving only")
    env_config = {} if args.episode_seconds is None else {"episode_seconds": args.episode_seconds}
    return _evaluate_and_report(args.out, lambda: evaluate(
        args.policy, args.opponent or "scripted", episodes=args.episodes, seeds=args.seeds,
        players_per_team=2 if args.players_per_team is None else args.players_per_team, perception=perception,
        sides=args.sides or "alternate", greedy=args.greedy, env_config=env_config, progress=progress,
        torch_threads=args.torch_threads, games_at_once=args.games_at_once), format_table, ledger)


# Each scenario's games, by the spelling --scenario takes (docs/decisions.md, "A scenario registry").
_EVALUATIONS: dict[str, Callable[[argparse.Namespace, Any, Any, Any], int]] = {
    "robocup": run_soccer_eval,
    "driving": lambda args, perception, progress, ledger: run_driving_eval(args, perception, progress)}


def run_compare(args: argparse.Namespace) -> int:
    from dynenv_ros.evaluation.best import compare_evaluations, format_result
    try:
        _check_folder(args.png, "--png")
        _check_folder(args.out, "--out")
        result = compare_evaluations(args.a, args.b, args.metric, png=args.png, draws=args.draws, tune=args.tune,
                                     chains=args.chains, random_seed=args.seed)
    except (ValueError, OSError) as error:
        return _fail(str(error))
    print(format_result(result, labels=(args.a.stem, args.b.stem), metric=args.metric))
    if args.png is not None:
        print(f"wrote {args.png}")
    if args.out is not None:
        summary = {"a": str(args.a), "b": str(args.b), "metric": args.metric, **result.as_dict()}
        try:
            args.out.write_text(json.dumps(summary, indent=1) + "\n")
        except OSError as error:
            return _fail(f"--out {args.out}: cannot write: {error}")
        print(f"wrote {args.out}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "compare":
        return run_compare(_compare_parser().parse_args(argv[1:]))
    if argv and argv[0] == "merge":
        return run_merge(_merge_parser().parse_args(argv[1:]))
    if argv and argv[0] == "ratio":
        return run_ratio(_ratio_parser().parse_args(argv[1:]))
    if argv and argv[0] == "mean":
        return run_mean(_mean_parser().parse_args(argv[1:]))
    if argv and argv[0] == "training-best":
        return run_training_best(_training_best_parser().parse_args(argv[1:]))
    return run_eval(_eval_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
