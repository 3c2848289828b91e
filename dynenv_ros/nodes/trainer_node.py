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
  and to the game's ``world_state`` when the variant learns localization or reconstruction (soccer;
  ``ros/experience_readers.py``).
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

Parameters: ``--help`` (``nodes/trainer_parameters.py``). docs/ros_graph.md, "Training over ROS", shows the graph
and how to spread it over machines.
"""
from __future__ import annotations

import json
import statistics
import time
from collections import Counter, deque
from collections.abc import Sequence as Args
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.agent.checkpoint import FORMAT, agent_config
from dynenv_ros.core.writable import NotWritable, check_run_dir
from dynenv_ros.learning.run.checkpoints import START_POLICY, list_checkpoints
from dynenv_ros.learning.config import ConfigError
from dynenv_ros.learning.run.disk_budget import run_disk_bytes
from dynenv_ros.learning.messages.assembly import REFUSALS, ExperienceAssembler
from dynenv_ros.learning.messages.scenarios import ExperienceScenario, experience_scenario
from dynenv_ros.learning.messages.message_trainer import TrainingThread, MessageTrainer
from dynenv_ros.nodes.trainer_parameters import declare_trainer_parameters
from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import load_secrets
from dynenv_ros.ros.diagnostics import Diagnostics
from dynenv_ros.ros.experience_readers import ExperienceReaders
from dynenv_ros.ros.node_runner import NodeExit, run_node
from dynenv_ros.ros.runtime_controls import lock_when_off
from dynenv_ros.ros.weights_release import WeightsRelease
from dynenv_ros.scenarios import get_scenario

class TrainerNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("trainer_node", **node_options)
        settings = self.settings = declare_trainer_parameters(self)
        self.scenario, self.team, self.cfg = settings.scenario, settings.team, settings.cfg
        self.max_updates, self.batch_sequences = settings.max_updates, settings.batch_sequences
        self.max_lag, self.publish_every = settings.max_lag, settings.publish_every
        self.runtime_controls, self.signing_key = settings.runtime_controls, settings.signing_key
        world = get_scenario(settings.scenario)
        count = getattr(settings.cfg, world.count_key)           # robots per team, or cars
        self.run_dir = Path(settings.run_dir or f"runs/trainer-{time.strftime('%Y%m%d-%H%M%S')}")
        try:        # a read-only disk, or one too small for the run's checkpoints: refused now, nothing written
            check_run_dir(self.run_dir, *run_disk_bytes(self.cfg), what="run_dir")
        except NotWritable as error:
            raise ParameterException(str(error), ["run_dir"]) from None
        try:
            self.message_trainer = MessageTrainer(self.cfg, self.run_dir, resume=settings.resume,
                                                  batch_sequences=self.batch_sequences, max_policy_lag=self.max_lag,
                                                  reward_weights=settings.reward_weights,
                                                  initial_policy=settings.initial_policy or None,
                                                  max_batch_sequences=settings.max_batch or None)
        except ConfigError as error:            # every refusal names its parameter
            raise ParameterException(str(error), [error.key]) from None
        if not list_checkpoints(self.run_dir):
            self.message_trainer.save_checkpoint()  # the first one at once: a kill from now on leaves a run to resume
            # the policy it starts from, so that what was learnt can be measured against it on held-out episodes
            from dynenv_ros.agent.checkpoint import save_policy
            save_policy(self.message_trainer.agent, str(self.run_dir / START_POLICY),
                        self.message_trainer.policy_meta())
        self.run_id = self.run_dir.resolve().name
        agents: ExperienceScenario = experience_scenario(settings.scenario, count, None, settings.action_mode)
        learns = self._learns if world.sides > 1 else None       # (one side: every agent learns)
        self.secrets = load_secrets(settings.secrets_dir, [n for n in agents.names if learns is None or learns(n)],
                                    True)
        self.assembler = ExperienceAssembler(settings.steps, agents, with_targets=self._needs_targets(),
                                             patience=settings.patience, learns=learns, secrets=self.secrets)
        self._refusals_logged: Counter[str] = Counter()      # the refusals already summarised in the log
        self.weights = WeightsRelease(self, self.signing_key, self.run_id)
        self.diagnostics_pub = Diagnostics(self, topics.TRAINER_DIAGNOSTICS)     # and /diagnostics
        self.readers = ExperienceReaders(self, self.assembler, agents.agent_pattern, settings.frames_secret,
                                         self._learn)
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
        self.discovery_timer = self.create_timer(0.5, self.readers.discover, clock=wall)
        self.diagnostics_timer = self.create_timer(settings.diagnostics_period, self._publish_diagnostics,
                                                   clock=wall)
        minutes = settings.max_minutes
        self.deadline = time.monotonic() + 60.0 * minutes if minutes > 0 else None
        if self.deadline is not None or self.max_updates:
            self.budget_timer = self.create_timer(0.2, self._check_budget, clock=wall)
        self.readers.discover()
        who = (f"{count} {world.agent}s ({settings.action_mode})" if world.sides == 1 else
               "both teams" if not self.team else "team " + self.team)
        self.get_logger().info(f"learning {settings.variant} (PPO) from {who} into {self.run_dir}, version "
                               f"{self.message_trainer.version}")

    def _learns(self, robot: str) -> bool:
        """Soccer: the robot is of ``learning_team`` (both teams when it is empty)."""
        return self.team in ("", robot[5])

    def _needs_targets(self) -> bool:
        losses = self.cfg.losses()
        return losses.localization or losses.reconstruction

    def _check_budget(self) -> None:
        """Either budget ends the run: updates make a run comparable across machine speeds, minutes cap it."""
        progress = self.message_trainer.progress
        spent = ("update budget" if self.max_updates and progress.updates >= self.max_updates else
                 "time budget" if self.deadline is not None and time.monotonic() >= self.deadline else None)
        if spent is not None:
            self.get_logger().info(f"{spent} spent: version {self.message_trainer.version}, "
                                   f"{progress.updates} updates, {progress.env_steps} steps learnt")
            raise NodeExit(0)

    def _learn(self, sequences: list) -> None:
        """Sequences the assembler completed: to the learner's queue."""
        self.background.put(sequences)

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
                  "games": str(len(self.readers.games)), "robots": str(len(self.readers.robots)),
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
        if self.readers.frame_gate is not None:
            values.update(self.readers.frame_gate.diagnostics())
        for key, value in list(self.message_trainer.counts.items()) + list(self.background.counts.items()):
            values[key] = str(value)
        for key, value in self.readers.received.items():
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
                "env_steps": self.message_trainer.progress.env_steps,
                "wall_seconds": self.message_trainer.meta()["wall_seconds"],
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
