"""The simulator node's parameters (docs/ros_graph.md, "Parameters (sim_node)"): declared in one place, in the order
``--help`` lists them, checked, and turned into the scenario's config and perception parameters (``SimSettings``).

Both scenarios' parameters are declared (so ``--help`` and ``ros2 param`` list them all); one given for the other
scenario is refused (it would change nothing). Those that shape the world are read-only: set them at start (a YAML
preset, ``--ros-args -p``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.envs.session import MISSING_ACTION_RULES
from dynenv_ros.envs.sim_game import MODES_OF_RUNNING, SCENARIOS
from dynenv_ros.perception.params import MODES, PRESETS
from dynenv_ros.ros.authentication import secrets_for
from dynenv_ros.ros.frame_tags import frames_secret
from dynenv_ros.ros.parameters import (declare_bool, declare_float, declare_int, declare_str, declare_str_list,
                                       refuse_other_scenario)
from dynenv_ros.ros.runtime_controls import declare_runtime_controls
from dynenv_ros.security.action_auth import GameSecrets
from dynenv_ros.scenarios import Scenario, get_scenario

# Parameters only one scenario has: giving one to the other scenario is refused (it would change nothing).
SCENARIO_PARAMETERS = {"robocup": ("players_per_team", "falls_enabled", "localization", "ros_sports",
                                   "gc_team_number_a", "gc_team_number_b"),
                       "driving": ("n_cars", "action_mode", "teams")}
# Defaults that differ: rates (physics Hz, ticks per vision frame, ticks per motion period), episode seconds, the
# agent whose detections the markers show.
SCENARIO_DEFAULTS = {"robocup": dict(rates=(100.0, 10, 50), episode_seconds=120.0, marker_robot="team_a_0"),
                     "driving": dict(rates=(100.0, 10, 10), episode_seconds=60.0, marker_robot="car_0")}


@dataclass
class SimSettings:
    """Every parameter's value at start, and what follows from them."""
    scenario: str
    mode: str
    real_time_factor: float
    missing_action: str
    perception_preset: str
    config: Any                     # SoccerConfig or DrivingConfig
    perception: Any                 # the scenario's perception parameters
    names: list[str]                # robots (cars)
    controlled: list[int] | None    # robots a period waits for; None: all
    seed: int | None                # None: drawn
    localization: bool              # soccer's emulated self-localization
    ros_sports: bool
    gc_team_numbers: tuple[int, int]
    auto_reset: bool
    publish_markers: bool
    marker_robot: str
    diagnostics_period: float
    wait_for_subscribers: int
    wait_for_truth_readers: int
    wait_for_recorder: bool
    exit_when_finished: bool
    report_path: str
    foxglove_port: int
    foxglove_host: str
    secrets: GameSecrets | None
    runtime_controls: bool
    frames_secret: bytes | None

    @property
    def game(self) -> Scenario:
        """The scenario ``scenario`` names (its parameter spelling: robocup, driving)."""
        return get_scenario(self.scenario)


def declare_sim_parameters(node: Node) -> SimSettings:
    """Declare the simulator's parameters on ``node`` and check them: a bad value is a ParameterException naming
    it, with the reason."""
    fixed = dict(read_only=True)
    scenario = declare_str(node, "scenario", "robocup", "Which world: robocup (soccer) or driving (urban "
                           "driving); read-only.", choices=SCENARIOS, **fixed)
    game = get_scenario(scenario)
    own = set(SCENARIO_PARAMETERS[scenario])        # a parameter of the other scenario stays off here
    refuse_other_scenario(node, scenario, SCENARIO_PARAMETERS)
    defaults = SCENARIO_DEFAULTS[scenario]
    players = declare_int(node, "players_per_team", 2, 1, 5, "Robots per team (robocup only).", **fixed)
    n_cars = declare_int(node, "n_cars", 2, 1, 10, "Cars (driving only).", **fixed)
    action_mode = declare_str(node, "action_mode", "discrete", "Driving only: discrete (the original's 3x3 "
                              "commands) or continuous (throttle, brake, steering).",
                              choices=("discrete", "continuous"), **fixed)
    teams = declare_int(node, "teams", 1, 1, 2, "Driving only: 1 team (every car shares the bonus) or 2.", **fixed)
    mode = declare_str(node, "mode", "stepped", "stepped: a period runs when every controlled robot has "
                       "acted (or on /sim/step); realtime: paced by the wall clock.", choices=MODES_OF_RUNNING,
                       **fixed)
    real_time_factor = declare_float(node, "real_time_factor", 1.0, 0.01, 100.0,
                                     "Realtime mode: sim seconds per wall second.")
    missing_action = declare_str(node, "missing_action", "none", "A robot without an action for a "
                                 "period: 'hold' repeats its last action, 'none' stands still.",
                                 choices=MISSING_ACTION_RULES)
    preset = declare_str(node, "perception_preset", "realistic", "Perception parameter preset.",
                         choices=PRESETS, **fixed)
    noise_mode = declare_str(node, "noise_mode", "", "Error mode (realistic|random|none); empty: the preset's.",
                             choices=("",) + MODES, **fixed)
    magnitude = declare_float(node, "noise_magnitude", -1.0, -1.0, 5.0,
                              "Noise magnitude 0..5; -1: the preset's.", **fixed)
    # Defaults by scenario (robocup / driving): 100 Hz physics, a vision frame every 10 ticks, a motion period
    # of 50 / 10 ticks, episodes of 120 / 60 s.
    hz, vision_default, motion_default = defaults["rates"]
    physics_hz = declare_float(node, "physics_hz", hz, 10.0, 1000.0, "Physics ticks per second.", **fixed)
    vision_ticks = declare_int(node, "vision_period_ticks", vision_default, 1, 1000, "Ticks per vision frame.",
                               **fixed)
    motion_ticks = declare_int(node, "motion_period_ticks", motion_default, 1, 10000,
                               "Ticks per motion period (default robocup 50, driving 10).", **fixed)
    episode_s = declare_float(node, "episode_seconds", defaults["episode_seconds"], 0.5, 86400.0,
                              "Episode length, s (default robocup 120, driving 60).", **fixed)
    falls = declare_bool(node, "falls_enabled", True, "Random and contact falls (robocup only).", **fixed)
    seed = declare_int(node, "seed", -1, -1, 2**62, "World seed; -1 draws one.", **fixed)
    localization = declare_bool(node, "localization", True, "Robocup only: emulate every robot's "
                                "self-localization, publish <robot>/pose_estimate and TF map -> <robot>/odom -> "
                                "<robot>/base_link at the estimate (the truth on <robot>/ground_truth/base_link); "
                                "off: base_link is the truth.", **fixed)
    ros_sports = declare_bool(node, "ros_sports", False, "Robocup only: also publish, per robot, its "
                              "detections as soccer_vision_3d_msgs (<robot>/soccer_vision_3d/balls, robots, "
                              "goalposts, markings; frame <robot>/base_link) and the game as "
                              "game_controller_spl's RCGCD15 on <robot>/gc/data once per motion period "
                              "(docs/interfaces.md).", **fixed)
    gc_team_numbers = [declare_int(node, f"gc_team_number_{team}", default, 1, 254, "Robocup with ros_sports: "
                                   f"the SPL team number of team {team.upper()} in gc/data.", **fixed)
                       for team, default in (("a", 1), ("b", 2))]
    controlled = declare_str_list(node, "controlled_robots", [], "Robots whose actions a period waits for "
                                  "(names like team_a_0); empty: all.", **fixed)
    auto_reset = declare_bool(node, "auto_reset", True, "Start a new episode when one ends.")
    publish_markers = declare_bool(node, "publish_markers", True, "RViz/Foxglove markers.")
    marker_robot = declare_str(node, "marker_robot", defaults["marker_robot"],
                               "Robot (car) whose detections are drawn (default robocup team_a_0, driving car_0).")
    diag_s = declare_float(node, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.", **fixed)
    wait_for_subscribers = declare_int(
        node, "wait_for_subscribers", 1, 0, 100, "Stepped mode: hold the first observation until every robot's "
        "detections topic has this many subscribers (policies, recorder); with authenticated_frames its tag "
        "topic (detections_mac) too, so count only readers that verify tags (policy nodes, the trainer).", **fixed)
    wait_for_truth_readers = declare_int(
        node, "wait_for_ground_truth_subscribers", 0, 0, 100, "Stepped mode: also hold the first observation "
        "until /world_state has this many subscribers (scripted policies read it).", **fixed)
    wait_for_recorder = declare_bool(
        node, "wait_for_recorder", False, "Stepped mode: also hold the first observation until /clock and every "
        "feedback topic have a subscriber, and every action topic one besides this node (a dynenv recorder: "
        "that has matched every action publisher), so a recorder misses nothing.", **fixed)
    exit_when_finished = declare_bool(node, "exit_when_finished", False, "Exit (status 0) when an episode "
                                      "ends and auto_reset is off, after every subscriber has it.", **fixed)
    report_path = declare_str(node, "report_path", "", "Write a JSON summary here on exit.", **fixed)
    foxglove_port = declare_int(node, "foxglove_port", -1, -1, 65535, "Live view in the Foxglove app "
                                "(docs/ros_graph.md): the port of its WebSocket server; -1 off, 0 any free "
                                "port (logged).", **fixed)
    foxglove_host = declare_str(node, "foxglove_host", "127.0.0.1", "The interface the live view listens on "
                                "(127.0.0.1: this machine only; 0.0.0.0: every interface, unauthenticated).",
                                **fixed)
    rates = {"physics_hz": physics_hz, "vision_period_ticks": vision_ticks, "motion_period_ticks": motion_ticks}
    overrides: dict[str, Any] = {}
    if noise_mode:
        overrides["mode"] = noise_mode
    if magnitude >= 0:
        overrides["noise_magnitude"] = magnitude
    # the settings of this scenario's own parameters (SCENARIO_PARAMETERS), then those both have
    own_settings = {"robocup": {"players_per_team": players, "falls": {"enabled": falls}},
                    "driving": {"n_cars": n_cars, "action_mode": action_mode, "teams": teams}}[scenario]
    try:
        config: Any = game.settings({**own_settings, "episode_seconds": episode_s, "rates": rates})
        perception: Any = game.perception(preset, **overrides)
    except ValueError as error:
        raise ParameterException(str(error), [game.count_key]) from None
    names = game.agent_names({"players_per_team": players, "n_cars": n_cars}[game.count_key])
    unknown = [c for c in controlled if c not in names]
    if unknown:
        raise ParameterException(f"unknown robots {unknown}; robots are {names}", ["controlled_robots"])
    if marker_robot and marker_robot not in names:
        raise ParameterException(f"'{marker_robot}' is not one of {names}", ["marker_robot"])
    # Authenticated actions (issue 27, security/action_auth.py): with secrets_dir, an action counts only with its
    # team's MAC and a nonce not used before, and the feedback carries the simulator's MAC. Either way the
    # feedback names the action each robot's period ran (StepFeedback.action_digest).
    secrets = secrets_for(node, names, simulator=True)
    # /sim/reset, /sim/step and the settable parameters change the game (issue 43, ros/runtime_controls.py).
    runtime_controls = declare_runtime_controls(node, "/sim/reset, /sim/step")
    # Authenticated frames (issue 43, security/frame_auth.py): each frame's tag on <topic>_mac.
    tags_secret = frames_secret(node, node.get_parameter("secrets_dir").value, "Tag each DetectionArray "
                                "and WorldState on <topic>_mac")
    # ros-sports (issue 41, docs/interfaces.md): the same frames in the messages a team's stack reads.
    ros_sports = ros_sports and "ros_sports" in own
    if ros_sports and (len(gc_team_numbers) != 2 or gc_team_numbers[0] == gc_team_numbers[1]):
        raise ParameterException(f"the teams need distinct numbers, got {gc_team_numbers}",
                                 ["gc_team_number_a", "gc_team_number_b"])
    return SimSettings(
        scenario=scenario, mode=mode, real_time_factor=real_time_factor, missing_action=missing_action,
        perception_preset=preset, config=config, perception=perception, names=names,
        controlled=[names.index(c) for c in controlled] if controlled else None, seed=None if seed < 0 else seed,
        localization=localization and "localization" in own, ros_sports=ros_sports,
        gc_team_numbers=(gc_team_numbers[0], gc_team_numbers[1]) if ros_sports else (1, 2),
        auto_reset=auto_reset, publish_markers=publish_markers, marker_robot=marker_robot,
        diagnostics_period=diag_s, wait_for_subscribers=wait_for_subscribers,
        wait_for_truth_readers=wait_for_truth_readers, wait_for_recorder=wait_for_recorder,
        exit_when_finished=exit_when_finished, report_path=report_path, foxglove_port=foxglove_port,
        foxglove_host=foxglove_host, secrets=secrets, runtime_controls=runtime_controls, frames_secret=tags_secret)


__all__ = ["SimSettings", "declare_sim_parameters", "SCENARIO_PARAMETERS", "SCENARIO_DEFAULTS"]
