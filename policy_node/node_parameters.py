"""The policy node's parameters (``ros2 run dynenv_ros policy_node --help`` lists them in this order), declared in
one place and read once: all but ``greedy`` and ``use_sim_time`` are read-only, and those two are fixed too when
``runtime_controls`` is off (``ros/runtime_controls.py``). A value that cannot work is refused with the reason
(ParameterException: the node exits with status 2 before it starts)."""
from __future__ import annotations

from dataclasses import dataclass

from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.agent.checkpoint import MAX_POLICY_BYTES
from dynenv_ros.driving.config import MAX_CARS
from dynenv_ros.ros import topics
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.pose_estimates import declare_pose_input
from dynenv_ros.ros.runtime_controls import declare_runtime_controls
from dynenv_ros.scenarios import Scenario, get_scenario
from policy_node.partial_periods import AUTO_DEADLINE, resolve_deadline
from policy_node.policy_files import RUNTIMES

SCENARIOS = ("robocup", "driving")


@dataclass(frozen=True)
class PolicyParameters:
    scenario: str
    players: int
    team: str
    n_cars: int
    cars: list[str]
    action_mode: str
    runtime: str
    checkpoint: str
    seed: int
    greedy: bool
    diagnostics_s: float
    weights_topic: str
    trusted_keys: list[str]
    max_weights: int
    weights_state: str
    operator_keys: list[str]
    allow_unsigned_files: bool
    runtime_controls: bool
    weights_run: str
    pose_max_age: float
    pose_frame: str
    deadline_ns: int | None          # decision_deadline in ns; None: wait for complete periods

    @property
    def game(self) -> Scenario:
        """The scenario ``scenario`` names (its parameter spelling: robocup, driving)."""
        return get_scenario(self.scenario)

    @property
    def agent_count(self) -> int:
        """The game's agents per team (robocup) or cars (driving): the scenario's ``count_key``."""
        return {"players_per_team": self.players, "n_cars": self.n_cars}[self.game.count_key]


def declare_parameters(node: Node) -> PolicyParameters:
    scenario = declare_str(node, "scenario", "robocup", "Which game: robocup (soccer robots) or driving "
                           "(cars); the policy must be of the same scenario.", choices=SCENARIOS, read_only=True)
    players = declare_int(node, "players_per_team", 2, 1, 5, "Robots per team in the game (robocup).",
                          read_only=True)
    team = declare_str(node, "team", "", "Control team 'a', team 'b', or both ('') (robocup).", read_only=True,
                       choices=("", "a", "b"))
    n_cars = declare_int(node, "n_cars", 2, 1, MAX_CARS, "Cars in the game (driving).", read_only=True)
    cars = declare_str_list(node, "cars", [], "Cars to drive (car_0, …; driving); empty: all n_cars — the "
                            "others may be driven by other nodes, e.g. scripted_driver.", read_only=True)
    action_mode = declare_str(node, "action_mode", "discrete", "The simulator's action_mode (driving): the "
                              "policy's must be the same.", choices=("discrete", "continuous"), read_only=True)
    if team and get_scenario(scenario).picks_agents_with != "team":
        raise ParameterException("team applies to robocup; a driving node picks its cars with cars", ["team"])
    runtime = declare_str(node, "runtime", "", "Inference runtime; empty: the checkpoint's (.onnx: onnxruntime, "
                          "else torch).", choices=("", *RUNTIMES), read_only=True)
    checkpoint = declare_str(node, "checkpoint", "", "Weights: a .safetensors policy file (torch) or .onnx "
                             "file; empty: untrained weights from 'seed' (smoke tests only).", read_only=True)
    seed = declare_int(node, "seed", 0, 0, 2**31 - 1, "Seed of action sampling (and untrained weights).",
                       read_only=True)
    greedy = declare_bool(node, "greedy", False, "Take the most likely action instead of sampling.")
    diagnostics_s = declare_float(node, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.",
                                  read_only=True)
    weights_topic = declare_str(node, "weights_topic", topics.WEIGHTS_ANNOUNCEMENT, "A trainer's signed "
                                "WeightsAnnouncements; the weights are taken from the blob topic beside it "
                                "(weights_blob) or the fetch service the announcement names, checked and "
                                "swapped in between two decisions (torch runtime); empty: never.", read_only=True)
    trusted_keys = declare_str_list(node, "trusted_weights_keys", [], "Ed25519 public keys (.pub files, or "
                                    "directories of them) whose signed weights are taken; none: a trainer's "
                                    "weights are refused.", read_only=True)
    max_weights = declare_int(node, "max_weights_bytes", MAX_POLICY_BYTES, 1, MAX_POLICY_BYTES, "Largest "
                              "announced policy file fetched, bytes (refused before any byte travels).",
                              read_only=True)
    weights_state = declare_str(node, "weights_state_file", "", "JSON file keeping the last accepted release "
                                "(run, version, stamp) across restarts, so a replay stays refused; empty: "
                                "kept in memory only.", read_only=True)
    operator_keys = declare_str_list(node, "trusted_operator_keys", [], "Ed25519 public keys (.pub files, or "
                                     "directories of them) of the operators whose signed requests "
                                     "~/load_policy and ~/accept_older_weights obey (dynenv-keys operator); "
                                     "none: those services are off.", read_only=True)
    allow_unsigned_files = declare_bool(node, "allow_unsigned_files", False, "Let ~/load_policy load a "
                                        "file without a trusted detached signature beside it (FILE.sig, "
                                        "dynenv-keys sign-file); the request itself must still be "
                                        "signed.", read_only=True)
    # use_sim_time (rclpy's own) and greedy are settable: fixed with runtime_controls false (ros/runtime_controls.py)
    runtime_controls = declare_runtime_controls(node, "greedy, use_sim_time")
    weights_run = declare_str(node, "weights_run_id", "", "Take weights from this trainer run only "
                              "(WeightsAnnouncement.run_id); empty: any run.", read_only=True)
    pose_max_age, pose_frame = declare_pose_input(node, "Robocup, a policy that takes the pose estimate")
    deadline = declare_float(node, "decision_deadline", AUTO_DEADLINE, AUTO_DEADLINE, 60.0, "Seconds (node "
                             "clock) after a period's last frame is due by which the node acts on the frames "
                             "that arrived, missing ones empty; a newer period's frame closes it too. -1: wait "
                             "for complete periods; -2 (default): 0.05 on the wall clock, -1 on sim time.",
                             read_only=True)
    deadline = resolve_deadline(deadline, bool(node.get_parameter("use_sim_time").value))
    return PolicyParameters(
        scenario=scenario, players=players, team=team, n_cars=n_cars, cars=cars, action_mode=action_mode,
        runtime=runtime, checkpoint=checkpoint, seed=seed, greedy=greedy, diagnostics_s=diagnostics_s,
        weights_topic=weights_topic, trusted_keys=trusted_keys,
        max_weights=max_weights, weights_state=weights_state, operator_keys=operator_keys,
        allow_unsigned_files=allow_unsigned_files, runtime_controls=runtime_controls, weights_run=weights_run,
        pose_max_age=pose_max_age, pose_frame=pose_frame,
        deadline_ns=round(deadline * 1e9) if deadline >= 0 else None)


def controlled_robots(params: PolicyParameters) -> tuple[list[str], dict[str, int]]:
    """The robots (cars) the node acts for, in the game's order, and each one's id in the game."""
    everyone = params.game.agent_names(params.agent_count)
    if params.cars and params.game.picks_agents_with != "cars":
        raise ParameterException("cars is a driving parameter (robocup picks robots with team)", ["cars"])
    unknown = [c for c in params.cars if c not in everyone]
    if unknown:
        raise ParameterException(f"unknown cars {unknown}; cars are {everyone}", ["cars"])
    names = [name for name in everyone if (not params.team or name[5] == params.team)
             and (not params.cars or name in params.cars)]
    return names, {name: everyone.index(name) for name in names}


__all__ = ["SCENARIOS", "PolicyParameters", "controlled_robots", "declare_parameters"]
