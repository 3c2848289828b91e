"""dynenv-train: train the DynEnv agent in-process (no ROS) on the soccer world or (scenario=driving) the driving
world.

    dynenv-train --config paper_a2c --run-dir runs/pred_s0 --seed 0
    dynenv-train --config quick --set num_envs=2 --set variant=baseline
    dynenv-train --resume runs/pred_s0
    dynenv-train --config driving_pred --set max_minutes=15 --run-dir runs/driving/pred_s0
    dynenv-train --from-bag bags/sample_2v2_realistic_30s --run-dir runs/bc_sample --epochs 5
    dynenv-train --from-bag runs/drive_demo/bag --config driving_quick --run-dir runs/bc_driving --epochs 5

``--config`` takes a preset name from config/train/ or a YAML path; ``--set key=value`` overrides any field of
``TrainConfig`` (values in YAML syntax). Bad configs are refused with the key and the reason before any work.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

PRESET_DIRS = (Path(__file__).resolve().parents[2] / "config" / "train",)


def preset_path(name: str) -> Path:
    """A YAML path as given, or a preset name looked up in config/train/ (the source tree, then the install)."""
    path = Path(name)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise ValueError(f"config file {path} does not exist")
        return path
    dirs = list(PRESET_DIRS)
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory("dynenv_ros")) / "config" / "train")
    except Exception:       # not installed through colcon: the source tree's presets only
        pass
    for folder in dirs:
        candidate = folder / f"{name}.yaml"
        if candidate.is_file():
            return candidate
    known = sorted({p.stem for folder in dirs if folder.is_dir() for p in folder.glob("*.yaml")})
    raise ValueError(f"no config preset {name!r}; presets: {', '.join(known) or 'none found'}")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    from dynenv_ros.learning.config import TrainConfig, field_help
    defaults = TrainConfig()
    keys = "\n".join(f"  {key} (default {getattr(defaults, key)!r}): {text}" for key, text in field_help().items())
    parser = argparse.ArgumentParser(prog="dynenv-train", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=f"keys for --set (TrainConfig):\n{keys}")
    parser.add_argument("--config", default="paper_a2c", help="preset name in config/train/ or a YAML file")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one config field (repeatable)")
    parser.add_argument("--seed", type=int, help="shorthand for --set seed=N")
    parser.add_argument("--device", help="shorthand for --set device=D (cpu, cuda, cuda:1)")
    parser.add_argument("--run-dir", help="where the run writes (default runs/<algorithm>_<variant>_s<seed>)")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue the run in RUN_DIR from its last checkpoint")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar (logs still written)")
    parser.add_argument("--from-bag", nargs="+", metavar="BAG", help="learn offline from recorded bags: behaviour "
                        "cloning of the recorded actions and (soccer) the localization/reconstruction heads "
                        "(learning/messages/bags.py); rollout_length sets the sequence length; a driving bag needs a "
                        "driving config (--config driving_quick)")
    parser.add_argument("--epochs", type=int, default=10, help="--from-bag: passes over the sequences")
    parser.add_argument("--batch-sequences", type=int, default=16, help="--from-bag: sequences per update")
    parser.add_argument("--team", choices=("a", "b"), help="--from-bag (soccer): clone this team's robots only")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from dynenv_ros.learning.config import ConfigError, TrainConfig, load_config
    if args.from_bag:
        return _from_bags(args)
    try:
        if args.resume:
            run_dir = Path(args.resume)
            saved = run_dir / "config.json"
            if not saved.is_file():
                raise ValueError(f"--resume {run_dir}: no config.json there, not a run directory")
            cfg = TrainConfig.from_dict(json.loads(saved.read_text()))
            if args.overrides or args.seed is not None or args.device:
                cfg = load_config(None, _overrides(args), base=cfg)
        else:
            cfg = load_config(preset_path(args.config), _overrides(args))
            run_dir = Path(args.run_dir or f"runs/{cfg.algorithm}_{cfg.variant}_s{cfg.seed}")
            if (run_dir / "checkpoints").exists():
                raise ValueError(f"{run_dir} already holds a run; use --resume {run_dir} or another --run-dir")
        _check_device(cfg.device)
        from dynenv_ros.learning.resources import check_machine
        check_machine(cfg)                 # cores, memory, shared memory, the Ray cluster: before anything starts
        from dynenv_ros.core.writable import check_run_dir
        from dynenv_ros.learning.run.disk_budget import run_disk_bytes
        # read-only, full, or too small for the run's checkpoints: refused now, nothing left behind
        check_run_dir(run_dir, *run_disk_bytes(cfg), what="--resume" if args.resume else "--run-dir")
    except (ConfigError, ValueError) as error:
        print(f"dynenv-train: {error}", file=sys.stderr)
        return 2
    from dynenv_ros.learning.run.checkpoints import list_checkpoints
    resume = bool(args.resume)
    if resume and not list_checkpoints(run_dir):     # killed before its first checkpoint (seconds after starting)
        print(f"dynenv-train: --resume {run_dir}: no checkpoint yet (the run stopped before its first); starting "
              f"it again from the beginning", file=sys.stderr)
        resume = False
    from dynenv_ros.learning.trainer import Trainer
    from dynenv_ros.learning.distributed.worker_pool import WorkerPoolError
    try:
        trainer = Trainer(cfg, run_dir, resume=resume, progress=not args.no_progress)
    except (ValueError, WorkerPoolError) as error:   # a checkpoint that does not fit; workers that cannot start
        print(f"dynenv-train: {error}", file=sys.stderr)
        return 2
    except OSError as error:                         # the disk filled or went read-only since the probe
        from dynenv_ros.core.writable import describe_os_error
        print(f"dynenv-train: cannot write to {run_dir}: {describe_os_error(error)}", file=sys.stderr)
        return 2
    summary = trainer.run()
    print(f"dynenv-train: {summary['env_steps']} env steps, {summary['updates']} updates, "
          f"{summary['episodes']} episodes in {summary['wall_seconds']:.0f} s -> {run_dir}")
    if summary.get("stop_reason"):
        print(f"dynenv-train: stopped early: {summary['stop_reason']}", file=sys.stderr)
        return 1
    return 0


def _from_bags(args: argparse.Namespace) -> int:
    from dynenv_ros.bags.inspect import BagError
    from dynenv_ros.learning.config import ConfigError, load_config
    from dynenv_ros.learning.messages.bags import train_from_bags
    try:
        if args.resume:
            raise ValueError("--from-bag starts a new run; --resume continues an in-process one")
        for flag, value, high in (("--epochs", args.epochs, 10_000), ("--batch-sequences", args.batch_sequences,
                                                                      4096)):
            if not 1 <= value <= high:
                raise ValueError(f"{flag} must be in 1..{high}, got {value}")
        cfg = load_config(preset_path(args.config), _overrides(args))
        run_dir = Path(args.run_dir or f"runs/from_bag_s{cfg.seed}")
        if (run_dir / "checkpoints").exists():
            raise ValueError(f"{run_dir} already holds a run; choose another --run-dir")
        from dynenv_ros.core.writable import check_run_dir
        from dynenv_ros.learning.run.disk_budget import run_disk_bytes
        fresh = not run_dir.exists()
        check_run_dir(run_dir, *run_disk_bytes(cfg), what="--run-dir")
        learns = (lambda name: name[5] == args.team) if args.team else None
        try:
            summary = train_from_bags(cfg, args.from_bag, run_dir, epochs=args.epochs,
                                      batch_sequences=args.batch_sequences, learns=learns)
        except (ConfigError, ValueError, BagError):
            if fresh and run_dir.is_dir() and not any(run_dir.iterdir()):
                run_dir.rmdir()                        # refused before anything was written: leave no folder
            raise
    except (ConfigError, ValueError, BagError) as error:
        print(f"dynenv-train: {error}", file=sys.stderr)
        return 2
    first, last = summary["first_epoch"], summary["last_epoch"]
    from dynenv_ros.scenarios import get_scenario
    agents = get_scenario(summary["scenario"]).agent
    print(f"dynenv-train: {summary['sequences']} sequences ({summary['robot_periods']} {agents}-periods) from "
          f"{len(args.from_bag)} bag(s), {summary['epochs']} epochs, {summary['updates']} updates -> {run_dir}")
    for key in first:
        print(f"  {key}: {first[key]:.4f} (first epoch) -> {last[key]:.4f} (last)")
    return 0


def _overrides(args: argparse.Namespace) -> list[str]:
    extra = list(args.overrides)
    if args.seed is not None:
        extra.append(f"seed={args.seed}")
    if args.device:
        extra.append(f"device={args.device}")
    return extra


def _check_device(device: str) -> None:
    import torch
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} asked for, but torch sees no CUDA GPU here")
    torch.device(device)


if __name__ == "__main__":
    sys.exit(main())
