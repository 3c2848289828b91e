"""The trainer node's parameters (``--help`` lists them): declared in one place, in the order ``--help`` shows them,
checked, and turned into the training config (``TrainerSettings``). Every refusal is a ParameterException naming
its parameter, before anything is written.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.driving.config import MAX_CARS
from dynenv_ros.learning.config import ACTION_MODES, SCENARIOS, VARIANTS, ConfigError, TrainConfig
from dynenv_ros.ros.authentication import declare_secrets_dir
from dynenv_ros.ros.frame_tags import frames_secret
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, refuse_other_scenario
from dynenv_ros.ros.runtime_controls import declare_runtime_controls
from dynenv_ros.scenarios import get_scenario
from dynenv_ros.security.keys import PRIVATE_NAME, KeyFileError, default_keys_dir, load_private_key

# The parameters only one scenario uses (a value given for the other scenario is refused).
SCENARIO_PARAMETERS = {"robocup": ("players_per_team", "learning_team"), "driving": ("n_cars", "action_mode")}


@dataclass
class TrainerSettings:
    """Every parameter's value at start that the node keeps, and the training config they make."""
    scenario: str
    players: int
    n_cars: int
    action_mode: str
    variant: str
    steps: int                      # sequence_length
    reward_weights: list[float]
    max_minutes: float
    max_updates: int
    batch_sequences: int
    max_batch: int                  # 0: 4 x batch_sequences
    max_lag: int
    publish_every: int
    run_dir: str
    initial_policy: str
    resume: bool
    team: str                       # learning_team
    patience: int
    diagnostics_period: float
    secrets_dir: str
    frames_secret: bytes | None
    runtime_controls: bool
    cfg: TrainConfig
    signing_key: Any                # the Ed25519 private key


def signing_key(path: str) -> Any:
    """The trainer's Ed25519 private key; without one it refuses to start (a ParameterException, one line):
    unsigned weights would be refused by every policy node that checks them."""
    file = Path(path).expanduser() if path else default_keys_dir() / PRIVATE_NAME
    if not path and not file.exists():
        raise ParameterException(f"no signing key: run `dynenv-keys generate {default_keys_dir()}` (or give "
                                 "-p signing_key:=FILE); the policy nodes get the trainer.pub beside it",
                                 ["signing_key"])
    try:
        return load_private_key(file)
    except KeyFileError as error:
        raise ParameterException(str(error), ["signing_key"]) from None


def declare_trainer_parameters(node: Node) -> TrainerSettings:
    """Declare the trainer's parameters on ``node``, check them and load the signing key."""
    fixed = {"read_only": True}
    scenario = declare_str(node, "scenario", "robocup", "Which games it learns from: robocup (soccer "
                           "robots) or driving (cars); the simulator's and the policy nodes'.",
                           choices=SCENARIOS, **fixed)
    refuse_other_scenario(node, scenario, SCENARIO_PARAMETERS)
    players = declare_int(node, "players_per_team", 2, 1, 5, "Robots per team in the games (robocup).", **fixed)
    n_cars = declare_int(node, "n_cars", 2, 1, MAX_CARS, "Cars in each game, all learning (driving).", **fixed)
    action_mode = declare_str(node, "action_mode", "discrete", "The cars' actions (driving): the simulator's "
                              "and the policy nodes' action_mode.", choices=ACTION_MODES, **fixed)
    variant = declare_str(node, "variant", "pred", "Paper row of losses (dynenv-train's variant; 'recon' needs "
                          "pretrained_encoder, not available here; driving: baseline, icm, rcm or pred).",
                          choices=VARIANTS, **fixed)
    learning_rate = declare_float(node, "learning_rate", 1e-4, 1e-7, 1.0, "Adam learning rate (settable).")
    entropy = declare_float(node, "entropy_coef", 0.01, 0.0, 10.0, "Weight of the entropy bonus (settable).")
    steps = declare_int(node, "sequence_length", 6, 1, 256, "Motion periods per sequence (T).", **fixed)
    feature_size = declare_int(node, "feature_size", 64, 1, 1024, "Width D of the network (paper: 64).", **fixed)
    gamma = declare_float(node, "gamma", 0.99, 0.0, 1.0, "Discount per motion period.", **fixed)
    normalize = declare_bool(node, "normalize_advantages", False, "Normalise advantages per minibatch.", **fixed)
    weights = node.declare_parameter("reward_weights", [1.0, 1.0, 1.0, 1.0], ParameterDescriptor(
        description="Reward learnt: weights of StepFeedback's primary, rule, auxiliary and observation terms "
                    "(all ones: the simulator's total).", read_only=True)).value
    max_minutes = declare_float(node, "max_minutes", 0.0, 0.0, 1e6, "Stop (checkpoint, policy file, summary) "
                                "after this many wall minutes; 0 = until stopped.", **fixed)
    max_updates = declare_int(node, "max_updates", 0, 0, 10**9, "Stop (checkpoint, policy file, summary) "
                              "after this many updates, however long they take; 0 = until stopped.", **fixed)
    batch_sequences = declare_int(node, "batch_sequences", 8, 1, 4096, "Sequences per update (at most one "
                                  "per robot stream).", **fixed)
    max_batch = declare_int(node, "max_batch_sequences", 0, 0, 65536, "Most sequences per update: a learner "
                            "behind takes each robot's waiting ones in order (0: 4 x batch_sequences).", **fixed)
    epochs = declare_int(node, "ppo_epochs", 4, 1, 64, "PPO passes over each batch.", **fixed)
    minibatches = declare_int(node, "ppo_minibatches", 2, 1, 4096, "PPO minibatches per pass (<= "
                              "batch_sequences).", **fixed)
    max_lag = declare_int(node, "max_policy_lag", 4, 0, 10_000, "Drop sequences chosen more than this "
                          "many versions ago (settable).")
    publish_every = declare_int(node, "publish_every_updates", 1, 1, 100_000, "Publish weights every this "
                                "many updates (settable).")
    checkpoint_min = declare_float(node, "checkpoint_every_minutes", 2.0, 0.01, 1440.0, "Checkpoint period, "
                                   "wall minutes.", **fixed)
    keep = declare_int(node, "keep_checkpoints", 3, 1, 1000, "Training checkpoints kept.", **fixed)
    run_dir = declare_str(node, "run_dir", "", "Run directory (config, metrics, checkpoints); empty: "
                          "runs/trainer-<time>.", **fixed)
    initial = declare_str(node, "initial_policy", "", "A policy file to start from (a warm start, e.g. dynenv-train "
                          "--from-bag's policy.safetensors); ignored when resuming.", **fixed)
    resume = declare_bool(node, "resume", False, "Resume from run_dir's latest checkpoint (dynenv-train "
                          "--resume reads the same directory).", **fixed)
    team = declare_str(node, "learning_team", "", "Robots whose experience is learnt (robocup): team 'a', "
                       "'b', or both ('': self-play with shared weights). Opponents are whoever controls "
                       "the other team (a scripted node, a frozen policy node with weights_topic:='').",
                       choices=("", "a", "b"), **fixed)
    patience = declare_int(node, "patience", 32, 1, 1000, "Periods a stream moves on before an incomplete one "
                           "counts as missing.", **fixed)
    seed = declare_int(node, "seed", 0, 0, 2**31 - 1, "Seed of the initial weights and minibatch order.", **fixed)
    threads = declare_int(node, "torch_threads", 1, 1, 256, "torch threads of the learner.", **fixed)
    diagnostics_s = declare_float(node, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.",
                                  **fixed)
    secrets_dir = declare_secrets_dir(node, "the learnt teams' secrets and simulator.secret: only actions with "
                                      "their team's MAC and feedback with the simulator's are learnt")
    # Authenticated frames (issue 43): only frames and world states whose tag under frames.secret came are learnt.
    frames = frames_secret(node, secrets_dir, "Learn only from frames and world states whose tag verifies")
    runtime_controls = declare_runtime_controls(node, "learning_rate, entropy_coef, max_policy_lag, "
                                                "publish_every_updates")
    key_path = declare_str(node, "signing_key", "", "Ed25519 private key (PEM, mode 0600) that signs every "
                           "weights release; empty: trainer.key in $DYNENV_KEYS_DIR or "
                           "~/.config/dynenv_ros/keys (make one with `dynenv-keys generate`).", **fixed)
    count_key = get_scenario(scenario).count_key
    game = {"scenario": scenario, count_key: {"players_per_team": players, "n_cars": n_cars}[count_key],
            "action_mode": action_mode}     # (the other scenario's parameters keep their defaults: refused above)
    try:
        cfg = TrainConfig(algorithm="ppo", variant=variant, **game, rollout_length=steps,
                          ltp_horizon=min(6, steps), learning_rate=learning_rate, entropy_coef=entropy,
                          feature_size=feature_size, gamma=gamma, normalize_advantages=normalize,
                          ppo_epochs=epochs, ppo_minibatches=minibatches, gae_lambda=0.95,
                          checkpoint_every_minutes=checkpoint_min, keep_checkpoints=keep, seed=seed,
                          torch_threads=threads, log_every_updates=1)
    except ConfigError as error:
        raise ParameterException(str(error), [error.key]) from None
    return TrainerSettings(
        scenario=scenario, players=players, n_cars=n_cars, action_mode=action_mode, variant=variant, steps=steps,
        reward_weights=list(weights), max_minutes=max_minutes, max_updates=max_updates,
        batch_sequences=batch_sequences, max_batch=max_batch, max_lag=max_lag, publish_every=publish_every,
        run_dir=run_dir, initial_policy=initial, resume=resume, team=team, patience=patience,
        diagnostics_period=diagnostics_s, secrets_dir=secrets_dir, frames_secret=frames,
        runtime_controls=runtime_controls, cfg=cfg,
        signing_key=signing_key(key_path))     # before the run directory exists: nothing left behind


__all__ = ["TrainerSettings", "declare_trainer_parameters", "signing_key", "SCENARIO_PARAMETERS"]
