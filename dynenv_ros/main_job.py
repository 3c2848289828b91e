"""The main job (`make run`): runs the project's node graph end to end and prints a summary.

Today the graph is the interface self-check (a talker publishes and serves every dynenv_msgs interface, a listener
verifies each field). Later graphs (simulator, policies, recorder, trainer) are further entries of GRAPHS.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import yaml

from dynenv_ros.graph.process_graph import GraphOutcome, NodeLaunch, run_graph
from dynenv_ros.ros.selfcheck import format_report

REPO_CONFIG = Path(__file__).resolve().parent.parent / "config" / "main_job.yaml"
INSTALLED_CONFIG = Path(sys.prefix) / "share" / "dynenv_ros" / "config" / "main_job.yaml"


def default_config_path() -> Path:
    """The repository's config in a source checkout; the installed share/ copy in a colcon install."""
    return REPO_CONFIG if REPO_CONFIG.exists() else INSTALLED_CONFIG


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range."""


@dataclass(frozen=True)
class MainJobConfig:
    graph: str = "selfcheck"
    seed: int = 0
    samples_per_type: int = 5
    timeout_s: float = 60.0
    domain_id: int = -1  # -1: pick one from the process id, so parallel runs do not meet

    @classmethod
    def from_mapping(cls, values: dict[str, Any]) -> "MainJobConfig":
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ConfigError(f"unknown key(s) {unknown}; known: {sorted(known)}")
        typed: dict[str, Any] = {}
        for key, value in values.items():
            expected = type(getattr(cls, key))
            if expected is float and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if type(value) is not expected:
                raise ConfigError(f"{key} must be {expected.__name__}, got {value!r}")
            typed[key] = value
        config = cls(**typed)
        config.validate()
        return config

    def validate(self) -> None:
        if self.graph not in GRAPHS:
            raise ConfigError(f"graph must be one of {sorted(GRAPHS)}, got {self.graph!r}")
        if not 1 <= self.samples_per_type <= 1000:
            raise ConfigError(f"samples_per_type must be in [1, 1000], got {self.samples_per_type}")
        if not 0 < self.timeout_s <= 86400:
            raise ConfigError(f"timeout_s must be in (0, 86400], got {self.timeout_s}")
        if not (self.domain_id == -1 or 0 <= self.domain_id <= 101):
            raise ConfigError(f"domain_id must be -1 (auto) or in [0, 101], got {self.domain_id}")
        if not 0 <= self.seed < 2**31:
            raise ConfigError(f"seed must be in [0, 2^31), got {self.seed}")


def load_config(path: Path, overrides: dict[str, Any]) -> MainJobConfig:
    if not path.is_file():
        raise ConfigError(f"config file {path} does not exist")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ConfigError(f"{path} is not valid YAML: {error}") from error
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{path} must hold a mapping of settings")
    section = raw.get("main_job", raw)
    if not isinstance(section, dict):
        raise ConfigError(f"{path}: 'main_job' must be a mapping")
    return MainJobConfig.from_mapping({**section, **overrides})


def selfcheck_graph(config: MainJobConfig, run_dir: Path) -> list[NodeLaunch]:
    shared = {"seed": config.seed, "samples_per_type": config.samples_per_type}
    return [
        NodeLaunch("selfcheck_talker", "dynenv_ros.nodes.selfcheck_talker", shared),
        NodeLaunch("selfcheck_listener", "dynenv_ros.nodes.selfcheck_listener",
                   {**shared, "timeout_s": config.timeout_s * 0.9, "report_path": str(run_dir / "selfcheck.json")},
                   ends_run=True),
    ]


def summarise_selfcheck(outcome: GraphOutcome, run_dir: Path) -> bool:
    report_path = run_dir / "selfcheck.json"
    if not report_path.exists():
        print(f"no self-check report was written; see the logs in {run_dir}")
        return False
    report = json.loads(report_path.read_text())
    print(format_report(report))
    return bool(report["ok"])


@dataclass(frozen=True)
class Graph:
    build: Callable[[MainJobConfig, Path], list[NodeLaunch]]
    summarise: Callable[[GraphOutcome, Path], bool]


GRAPHS: dict[str, Graph] = {"selfcheck": Graph(selfcheck_graph, summarise_selfcheck)}


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="dynenv-run", description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=None,
                        help=f"YAML settings (default: {REPO_CONFIG.relative_to(REPO_CONFIG.parents[1])})")
    parser.add_argument("--output-dir", type=Path, default=None, help="run directory (default: runs/<time>)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a setting, value in YAML syntax (repeatable)")
    return parser.parse_args(argv)


def parse_overrides(pairs: list[str]) -> dict[str, Any]:
    overrides = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE, got {pair!r}")
        overrides[key.strip()] = yaml.safe_load(value)
    return overrides


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        config = load_config(args.config or default_config_path(), parse_overrides(args.set))
    except ConfigError as error:
        print(f"dynenv-run: configuration error: {error}", file=sys.stderr)
        return 2
    run_dir = args.output_dir or Path("runs") / time.strftime("%Y%m%d-%H%M%S")
    domain_id = config.domain_id if config.domain_id >= 0 else 1 + os.getpid() % 100
    graph = GRAPHS[config.graph]
    print(f"dynenv-run: graph '{config.graph}' on ROS domain {domain_id}; logs in {run_dir}")
    outcome = run_graph(graph.build(config, run_dir), run_dir, domain_id, config.timeout_s)
    for node in outcome.nodes:
        state = "stopped" if node.stopped_by_graph else f"exit {node.exit_code}"
        print(f"  node {node.name:<24} {state:<10} log {node.log_path}")
    ok = graph.summarise(outcome, run_dir) and outcome.ok
    print(f"dynenv-run: {'OK' if ok else 'FAILED'} in {outcome.wall_time_s:.1f} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
