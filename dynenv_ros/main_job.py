"""The main job (`make run`): runs the project's node graph end to end and prints a summary.

Graphs: ``train`` — live training over ROS: simulator games, their policy nodes, the trainer node and a recorder
(``graph/train_graph.py``). ``soccer`` (default) — the simulator node in stepped mode, team A played by a trained policy file (one
policy node) or scripted, team B by one scripted policy node per robot (``policy: perceiving``: a
``perceiving_policy`` node per robot, on its detections and pose estimate), and the recorder, for ``duration_s`` of sim
time; it prints achieved rates, message counts and the score, leaves the bag and a GIF in the run directory, and
checks the bag holds every message the simulator published and every action it accepted. With
``scenario: driving`` the same graph plays urban driving instead: the simulator with ``n_cars`` cars, a policy node
driving ``car_0`` with the shipped driving policy (``car_0``: another file, or ``scripted``), one ``scripted_driver``
node driving the others, and the recorder; it prints cars home, crashes, pedestrians hit and the
reward per car. ``selfcheck`` — every dynenv_msgs interface across processes. ``--help`` lists the settings and the
graphs (and scenarios) that use them.
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
from dynenv_ros.graph.train_graph import STEPPED_GAME_DEADLINE, summarise_train, train_graph
from dynenv_ros.ros.selfcheck import format_report
from dynenv_ros.driving.config import car_names
from dynenv_ros.soccer.config import robot_names

REPO_CONFIG = Path(__file__).resolve().parent.parent / "config" / "main_job.yaml"
INSTALLED_SHARE = Path(sys.prefix) / "share" / "dynenv_ros"          # setup.py's data_files, in an install
INSTALLED_CONFIG = INSTALLED_SHARE / "config" / "main_job.yaml"


def default_config_path() -> Path:
    """The repository's config in a source checkout; the installed share/ copy in a colcon install."""
    return REPO_CONFIG if REPO_CONFIG.exists() else INSTALLED_CONFIG


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range."""


POLICIES = ("keeper_and_chasers", "chaser", "random", "perceiving")
# Scripted teams that play on their robots' detections and pose estimates (policy_node/perceiving_policy.py), not
# on /world_state: the simulator's self-localization must be on for them.
PERCEIVING = ("perceiving",)
SCENARIOS = ("robocup", "driving")        # each with its game (GAMES)
# The graph that plays one game of the chosen scenario (GAMES), named for the first one it played.
GAME_GRAPH = "soccer"
INTERFACES = ("dynenv", "ros_sports")
ACTION_MODES = ("discrete", "continuous")
PERCEPTION_PRESETS = ("realistic", "dynenv", "none")
SHIPPED_POLICY = "policy_node/pretrained/policy.onnx"     # relative to the repository (see policy_file)
SHIPPED_DRIVING_POLICY = "policy_node/pretrained/driving/policy.onnx"     # discrete actions
AUTO_DOMAIN, ISOLATED_DOMAIN = -1, -2      # domain_id: the user's ROS_DOMAIN_ID, else isolated; always isolated


def choose_domain(domain_id: int, environ: dict[str, str]) -> tuple[int, bool, str]:
    """(ROS domain of the graph, whether to isolate it — discovery on this host only —, why, for the summary). A
    user who set ROS_DOMAIN_ID wants their own tools to see the graph; parallel runs without one must not meet."""
    if domain_id >= 0:
        return domain_id, False, "domain_id"
    mine = environ.get("ROS_DOMAIN_ID", "").strip()
    if domain_id == AUTO_DOMAIN and mine:
        if not mine.isdigit() or not 0 <= int(mine) <= 101:
            raise ConfigError(f"ROS_DOMAIN_ID={mine!r} in your environment is not a domain id in [0, 101]")
        return int(mine), False, "your ROS_DOMAIN_ID"
    return 1 + os.getpid() % 100, True, "isolated: picked from the process id, discovery on this host only"


@dataclass(frozen=True)
class MainJobConfig:
    graph: str = GAME_GRAPH
    scenario: str = "robocup"        # soccer graph: robocup (soccer) or driving
    seed: int = 0
    samples_per_type: int = 5        # selfcheck graph
    duration_s: float = 60.0         # soccer graph: sim seconds
    players_per_team: int = 2
    perception: str = "realistic"
    localization: bool = True        # robocup: the simulator's emulated self-localization (pose estimates)
    policy: str = "keeper_and_chasers"
    team_a: str = SHIPPED_POLICY     # soccer: a policy file (.onnx/.safetensors) or 'scripted' (the policy above)
    greedy: bool = True              # soccer: team_a's policy takes its most likely action (as the shipped one was
                                     # chosen and evaluated, docs/results.md); false: sampled
    gif: bool = True
    timeout_s: float = 180.0
    domain_id: int = -1  # -1: the user's ROS_DOMAIN_ID if set, else an isolated one; -2: always isolated
    games: int = 2                   # train graph: simulator games feeding the trainer
    train_updates: int = 60          # train graph: the trainer's budget, in updates (the same on any machine)
    train_minutes: float = 20.0      # train graph: a wall-time cap (a run that reaches it fails)
    episode_seconds: float = 10.0    # train graph: sim seconds per episode
    n_cars: int = 2                  # driving: cars; car_0 by car_0's policy, the others by the scripted driver
    car_0: str = SHIPPED_DRIVING_POLICY   # driving: a policy file of the run's action_mode, or 'scripted'
    action_mode: str = "discrete"    # driving: discrete | continuous
    foxglove_port: int = -1          # soccer graph: the simulator's Foxglove live view port; -1 off, 0 any free port
    interfaces: str = "dynenv"       # robocup: how team A's policy meets the robots: dynenv (DetectionArray,
                                     # Action) or ros_sports (soccer_vision_3d, RCGCD, twist, kick, head; issue 41)

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
        if not (self.domain_id in (AUTO_DOMAIN, ISOLATED_DOMAIN) or 0 <= self.domain_id <= 101):
            raise ConfigError(f"domain_id must be -1 (yours, else isolated), -2 (isolated) or in [0, 101], got "
                              f"{self.domain_id}")
        if not 0 <= self.seed < 2**31:
            raise ConfigError(f"seed must be in [0, 2^31), got {self.seed}")
        if not 0.5 <= self.duration_s <= 3600:
            raise ConfigError(f"duration_s must be in [0.5, 3600], got {self.duration_s}")
        if not 1 <= self.players_per_team <= 5:
            raise ConfigError(f"players_per_team must be in [1, 5], got {self.players_per_team}")
        if self.perception not in PERCEPTION_PRESETS:
            raise ConfigError(f"perception must be one of {PERCEPTION_PRESETS}, got {self.perception!r}")
        if not 1 <= self.games <= 8:
            raise ConfigError(f"games must be in [1, 8], got {self.games}")
        if not 1 <= self.train_updates <= 1_000_000:
            raise ConfigError(f"train_updates must be in [1, 1000000], got {self.train_updates}")
        if not 0.2 <= self.train_minutes <= 1440:
            raise ConfigError(f"train_minutes must be in [0.2, 1440], got {self.train_minutes}")
        if not 1.0 <= self.episode_seconds <= 600:
            raise ConfigError(f"episode_seconds must be in [1, 600], got {self.episode_seconds}")
        if self.policy not in POLICIES:
            raise ConfigError(f"policy must be one of {POLICIES}, got {self.policy!r}")
        if self.scenario not in SCENARIOS:
            raise ConfigError(f"scenario must be one of {SCENARIOS}, got {self.scenario!r}")
        game = GAMES[self.scenario]      # a check of settings only one scenario's game uses is that game's alone
        if self.policy in PERCEIVING and not self.localization and game.uses("policy"):
            raise ConfigError(f"policy {self.policy} plays on the robots' pose estimates: it needs "
                              "localization=true (the simulator's self-localization)")
        if not 1 <= self.n_cars <= 10:
            raise ConfigError(f"n_cars must be in [1, 10], got {self.n_cars}")
        if self.action_mode not in ACTION_MODES:
            raise ConfigError(f"action_mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        for key in ("car_0", "team_a"):
            check_policy_setting(key, getattr(self, key))
        if not -1 <= self.foxglove_port <= 65535:
            raise ConfigError(f"foxglove_port must be -1 (off), 0 (any free port) or a port in [1, 65535], got "
                              f"{self.foxglove_port}")
        if self.interfaces not in INTERFACES:
            raise ConfigError(f"interfaces must be one of {INTERFACES}, got {self.interfaces!r}")
        if self.interfaces == "ros_sports" and self.team_a == "scripted" and game.uses("interfaces"):
            raise ConfigError("interfaces ros_sports runs team A's policy node through the ros-sports messages: "
                              "team_a must be a policy file, not 'scripted'")
        if self.car_0 == SHIPPED_DRIVING_POLICY and self.action_mode != "discrete" and game.uses("car_0"):
            raise ConfigError("car_0: the shipped driving policy takes discrete actions; with action_mode "
                              "continuous set car_0=scripted or a continuous policy file")


def check_policy_setting(key: str, value: str) -> None:
    """A setting naming who plays (team_a, car_0): 'scripted', or a policy file that exists."""
    if value == "scripted":
        return
    path = policy_file(value)
    if path.suffix not in (".onnx", ".safetensors"):
        raise ConfigError(f"{key} must be 'scripted' or a .onnx / .safetensors policy file, got {value!r}")
    if not path.is_file():
        raise ConfigError(f"{key}: policy file {path} does not exist")

# What each setting means (listed by --help) and which graphs use it: a --set of a key the chosen graph does not use
# is refused, because it would change nothing (the config file may hold every key).
SETTINGS_HELP: dict[str, tuple[str, tuple[str, ...]]] = {
    "graph": ("soccer | train | selfcheck: what to run", ("soccer", "train", "selfcheck")),
    "scenario": ("robocup | driving: the world the soccer graph plays (driving: scripted drivers)", ("soccer",)),
    "seed": ("world seed (soccer, train) / sample seed (selfcheck), 0..2^31-1", ("soccer", "train", "selfcheck")),
    "timeout_s": ("wall-clock limit of the whole run, s (train: beyond train_minutes)",
                  ("soccer", "train", "selfcheck")),
    "domain_id": ("ROS_DOMAIN_ID of the graph, 0..101; -1: your ROS_DOMAIN_ID if set, else an isolated one (picked "
                  "from the process id, discovery on this host only); -2: isolated whatever ROS_DOMAIN_ID says",
                  ("soccer", "train", "selfcheck")),
    "duration_s": ("sim seconds to play, 0.5..3600", ("soccer",)),
    "players_per_team": ("robots per team, 1..5", ("soccer", "train")),
    "perception": ("perception preset: " + " | ".join(PERCEPTION_PRESETS), ("soccer", "train")),
    "games": ("simulator games (each with its policy node) feeding the trainer, 1..8", ("train",)),
    "train_updates": ("the trainer's budget in updates, 1..10^6: the run ends after this many, however long "
                      "they take (a busy machine is slower, not worse)", ("train",)),
    "train_minutes": ("a wall-time cap on the trainer, minutes, 0.2..1440: a run that reaches it before "
                      "train_updates stops and fails", ("train",)),
    "episode_seconds": ("sim seconds per training episode, 1..600", ("train",)),
    "policy": ("scripted team(s): " + " | ".join(POLICIES) + " (perceiving: keeper_and_chasers on each robot's own "
               "detections and pose estimate, never the ground truth)", ("soccer",)),
    "localization": ("the simulator's self-localization, robots' pose estimates (true | false; perceiving needs it)",
                     ("soccer",)),
    "team_a": ("a trained policy file for team A (.onnx: onnxruntime, .safetensors: torch) or 'scripted'",
               ("soccer",)),
    "greedy": ("team A's policy takes its most likely action (true, how the shipped policy was chosen and evaluated) "
               "or samples (false)", ("soccer",)),
    "gif": ("render the recorded bag as game.gif (true | false)", ("soccer",)),
    "samples_per_type": ("messages per type and calls per service that must arrive intact, 1..1000",
                         ("selfcheck",)),
    "n_cars": ("cars, 1..10 (scenario driving)", ("soccer",)),
    "car_0": ("a trained driving policy file for car_0 (.onnx: onnxruntime, .safetensors: torch; default the shipped "
              "one, discrete actions) or 'scripted' (scenario driving; the other cars: scripted drivers)",
              ("soccer",)),
    "action_mode": ("discrete | continuous: the cars' actions (scenario driving)", ("soccer",)),
    "interfaces": ("dynenv | ros_sports: how team A's policy node meets its robots — dynenv (DetectionArray in, "
                   "Action out) or ros_sports (the simulator publishes soccer_vision_3d_msgs, RCGCD15 and joint "
                   "states, the policy node answers with walk twists, kick requests and head commands, and a motion "
                   "emulator turns them into the robots' actions; docs/deploy.md)", ("soccer",)),
    "foxglove_port": ("live view in the Foxglove app: the simulator streams field, robots (cars), detections, TF and "
                      "score on ws://127.0.0.1:PORT; -1 off, 0 any free port (the simulator's log names it), "
                      "1..65535 that port", ("soccer",)),
}
# Settings of the soccer graph that only one scenario's game uses (``Game.settings``; a --set for another scenario
# is refused).
ROBOCUP_SETTINGS = ("players_per_team", "policy", "team_a", "localization", "greedy", "interfaces")
DRIVING_SETTINGS = ("n_cars", "action_mode", "car_0")


def check_overrides_apply(config: "MainJobConfig", overrides: dict[str, Any]) -> None:
    """Refuse a --set the chosen graph ignores (e.g. samples_per_type for the soccer graph), with the reason."""
    unused = sorted(k for k in overrides if config.graph not in SETTINGS_HELP.get(k, ("", config.graph))[1])
    if unused:
        used = sorted(k for k, (_, graphs) in SETTINGS_HELP.items() if config.graph in graphs)
        raise ConfigError(f"--set {', '.join(unused)}: not used by graph '{config.graph}' (it uses {used})")
    if config.graph == GAME_GRAPH:
        game = GAMES[config.scenario]
        other = sorted(k for k in overrides if k in SCENARIO_SETTINGS and not game.uses(k))
        if other:
            raise ConfigError(f"--set {', '.join(other)}: not used by scenario '{config.scenario}' (set "
                              f"scenario={SCENARIO_SETTINGS[other[0]]} for it)")


def settings_epilog() -> str:
    """The settings --set accepts, their defaults and the graphs that use them (dynenv-run --help)."""
    defaults = MainJobConfig()
    lines = ["settings (--set KEY=VALUE; the defaults shown are those of config/main_job.yaml):"]
    for name, (text, graphs) in SETTINGS_HELP.items():
        lines.append(f"  {name} (default {getattr(defaults, name)!r}; {', '.join(graphs)}): {text}")
    return "\n".join(lines)


SHIPPED_FOLDER = Path("policy_node") / "pretrained"
INSTALLED_SHIPPED = INSTALLED_SHARE / "pretrained"


def policy_file(value: str) -> Path:
    """A policy file named in the config (team_a, car_0): absolute, or relative to the repository (where the
    shipped ones lie); in a colcon / pip install without the repository, a shipped one is read from share/."""
    path = Path(value)
    if path.is_absolute():
        return path
    in_repo = Path(__file__).resolve().parent.parent / path
    if not in_repo.exists() and path.parts[:2] == SHIPPED_FOLDER.parts:
        installed = INSTALLED_SHIPPED.joinpath(*path.parts[2:])
        if installed.exists():
            return installed
    return in_repo


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
    config = MainJobConfig.from_mapping({**section, **overrides})
    check_overrides_apply(config, overrides)
    return config


def selfcheck_graph(config: MainJobConfig, run_dir: Path) -> list[NodeLaunch]:
    shared = {"seed": config.seed, "samples_per_type": config.samples_per_type}
    return [
        NodeLaunch("selfcheck_talker", "dynenv_ros.nodes.selfcheck_talker", shared),
        NodeLaunch("selfcheck_listener", "dynenv_ros.nodes.selfcheck_listener",
                   {**shared, "timeout_s": config.timeout_s * 0.9, "report_path": str(run_dir / "selfcheck.json")},
                   ends_run=True),
    ]


def read_report(path: Path, writer: str) -> dict[str, Any] | None:
    if not path.exists():
        print(f"the {writer} wrote no report; see the logs in {path.parent}")
        return None
    return json.loads(path.read_text())


def summarise_selfcheck(outcome: GraphOutcome, run_dir: Path, config: MainJobConfig) -> bool:
    report = read_report(run_dir / "selfcheck.json", "self-check listener")
    if report is None:
        return False
    print(format_report(report))
    return bool(report["ok"])


# Team A's policy node on the ros-sports route (docs/deploy.md, "The ros-sports route"): the simulator's period 0
# repeats one instant (no camera does), so its grid starts at the first frame after it, one vision period in, and
# the grid's periods are the simulator's; its own Action goes to <robot>/policy_action (the motion emulator acts).
# A frame's class messages come in one burst in a stepped game: class_wait only guards against a lost one.
ROS_SPORTS_POLICY = {"interfaces": "ros_sports", "frame_epoch": 0.1, "class_wait": 0.5}


def soccer_graph(config: MainJobConfig, run_dir: Path) -> list[NodeLaunch]:
    """The game graph of the chosen scenario (``GAMES``)."""
    return GAMES[config.scenario].build(config, run_dir)


def robocup_graph(config: MainJobConfig, run_dir: Path) -> list[NodeLaunch]:
    names = robot_names(config.players_per_team)
    learned = config.team_a != "scripted"
    perceiving = config.policy in PERCEIVING
    ros_sports = learned and config.interfaces == "ros_sports"
    # readers of /world_state: the recorder and the ground-truth scripted nodes (perceiving ones never read it)
    truth_readers = 1 + (0 if perceiving else len(names) - (config.players_per_team if learned else 0))
    sim = NodeLaunch("sim_node", "dynenv_ros.nodes.sim_node", {
        "players_per_team": config.players_per_team, "seed": config.seed, "perception_preset": config.perception,
        "localization": config.localization, "mode": "stepped", "episode_seconds": config.duration_s, "auto_reset": False, "exit_when_finished": True,
        "report_path": str(run_dir / "sim_report.json"), "wait_for_subscribers": 1 if ros_sports else 2,
        "wait_for_ground_truth_subscribers": truth_readers, "wait_for_recorder": True,
        "foxglove_port": config.foxglove_port, **({"ros_sports": True} if ros_sports else {})}, ends_run=True)
    policies = []
    if learned:       # one policy node drives all of team A (onnxruntime for .onnx files)
        path = policy_file(config.team_a)
        policies.append(NodeLaunch("policy_team_a", "policy_node.policy_node", {
            "players_per_team": config.players_per_team, "team": "a", "checkpoint": str(path),
            "runtime": "onnxruntime" if path.suffix == ".onnx" else "torch", "seed": config.seed,
            "greedy": config.greedy, "decision_deadline": STEPPED_GAME_DEADLINE,
            **(ROS_SPORTS_POLICY if ros_sports else {})},
            remaps={f"/{n}/action": f"/{n}/policy_action" for n in names[:config.players_per_team]}
            if ros_sports else {}))
    if ros_sports:    # the walk, kick and head engines of team A's robots over the simulator
        policies.append(NodeLaunch("motion_emulator", "dynenv_ros.nodes.motion_emulator", {
            "players_per_team": config.players_per_team, "team": "a"}))
    for i, name in enumerate(names):
        if learned and i < config.players_per_team:
            continue
        if perceiving:        # keeper_and_chasers on the robot's detections and pose estimate
            policies.append(NodeLaunch(f"policy_{name}", "policy_node.perceiving_policy",
                                       {"robot": name, "players_per_team": config.players_per_team}))
            continue
        slot = i % config.players_per_team
        kind = {"chaser": "chaser", "random": "random"}.get(
            config.policy, "keeper" if slot == 0 and config.players_per_team > 1 else "chaser")
        policies.append(NodeLaunch(f"policy_{name}", "policy_node.scripted_policy",
                                   {"robot": name, "policy": kind, "seed": config.seed + i}))
    # Stamped with sim time (as `ros2 bag record --use-sim-time`): the bag replays at game speed.
    recorder = NodeLaunch("recorder", "dynenv_ros.nodes.recorder", {"output": str(run_dir / "bag"),
                                                                     "use_sim_time": True})
    return [recorder, *policies, sim]


def driving_graph(config: MainJobConfig, run_dir: Path) -> list[NodeLaunch]:
    """The simulator (scenario driving, stepped), a policy node driving car_0 with ``car_0``'s policy (unless
    'scripted'), one scripted_driver node for the other cars, and the recorder."""
    sim = NodeLaunch("sim_node", "dynenv_ros.nodes.sim_node", {
        "scenario": "driving", "n_cars": config.n_cars, "action_mode": config.action_mode, "seed": config.seed,
        "perception_preset": config.perception, "mode": "stepped", "episode_seconds": config.duration_s,
        "auto_reset": False, "exit_when_finished": True, "report_path": str(run_dir / "sim_report.json"),
        "wait_for_subscribers": 2, "wait_for_ground_truth_subscribers": 2, "wait_for_recorder": True,
        "foxglove_port": config.foxglove_port}, ends_run=True)
    drivers = []
    scripted = car_names(config.n_cars)
    if config.car_0 != "scripted":
        path = policy_file(config.car_0)
        drivers.append(NodeLaunch("policy_car_0", "policy_node.policy_node", {
            "scenario": "driving", "n_cars": config.n_cars, "action_mode": config.action_mode, "cars": ["car_0"],
            "checkpoint": str(path), "runtime": "onnxruntime" if path.suffix == ".onnx" else "torch",
            "seed": config.seed, "decision_deadline": STEPPED_GAME_DEADLINE}))
        scripted = scripted[1:]
    if scripted:
        drivers.append(NodeLaunch("scripted_driver", "policy_node.scripted_driver",
                                  {"n_cars": config.n_cars, "action_mode": config.action_mode, "cars": scripted}))
    recorder = NodeLaunch("recorder", "dynenv_ros.nodes.recorder", {"output": str(run_dir / "bag"),
                                                                     "use_sim_time": True})
    return [recorder, *drivers, sim]


def missing_from_bag(report: dict[str, Any], info: dict[str, Any]) -> dict[str, tuple[int, int]]:
    """Topics whose recorded count differs from what the simulator says it published (or accepted, for actions):
    topic → (published, recorded)."""
    published = report["published"]
    expected = {"/world_state": published["world_state"], "/clock": published["world_state"]}
    for name in report["robots"]:
        expected[f"/{name}/detections"] = published["detections_per_robot"]
        expected[f"/{name}/feedback"] = published["feedback_per_robot"]
        if published.get("pose_estimates_per_robot"):           # the simulator's self-localization was on
            expected[f"/{name}/pose_estimate"] = published["pose_estimates_per_robot"]
    counts = {t["name"]: t["count"] for t in info["topics"]}
    return {t: (n, counts.get(t, 0)) for t, n in expected.items() if counts.get(t, 0) != n}


def actions_not_recorded(report: dict[str, Any], bag: Path) -> dict[str, tuple[int, int]]:
    """Action topics whose recorded actions for the periods that ran differ in number from what the simulator
    accepted: topic → (accepted, recorded). The answers to the last frames (a period that never ran) may or may
    not be recorded before the graph stops, so they are not counted."""
    from dynenv_ros.bags.inspect import BagError, echo
    periods = int(report["diagnostics"]["periods_run"])
    differences = {}
    for name, accepted in report.get("accepted_actions", {}).items():
        topic = f"/{name}/action"
        try:
            recorded = sum(1 for r in echo(bag, topic) if r["message"]["motion_period"] <= periods)
        except BagError:                       # the topic is not in the bag at all
            recorded = 0
        if recorded != accepted:
            differences[topic] = (accepted, recorded)
    return differences


def check_bag(report: dict[str, Any], run_dir: Path) -> tuple[bool, Path]:
    """Print the bag's size and whether it holds everything published and accepted; (complete, bag path)."""
    from dynenv_ros.bags.inspect import bag_info
    bag = run_dir / "bag"
    if not bag.exists():
        print(f"  no bag was recorded in {bag}")
        return False, bag
    info = bag_info(bag)
    lost = {**missing_from_bag(report, info), **actions_not_recorded(report, bag)}
    counts = {t["name"]: t["count"] for t in info["topics"]}
    total = sum(counts.values())
    print(f"  bag {bag}: {total} messages on {len(counts)} topics, {info['duration_s']:.1f} s; "
          + ("every published message recorded" if not lost else f"LOST (published or accepted, recorded): {lost}"))
    return not lost, bag


def summarise_driving(outcome: GraphOutcome, run_dir: Path, config: MainJobConfig) -> bool:
    from dynenv_ros.bags.inspect import render
    report = read_report(run_dir / "sim_report.json", "simulator")
    if report is None:
        return False
    diag = report["diagnostics"]
    rejected = sum(int(v) for k, v in diag.items() if k.startswith("rejected_"))
    episodes = report.get("episodes", [])
    who = ("scripted drivers" if config.car_0 == "scripted"
           else f"car_0 by {config.car_0}, {'the others by scripted drivers' if config.n_cars > 1 else 'alone'}")
    print(f"  driving: {config.n_cars} cars ({config.action_mode} actions), {who}, perception "
          f"'{config.perception}'")
    if episodes:
        last = episodes[-1]
        rewards = ", ".join(f"{name} {value:+.2f}" for name, value in last["reward_per_car"].items())
        print(f"  game: {last['sim_seconds']:.1f} s of sim time in {last['periods']} periods; cars home "
              f"{last['cars_home']}/{config.n_cars}, crashed {last['crashed']}, pedestrians hit "
              f"{last['pedestrians_hit']}; reward per car: {rewards}")
    else:
        print("  game: unfinished")
    print(f"  stepped-mode real-time factor {diag['real_time_factor_running']}x "
          f"({diag['real_time_factor_since_start']}x with start-up); actions accepted "
          f"{diag['accepted']}, missing {diag['missing']}, rejected {rejected}")
    complete, bag = check_bag(report, run_dir)
    ok = rejected == 0 and bool(episodes) and complete
    if config.gif and bag.exists():
        target = run_dir / "game.gif"
        frames = render(bag, target, robot="car_0", fps=10.0)
        print(f"  replay: {target} ({frames} frames, car_0's detections overlaid)")
    return ok


def summarise_soccer(outcome: GraphOutcome, run_dir: Path, config: MainJobConfig) -> bool:
    """The game graph's summary for the chosen scenario (``GAMES``)."""
    return GAMES[config.scenario].summarise(outcome, run_dir, config)


def summarise_robocup(outcome: GraphOutcome, run_dir: Path, config: MainJobConfig) -> bool:
    from dynenv_ros.bags.inspect import render
    report = read_report(run_dir / "sim_report.json", "simulator")
    if report is None:
        return False
    diag = report["diagnostics"]
    rejected = sum(int(v) for k, v in diag.items() if k.startswith("rejected_"))
    scores = report["episode_scores"]
    team_a = config.policy if config.team_a == "scripted" else \
        f"{config.team_a} (policy node, {'greedy' if config.greedy else 'sampled'} actions" + (
            ", through ros-sports messages and the motion emulator)" if config.interfaces == "ros_sports" else ")")
    played = "scripted, on its detections and pose estimates" if config.policy in PERCEIVING else "scripted"
    print(f"  teams: A {team_a}, B {config.policy} ({played})")
    print(f"  game: {diag['sim_time_s']} s of sim time in {diag['periods_run']} periods, "
          f"score A {scores[-1][0]} : {scores[-1][1]} B" if scores else "  game: unfinished")
    print(f"  stepped-mode real-time factor {diag['real_time_factor_running']}x "
          f"({diag['real_time_factor_since_start']}x with start-up); actions accepted "
          f"{diag['accepted']}, missing {diag['missing']}, rejected {rejected}")
    complete, bag = check_bag(report, run_dir)
    if not bag.exists():
        return False
    ok = rejected == 0 and bool(scores) and complete
    if config.gif:
        target = run_dir / "game.gif"
        frames = render(bag, target, robot="team_a_0", fps=10.0, pixels_per_metre=40.0)
        print(f"  replay: {target} ({frames} frames, robot team_a_0's detections overlaid)")
    return ok


@dataclass(frozen=True)
class Graph:
    build: Callable[[MainJobConfig, Path], list[NodeLaunch]]
    summarise: Callable[[GraphOutcome, Path, MainJobConfig], bool]


@dataclass(frozen=True)
class Game(Graph):
    """One scenario's game on the game graph: its nodes and summary, the settings only it uses, and whether the
    start-up line names the scenario (the graph's name says soccer already)."""
    settings: tuple[str, ...]
    announced: bool

    def uses(self, key: str) -> bool:
        """Whether ``key`` is one of the settings only this game uses (``SCENARIO_SETTINGS``)."""
        return key in self.settings


# The game graph's game of each scenario, by the spelling MainJobConfig.scenario takes: this launcher keeps the
# registry (which imports torch) out of its start-up (docs/decisions.md, "A scenario registry").
GAMES: dict[str, Game] = {"robocup": Game(robocup_graph, summarise_robocup, ROBOCUP_SETTINGS, announced=False),
                          "driving": Game(driving_graph, summarise_driving, DRIVING_SETTINGS, announced=True)}
# The scenario whose game uses each of those settings (for the error naming it).
SCENARIO_SETTINGS: dict[str, str] = {key: name for name, game in GAMES.items() for key in game.settings}

GRAPHS: dict[str, Graph] = {GAME_GRAPH: Graph(soccer_graph, summarise_soccer),
                            "train": Graph(train_graph, summarise_train),
                            "selfcheck": Graph(selfcheck_graph, summarise_selfcheck)}


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="dynenv-run", description=__doc__.splitlines()[0], epilog=settings_epilog(),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=None,
                        help=f"YAML settings (default: {REPO_CONFIG.relative_to(REPO_CONFIG.parents[1])})")
    parser.add_argument("--output-dir", type=Path, default=None, help="run directory (default: runs/<time>)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a setting, value in YAML syntax (repeatable); a key the chosen graph "
                             "does not use is refused")
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
    try:
        domain_id, isolate, why = choose_domain(config.domain_id, dict(os.environ))
    except ConfigError as error:
        print(f"dynenv-run: configuration error: {error}", file=sys.stderr)
        return 2
    graph = GRAPHS[config.graph]
    announced = config.graph == GAME_GRAPH and GAMES[config.scenario].announced
    played = f" (scenario '{config.scenario}')" if announced else ""
    print(f"dynenv-run: graph '{config.graph}'{played} on ROS domain {domain_id} ({why}); logs in {run_dir}")
    if config.graph == GAME_GRAPH and config.foxglove_port >= 0:
        where = (f"ws://127.0.0.1:{config.foxglove_port}" if config.foxglove_port else
                 f"the port the simulator's log ({run_dir}/sim_node.log) names")
        print(f"  live view: open {where} in the Foxglove app (Open connection → Foxglove WebSocket), layout "
              "config/foxglove/dynenv_layout.json")
    timeout_s = config.timeout_s + (60.0 * config.train_minutes if config.graph == "train" else 0.0)
    outcome = run_graph(graph.build(config, run_dir), run_dir, domain_id, timeout_s, isolate=isolate)
    for node in outcome.nodes:
        state = "stopped" if node.stopped_by_graph else f"exit {node.exit_code}"
        print(f"  node {node.name:<24} {state:<10} log {node.log_path}")
    ok = graph.summarise(outcome, run_dir, config) and outcome.ok
    print(f"dynenv-run: {'OK' if ok else 'FAILED'} in {outcome.wall_time_s:.1f} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
