"""The trainer node (``ros2 run dynenv_ros trainer_node``): learns from the experience of every simulator game and
policy node it finds on the ROS graph, and streams new weights back to the policy nodes.

- Scenario (``scenario``, read-only): ``robocup`` learns the soccer agent from robots ``team_a_<k>`` /
  ``team_b_<k>`` (``players_per_team``, ``learning_team``); ``driving`` the driving agent (``action_mode``, the
  simulator's and the policy node's) from cars ``car_<k>`` (``n_cars``), each car's episode ending where its
  feedback says it ended (crashed, or home with its team's bonus decided). A parameter of the other scenario is
  refused, as the simulator node refuses it.
- Experience: for each robot (car) it discovers (``<game namespace>/<robot>/detections`` of type DetectionArray,
  e.g. ``/game_1/team_a_0/detections``, ``/game_1/car_0/detections``; the root namespace is a game too) it
  subscribes to the robot's detections, actions (with the behaviour policy's learning fields) and step feedback,
  and to the game's ``world_state`` when the variant learns localization or reconstruction (soccer).
  ``learning.messages.assembly`` assembles per-robot sequences aligned by episode and motion period, counting what is
  late, duplicated, out of order, missing or malformed. Each step is the action the simulator ran (its feedback
  names it by digest); with ``secrets_dir`` only actions carrying their team's MAC and feedback carrying the
  simulator's are read (``security.action_auth``; refusals counted and logged once per diagnostics period).
- Learning: ``learning.messages.message_trainer`` in a thread of its own, so no callback waits for a gradient step; PPO
  against the stored behaviour log-probabilities, sequences older than ``max_policy_lag`` versions dropped
  (docs/decisions.md). Run directory, logs (CSV, TensorBoard) and checkpoints as ``dynenv-train`` writes them,
  plus ``policy_start.safetensors``, the policy a fresh run starts from (what it learnt is measured against it).
- Budget: ``max_updates`` and/or ``max_minutes``; the first reached ends the run (checkpoint, policy, summary).
- Weights (``ros.weights_release``): each release, the initial one at start and a new one every
  ``publish_every_updates`` updates, is signed with the Ed25519 key ``signing_key`` and announced on
  ``/trainer/weights_announcement`` (reliable, transient local); its bytes are served in chunks on
  ``/trainer/fetch_weights``. Policy nodes that trust the key fetch, check and swap them in between two decisions.
- ``/trainer/diagnostics``: experience rate, queue depth, updates/s, version, lag, losses, the counts.

Parameters: ``--help``. docs/ros_graph.md, "Training over ROS", shows the graph and how to spread it over machines.
"""
from __future__ import annotations

import json
import re
import statistics
import time
from collections import Counter, deque
from collections.abc import Sequence as Args
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dynenv_msgs.msg import Action, DetectionArray, StepFeedback, WorldState
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dynenv_ros.agent.checkpoint import FORMAT, agent_config
from dynenv_ros.driving.config import MAX_CARS, DrivingConfig
from dynenv_ros.learning.config import ACTION_MODES, SCENARIOS, VARIANTS, ConfigError, TrainConfig
from dynenv_ros.core.writable import NotWritable, check_run_dir
from dynenv_ros.learning.run.checkpoints import START_POLICY, list_checkpoints
from dynenv_ros.learning.run.disk_budget import run_disk_bytes
from dynenv_ros.learning.messages.assembly import REFUSALS, ExperienceAssembler
from dynenv_ros.learning.messages.scenarios import DrivingExperience, ExperienceScenario, SoccerExperience
from dynenv_ros.learning.messages.message_trainer import MessageTrainer, TrainingThread
from dynenv_ros.ros import topics
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.runtime_controls import declare_runtime_controls, lock_when_off
from dynenv_ros.ros.frame_tags import FrameReceiver, frames_secret
from dynenv_ros.ros.drain import take
from dynenv_ros.ros.authentication import declare_secrets_dir, load_secrets
from dynenv_ros.ros.node_runner import NodeExit, run_node
from dynenv_ros.ros.parameters import declare_bool, declare_float, declare_int, declare_str, refuse_other_scenario
from dynenv_ros.ros.weights_release import WeightsRelease
from dynenv_ros.security.frame_auth import detection_array_bytes, world_state_bytes
from dynenv_ros.security.keys import PRIVATE_NAME, KeyFileError, default_keys_dir, load_private_key
from dynenv_ros.soccer.config import SoccerConfig

DETECTION_TYPE = "dynenv_msgs/msg/DetectionArray"
# Keep-last depths of the experience readers: deep enough that a stepped game's burst (an episode's last period and
# the next one's first) and a learner holding the GIL for a moment lose nothing; bounded so a trainer that cannot
# keep up falls behind in its own memory, never the games' (a reliable keep-last reader never blocks a writer).
FRAME_DEPTH, MESSAGE_DEPTH = 400, 100
# The parameters only one scenario uses (a value given for the other scenario is refused).
SCENARIO_PARAMETERS = {"robocup": ("players_per_team", "learning_team"), "driving": ("n_cars", "action_mode")}


def _signing_key(path: str):
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


def detections_pattern(agent_pattern: str) -> re.Pattern[str]:
    """``<game namespace>/<agent>/detections`` for agents named by ``agent_pattern`` (the scenario's)."""
    return re.compile(rf"^(?P<source>(/[A-Za-z0-9_]+)*)/(?P<robot>{agent_pattern})/detections$")


def experience_qos(depth: int, latched: bool = False) -> QoSProfile:
    """Reliable keep-last. Actions are read transient local: a policy node keeps its last 20 (``qos.action_stream``),
    so the first answers of a game are not lost while the trainer's reader is still matching the policy's writer (a
    stepped game starts once the trainer reads the detections, not once it has matched every policy). A publisher
    offering only volatile durability does not match such a reader — its actions carry no learning fields anyway."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class TrainerNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("trainer_node", **node_options)
        fixed = {"read_only": True}
        self.scenario = declare_str(self, "scenario", "robocup", "Which games it learns from: robocup (soccer "
                                    "robots) or driving (cars); the simulator's and the policy nodes'.",
                                    choices=SCENARIOS, **fixed)
        refuse_other_scenario(self, self.scenario, SCENARIO_PARAMETERS)
        driving = self.scenario == "driving"
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team in the games (robocup).", **fixed)
        n_cars = declare_int(self, "n_cars", 2, 1, MAX_CARS, "Cars in each game, all learning (driving).", **fixed)
        action_mode = declare_str(self, "action_mode", "discrete", "The cars' actions (driving): the simulator's "
                                  "and the policy nodes' action_mode.", choices=ACTION_MODES, **fixed)
        variant = declare_str(self, "variant", "pred", "Paper row of losses (dynenv-train's variant; 'recon' needs "
                              "pretrained_encoder, not available here; driving: baseline, icm, rcm or pred).",
                              choices=VARIANTS, **fixed)
        learning_rate = declare_float(self, "learning_rate", 1e-4, 1e-7, 1.0, "Adam learning rate (settable).")
        entropy = declare_float(self, "entropy_coef", 0.01, 0.0, 10.0, "Weight of the entropy bonus (settable).")
        steps = declare_int(self, "sequence_length", 6, 1, 256, "Motion periods per sequence (T).", **fixed)
        feature_size = declare_int(self, "feature_size", 64, 1, 1024, "Width D of the network (paper: 64).", **fixed)
        gamma = declare_float(self, "gamma", 0.99, 0.0, 1.0, "Discount per motion period.", **fixed)
        normalize = declare_bool(self, "normalize_advantages", False, "Normalise advantages per minibatch.",
                                 **fixed)
        weights = self.declare_parameter("reward_weights", [1.0, 1.0, 1.0, 1.0], ParameterDescriptor(
            description="Reward learnt: weights of StepFeedback's primary, rule, auxiliary and observation terms "
                        "(all ones: the simulator's total).", read_only=True)).value
        max_minutes = declare_float(self, "max_minutes", 0.0, 0.0, 1e6, "Stop (checkpoint, policy file, summary) "
                                    "after this many wall minutes; 0 = until stopped.", **fixed)
        self.max_updates = declare_int(self, "max_updates", 0, 0, 10**9, "Stop (checkpoint, policy file, summary) "
                                       "after this many updates, however long they take; 0 = until stopped.",
                                       **fixed)
        self.batch_sequences = declare_int(self, "batch_sequences", 8, 1, 4096, "Sequences per update (at most one "
                                           "per robot stream).", **fixed)
        max_batch = declare_int(self, "max_batch_sequences", 0, 0, 65536, "Most sequences per update: a learner "
                                "behind takes each robot's waiting ones in order (0: 4 x batch_sequences).", **fixed)
        epochs = declare_int(self, "ppo_epochs", 4, 1, 64, "PPO passes over each batch.", **fixed)
        minibatches = declare_int(self, "ppo_minibatches", 2, 1, 4096, "PPO minibatches per pass (<= "
                                  "batch_sequences).", **fixed)
        self.max_lag = declare_int(self, "max_policy_lag", 4, 0, 10_000, "Drop sequences chosen more than this "
                                   "many versions ago (settable).")
        self.publish_every = declare_int(self, "publish_every_updates", 1, 1, 100_000, "Publish weights every this "
                                         "many updates (settable).")
        checkpoint_min = declare_float(self, "checkpoint_every_minutes", 2.0, 0.01, 1440.0, "Checkpoint period, "
                                       "wall minutes.", **fixed)
        keep = declare_int(self, "keep_checkpoints", 3, 1, 1000, "Training checkpoints kept.", **fixed)
        run_dir = declare_str(self, "run_dir", "", "Run directory (config, metrics, checkpoints); empty: "
                              "runs/trainer-<time>.", **fixed)
        initial = declare_str(self, "initial_policy", "", "A policy file to start from (a warm start, e.g. dynenv-train "
                              "--from-bag's policy.safetensors); ignored when resuming.", **fixed)
        resume = declare_bool(self, "resume", False, "Resume from run_dir's latest checkpoint (dynenv-train "
                              "--resume reads the same directory).", **fixed)
        self.team = declare_str(self, "learning_team", "", "Robots whose experience is learnt (robocup): team 'a', "
                                "'b', or both ('': self-play with shared weights). Opponents are whoever controls "
                                "the other team (a scripted node, a frozen policy node with weights_topic:='').",
                                choices=("", "a", "b"), **fixed)
        patience = declare_int(self, "patience", 32, 1, 1000, "Periods a stream moves on before an incomplete one "
                               "counts as missing.", **fixed)
        seed = declare_int(self, "seed", 0, 0, 2**31 - 1, "Seed of the initial weights and minibatch order.", **fixed)
        threads = declare_int(self, "torch_threads", 1, 1, 256, "torch threads of the learner.", **fixed)
        diagnostics_s = declare_float(self, "diagnostics_period", 1.0, 0.1, 60.0, "Seconds between diagnostics.",
                                      **fixed)
        secrets_dir = declare_secrets_dir(self, "the learnt teams' secrets and simulator.secret: only actions with "
                                          "their team's MAC and feedback with the simulator's are learnt")
        # Authenticated frames (issue 43): only frames and world states whose tag under frames.secret came are learnt.
        frames = frames_secret(self, secrets_dir, "Learn only from frames and world states whose tag verifies")
        self.runtime_controls = declare_runtime_controls(self, "learning_rate, entropy_coef, max_policy_lag, "
                                                         "publish_every_updates")
        signing_key = declare_str(self, "signing_key", "", "Ed25519 private key (PEM, mode 0600) that signs every "
                                  "weights release; empty: trainer.key in $DYNENV_KEYS_DIR or "
                                  "~/.config/dynenv_ros/keys (make one with `dynenv-keys generate`).", **fixed)
        game = ({"scenario": "driving", "n_cars": n_cars, "action_mode": action_mode} if driving
                else {"players_per_team": players})
        try:
            self.cfg = TrainConfig(algorithm="ppo", variant=variant, **game, rollout_length=steps,
                                   ltp_horizon=min(6, steps), learning_rate=learning_rate, entropy_coef=entropy,
                                   feature_size=feature_size, gamma=gamma, normalize_advantages=normalize,
                                   ppo_epochs=epochs, ppo_minibatches=minibatches, gae_lambda=0.95,
                                   checkpoint_every_minutes=checkpoint_min, keep_checkpoints=keep, seed=seed,
                                   torch_threads=threads, log_every_updates=1)
        except ConfigError as error:
            raise ParameterException(str(error), [error.key]) from None
        self.signing_key = _signing_key(signing_key)     # before the run directory exists: nothing left behind
        self.run_dir = Path(run_dir or f"runs/trainer-{time.strftime('%Y%m%d-%H%M%S')}")
        try:        # a read-only disk, or one too small for the run's checkpoints: refused now, nothing written
            check_run_dir(self.run_dir, *run_disk_bytes(self.cfg), what="run_dir")
        except NotWritable as error:
            raise ParameterException(str(error), ["run_dir"]) from None
        try:
            self.message_trainer = MessageTrainer(self.cfg, self.run_dir, resume=resume,
                                           batch_sequences=self.batch_sequences, max_policy_lag=self.max_lag,
                                           reward_weights=list(weights), initial_policy=initial or None,
                                           max_batch_sequences=max_batch or None)
        except ConfigError as error:            # every refusal names its parameter
            raise ParameterException(str(error), [error.key]) from None
        if not list_checkpoints(self.run_dir):
            self.message_trainer.save_checkpoint()      # the first one at once: a kill from now on leaves a run to resume
            # the policy it starts from, so that what was learnt can be measured against it on held-out episodes
            from dynenv_ros.agent.checkpoint import save_policy
            save_policy(self.message_trainer.agent, str(self.run_dir / START_POLICY), self.message_trainer.policy_meta())
        self.run_id = self.run_dir.resolve().name
        if driving:
            agents: ExperienceScenario = DrivingExperience(DrivingConfig(n_cars=n_cars, action_mode=action_mode))
            learns = None
        else:
            soccer = SoccerConfig.from_mapping({"players_per_team": players})
            agents = SoccerExperience(players, soccer.rates.frames_per_period, soccer.motion.head_max_delta,
                                      soccer.motion.head_units)
            learns = self._learns
        self.detections = detections_pattern(agents.agent_pattern)
        self.secrets = load_secrets(secrets_dir, [n for n in agents.names if learns is None or learns(n)], True)
        self.assembler = ExperienceAssembler(steps, agents, with_targets=self._needs_targets(), patience=patience,
                                             learns=learns, secrets=self.secrets)
        self._refusals_logged: Counter[str] = Counter()      # the refusals already summarised in the log
        self.weights = WeightsRelease(self, self.signing_key, self.run_id)
        self.diagnostics_pub = Diagnostics(self, topics.TRAINER_DIAGNOSTICS)     # and /diagnostics
        self.received: Counter[str] = Counter()
        self.robots: set[tuple[str, str]] = set()
        self.games: set[str] = set()
        self.experience_subs: list = []
        self.frame_gate = FrameReceiver(self, frames) if frames is not None else None
        self._steps_window: deque[tuple[float, int, int]] = deque(maxlen=2)   # (wall, steps, updates)
        self.episodes: list[dict[str, float]] = []      # finished episodes: the version that ended it, return
        self.weights_published = 0
        self.finished = False
        self.background = TrainingThread(self.message_trainer, on_update=self._on_update)
        self._publish_weights()
        self.background.start()
        # The settable parameters change what is learnt: fixed with runtime_controls false (ros/runtime_controls.py).
        lock_when_off(self, self.runtime_controls, "learning_rate, entropy_coef, max_policy_lag and "
                      "publish_every_updates are fixed")
        if self.runtime_controls:
            self.add_on_set_parameters_callback(self._on_set_parameters)
        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.discovery_timer = self.create_timer(0.5, self._discover, clock=wall)
        self.diagnostics_timer = self.create_timer(diagnostics_s, self._publish_diagnostics, clock=wall)
        self.deadline = time.monotonic() + 60.0 * max_minutes if max_minutes > 0 else None
        if self.deadline is not None or self.max_updates:
            self.budget_timer = self.create_timer(0.2, self._check_budget, clock=wall)
        self._discover()
        who = (f"{n_cars} cars ({action_mode})" if driving else
               "both teams" if not self.team else "team " + self.team)
        self.get_logger().info(f"learning {variant} (PPO) from {who} into {self.run_dir}, version "
                               f"{self.message_trainer.version}")

    def _learns(self, robot: str) -> bool:
        """Soccer: the robot is of ``learning_team`` (both teams when it is empty)."""
        return self.team in ("", robot[5])

    def _needs_targets(self) -> bool:
        losses = self.cfg.losses()
        return losses.localization or losses.reconstruction

    def _check_budget(self) -> None:
        """Either budget ends the run: updates make a run comparable across machine speeds, minutes cap it."""
        spent = ("update budget" if self.max_updates and self.message_trainer.progress.updates >= self.max_updates else
                 "time budget" if self.deadline is not None and time.monotonic() >= self.deadline else None)
        if spent is not None:
            progress = self.message_trainer.progress
            self.get_logger().info(f"{spent} spent: version {self.message_trainer.version}, "
                                   f"{progress.updates} updates, {progress.env_steps} steps learnt")
            raise NodeExit(0)

    # -- experience ---------------------------------------------------------------------------------------------
    def _discover(self) -> None:
        """Subscribe to every robot that has appeared (names and types from the graph, no configuration)."""
        for name, types in self.get_topic_names_and_types():
            match = self.detections.match(name)
            if match is None or DETECTION_TYPE not in types:
                continue
            source, robot = match["source"], match["robot"]
            if (source, robot) in self.robots or robot not in self.assembler.names:
                continue
            self.robots.add((source, robot))
            if not self.assembler.learns(robot):
                continue
            add = self.assembler
            for msg_type, topic, method, kind, depth, latched in (
                    (DetectionArray, name, self._gated(add.add_frame, name, detection_array_bytes), "frames",
                     FRAME_DEPTH, False),
                    (Action, f"{source}/{robot}/action", add.add_action, "actions", MESSAGE_DEPTH, True),
                    (StepFeedback, f"{source}/{robot}/feedback", add.add_feedback, "feedback", MESSAGE_DEPTH, False)):
                handler = self._handler(method, source, robot, kind, depth)
                handler.subscription = self.create_subscription(msg_type, topic, handler,
                                                                experience_qos(depth, latched))
                self.experience_subs.append(handler.subscription)
            if self.frame_gate is not None:
                self.experience_subs.append(self.frame_gate.subscribe(self.resolve_topic_name(name),
                                                                      experience_qos(FRAME_DEPTH), self._release))
            if source not in self.games:
                self.games.add(source)
                if add.with_targets:
                    world = f"{source}/world_state"
                    self.experience_subs.append(self.create_subscription(
                        WorldState, world, self._world_handler(source), experience_qos(FRAME_DEPTH)))
                    if self.frame_gate is not None:
                        self.experience_subs.append(self.frame_gate.subscribe(
                            self.resolve_topic_name(world), experience_qos(FRAME_DEPTH), self._release))
            self.get_logger().info(f"learning from {source or '/'} {robot}")

    def _handler(self, add, source: str, robot: str, kind: str, depth: int):
        """The callback of one experience topic. It drains the topic's queue (``ros.drain``): the executor takes
        one message per subscription per wake-up, so a robot's frames (five per period) would fall behind its
        actions and feedback (one each) and miss their periods."""
        def receive(msg) -> None:
            for _ in range(depth):
                self.received[kind] += 1
                try:
                    add(source, robot, msg)
                except Exception as error:     # a message nothing foresaw: dropped and counted, never fatal
                    self.received["errors"] += 1
                    self.get_logger().error(f"{kind} of {source}/{robot} dropped: {type(error).__name__}: "
                                            f"{error}", throttle_duration_sec=5.0)
                msg = take(receive.subscription)
                if msg is None:
                    break
            ready = self.assembler.take()
            if ready:
                self.background.put(ready)
        receive.subscription = None
        return receive

    def _world_handler(self, source: str):
        add = self._gated(lambda _source, _robot, msg: self.assembler.add_world_state(source, msg),
                          f"{source}/world_state", world_state_bytes)

        def receive(msg) -> None:
            self.received["world_states"] += 1
            add(source, None, msg)
        return receive

    def _gated(self, add, topic: str, encode):
        """``add`` as it is, or with authenticated frames behind the gate: a frame is added once its tag came
        (now, or later by ``_release``)."""
        if self.frame_gate is None:
            return add
        topic = self.resolve_topic_name(topic)

        def admit(source: str, robot: str | None, msg) -> None:
            try:
                data = encode(msg, topic)
            except ValueError:
                data = None
            for item in self.frame_gate.frame((add, source, robot, msg), data, topic):
                self._add_verified([item])
        return admit

    def _release(self, items: list) -> None:
        """Frames whose tag came after them: added, and whatever they complete handed to the learner."""
        self._add_verified(items)
        ready = self.assembler.take()
        if ready:
            self.background.put(ready)

    def _add_verified(self, items: list) -> None:
        for add, source, robot, msg in items:
            try:
                add(source, robot, msg)
            except Exception as error:     # as the handlers: a message nothing foresaw is dropped and counted
                self.received["errors"] += 1
                self.get_logger().error(f"frame of {source}/{robot} dropped: {type(error).__name__}: {error}",
                                        throttle_duration_sec=5.0)

    # -- weights --------------------------------------------------------------------------------------------------
    def _on_update(self, trainer: MessageTrainer, stats: dict[str, float]) -> None:
        """In the learner thread, after each update: log, and publish the weights at the cadence asked for."""
        scalars = {f"train/{k}": v for k, v in stats.items()}
        finished, trainer.finished = trainer.finished, []
        if finished:
            scalars["episode/return"] = statistics.fmean(e["return"] for e in finished)
            self.episodes.extend(finished)
        scalars["experience/queue_depth"] = float(self.background.depth())
        trainer.log(scalars)
        if trainer.progress.updates % self.publish_every == 0:
            self._publish_weights()

    def _publish_weights(self) -> None:
        try:
            data = self.message_trainer.weights()
        except ValueError as error:         # non-finite weights are never published (checkpoint.policy_bytes)
            self.message_trainer.counts["weights_refused"] += 1
            self.get_logger().error(f"weights not published: {error}")
            return
        # the network's shape, so a policy node checks it before fetching (a policy file's format and config)
        metadata = {"format": FORMAT, "config": agent_config(self.message_trainer.agent),
                    "updates": self.message_trainer.policy_meta()["updates"]}
        self.weights.release(self.message_trainer.version, data, json.dumps(metadata, sort_keys=True))
        self.weights_published += 1

    # -- parameters, diagnostics, shutdown ---------------------------------------------------------------------
    def _on_set_parameters(self, parameters: list) -> SetParametersResult:
        for p in parameters:
            if p.name == "learning_rate":
                self.message_trainer.set_learning_rate(float(p.value))
            elif p.name == "entropy_coef":
                self.message_trainer.settings.entropy_coef = float(p.value)
            elif p.name == "max_policy_lag":
                self.message_trainer.max_policy_lag = int(p.value)
            elif p.name == "publish_every_updates":
                self.publish_every = int(p.value)
        return SetParametersResult(successful=True)

    def diagnostics(self) -> dict[str, str]:
        now = time.monotonic()
        counts = self.assembler.counts
        self._steps_window.append((now, counts["steps"], self.message_trainer.progress.updates))
        (t0, s0, u0), (t1, s1, u1) = self._steps_window[0], self._steps_window[-1]
        span = max(t1 - t0, 1e-9)
        stats = self.message_trainer.last_stats
        values = {"version": str(self.message_trainer.version), "updates": str(self.message_trainer.progress.updates),
                  "games": str(len(self.games)), "robots": str(len(self.robots)),
                  "experience_steps_per_s": f"{(s1 - s0) / span:.1f}" if t1 > t0 else "0.0",
                  "updates_per_s": f"{(u1 - u0) / span:.3f}" if t1 > t0 else "0.000",
                  "queue_depth": str(self.background.depth()),
                  "lag_versions_mean": f"{stats.get('lag_versions_mean', 0.0):.2f}",
                  "lag_seconds_mean": f"{stats.get('lag_seconds_mean', 0.0):.2f}",
                  "policy_loss": f"{stats.get('policy_loss', 0.0):.4f}",
                  "value_loss": f"{stats.get('value_loss', 0.0):.4f}",
                  "entropy": f"{stats.get('entropy', 0.0):.4f}",
                  "learner_error": self.background.error, "last_missing": self.assembler.last_missing,
                  "last_refused": self.assembler.last_refused}
        for key in ("steps", "sequences", "late", "duplicate", "out_of_order", "missing", "malformed",
                    "not_learning", "cuts", "steps_discarded", "unknown_robot", "targets_missing",
                    "bootstrap_estimated", "after_end", "actions_rounded", "out_of_range", "early_replaced",
                    "contested", "contested_cuts", "rival_answers", "rivals_resolved", "unmatched_action",
                    "not_executed", "beyond_horizon", "candidates_full", "action_mac_missing", "action_mac_invalid",
                    "feedback_mac_missing", "feedback_mac_invalid"):
            values[key] = str(counts.get(key, 0))
        values["action_authentication"] = "off" if self.secrets is None else "on"
        values["runtime_controls"] = "on" if self.runtime_controls else "off"
        values["frame_authentication"] = "off"
        if self.frame_gate is not None:
            values.update(self.frame_gate.diagnostics())
        for key, value in list(self.message_trainer.counts.items()) + list(self.background.counts.items()):
            values[key] = str(value)
        for key, value in self.received.items():
            values[f"received_{key}"] = str(value)
        return values

    def _publish_diagnostics(self) -> None:
        values = self.diagnostics()
        level = DiagnosticStatus.ERROR if self.background.error else DiagnosticStatus.OK
        status = DiagnosticStatus(level=level, name="dynenv_trainer", hardware_id=self.get_fully_qualified_name(),
                                  message=self.background.error or f"version {values['version']}",
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(msg)
        self._log_refusals()

    def _log_refusals(self) -> None:
        """One line per diagnostics period with the messages refused since the last one, by reason, and the last
        refusal: a flood of forged messages costs a counter each, never a log line each."""
        counts = self.assembler.counts
        new = {k: counts[k] - self._refusals_logged[k] for k in REFUSALS if counts[k] > self._refusals_logged[k]}
        if new:
            self._refusals_logged.update(new)
            summary = ", ".join(f"{n} {k}" for k, n in sorted(new.items()))
            self.get_logger().warning(f"messages refused since the last report: {summary}; last: "
                                      f"{self.assembler.last_refused}")

    def summary(self) -> dict[str, Any]:
        """Mean episode return per policy version (of the episode's last step), and the counts."""
        by_version: dict[int, list[float]] = {}
        for episode in self.episodes:
            by_version.setdefault(int(episode["version"]), []).append(episode["return"])
        return {"version": self.message_trainer.version, "updates": self.message_trainer.progress.updates,
                "env_steps": self.message_trainer.progress.env_steps, "wall_seconds": self.message_trainer.meta()["wall_seconds"],
                "reward_weights": self.message_trainer.reward_weights.tolist(),
                "episodes": [[int(e["version"]), e["return"]] for e in self.episodes],
                "returns_by_version": {v: {"episodes": len(r), "mean_return": statistics.fmean(r)}
                                       for v, r in sorted(by_version.items())},
                "diagnostics": self.diagnostics()}

    def destroy_node(self) -> None:
        """Stop learning, checkpoint, write the policy file and the summary (the run directory is complete)."""
        if self.finished:
            return
        self.finished = True
        self.background.stop()
        try:
            self.message_trainer.save_checkpoint()
            from dynenv_ros.agent.checkpoint import save_policy
            save_policy(self.message_trainer.agent, str(self.run_dir / "policy.safetensors"),
                        self.message_trainer.policy_meta())
            (self.run_dir / "summary.json").write_text(json.dumps(self.summary(), indent=2) + "\n")
        finally:
            self.message_trainer.close()
            super().destroy_node()


def main(args: Args[str] | None = None) -> int:
    return run_node(TrainerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
