"""The in-process trainer: the vectorised soccer batch, the agent, PPO or A2C with the paper's auxiliary losses,
logging, atomic checkpoints and resumption — no ROS. ``dynenv-train`` (``train_cli``) runs it; the trainer node
reuses its pieces (``RolloutCollector``, ``update``, ``checkpoints``).

A run directory holds: ``config.json`` (the resolved config), ``metrics.csv`` and ``tensorboard/`` (every scalar),
``checkpoints/`` (the last few, safetensors + JSON, see ``checkpoints``), and at the end ``policy.safetensors``,
``policy.onnx``, ``curves.png`` and ``summary.json`` (with ``best_policy_window``, also ``best_policy.safetensors``:
``learning.run.best_policy``). Resuming (``--resume RUN_DIR``) restores the networks, the
optimiser, the step counters and the random generators from the latest checkpoint; the worlds restart with fresh
episodes seeded from (seed, update), since a world's physics state is not checkpointed — an episode cut by a kill
is simply not counted.

``scenario: driving``: the driving agent (``DynEnvAgent(scenario='driving', action_mode)``) on ``DrivingVectorEnv``
with ``n_cars`` cars per world, every car learning (no opponent); the same run directory. Episode scalars are per
car: return, its terms, ``home`` and ``crashed`` (fractions of finished car-episodes).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.algo import compiled
from dynenv_ros.learning.algo.networks import make_agent
from dynenv_ros.learning.algo.ppo import update, update_settings
from dynenv_ros.learning.run.best_policy import BestPolicy
from dynenv_ros.learning.run.compute import ComputeMeter
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.algo.networks import Learner
from dynenv_ros.learning.algo.experience import Rollout
from dynenv_ros.learning.run.metrics import RunLogger, as_logged, plot_curves
from dynenv_ros.learning.sampling.worlds import make_worlds, soccer_config, teacher_driven_share

@dataclass
class Experience:
    """What one update learns from: a rollout (possibly several workers' joined), the env steps in it, the episodes
    that finished while it was collected, and scalars to log about it (averaged, or the maximum for ``*_max``)."""
    rollout: Rollout
    env_steps: int
    finished: list[dict[str, float]]
    scalars: dict[str, float] = field(default_factory=dict)


class Trainer:
    def __init__(self, cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True) -> None:
        self.cfg, self.run_dir, self.progress = cfg, Path(run_dir), progress
        self.run_dir.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(cfg.torch_threads)
        self.device = torch.device(cfg.device)
        self.settings = update_settings(cfg)
        self.soccer = soccer_config(cfg)
        seeds = np.random.SeedSequence(cfg.seed).spawn(4)
        self.generator = torch.Generator().manual_seed(int(seeds[0].generate_state(1)[0]))
        self.rng = np.random.default_rng(seeds[1])
        self.env_seed = int(seeds[2].generate_state(1)[0])
        torch.manual_seed(int(seeds[3].generate_state(1)[0]))   # parameter init only; no global RNG use after this
        agent = make_agent(cfg)
        self.learner = Learner(agent, cfg.ltp_horizon).to(self.device)
        # fused: one kernel over all 200-odd parameter tensors (CPU and CUDA) — 8x cheaper than the per-tensor loop
        self.optimizer = torch.optim.Adam(self.learner.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps,
                                          fused=self.device.type in ("cpu", "cuda"))
        self.env_steps = self.updates = self.episodes = 0
        self.wall_before = 0.0
        self._earlier_compute: list[dict[str, Any]] = []
        if cfg.torch_compile:
            compiled.compile_hot_paths()
        if resume:
            self._resume()
        elif cfg.pretrained_encoder:
            self._load_encoder(cfg.pretrained_encoder)
        elif cfg.init_policy:
            self._load_init_policy(cfg.init_policy)
        self.compute = ComputeMeter(self.env_steps, self._earlier_compute)
        self.best_policy = None
        if cfg.best_policy_window is not None:
            self.best_policy = (BestPolicy.resume(self.run_dir, cfg.best_policy_window, self.env_steps) if resume
                                else BestPolicy(cfg.best_policy_window))
        (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        self._start_rollouts()
        self.logger = RunLogger(self.run_dir)

    def _start_rollouts(self) -> None:
        """The worlds, the opponent and the collector (this process's; the asynchronous runner starts workers)."""
        worlds = make_worlds(self.cfg, self.learner, self.cfg.num_envs, self.cfg.backend, self.generator, self.rng,
                             seed=self.env_seed + self.updates)
        self.env, self.opponent, self.collector = worlds.env, worlds.opponent, worlds.collector
        self.layout_shapes = {k: list(v) for k, v in self.env.layout.shapes().items()}

    # -- checkpoints ------------------------------------------------------------------------------------------
    def _meta(self) -> dict[str, Any]:
        return {"version": checkpoints.META_VERSION, "config": self.cfg.to_dict(), "variant": self.cfg.variant,
                "algorithm": self.cfg.algorithm, "env_steps": self.env_steps, "updates": self.updates,
                "episodes": self.episodes, "wall_seconds": self.wall_before + self._elapsed(),
                "observation_layout": self.layout_shapes,
                "numpy_rng": self.rng.bit_generator.state, "code_revision": checkpoints.code_revision(),
                "compute": self.compute.record(self.env_steps)}

    def _policy_meta(self) -> dict[str, Any]:
        """What a policy file carries of the run (the checkpoint's meta less the generator state)."""
        return {k: v for k, v in self._meta().items() if k != "numpy_rng"}

    def save_checkpoint(self) -> Path:
        extra = {"torch_generator": self.generator.get_state()}
        return checkpoints.save_training_checkpoint(self.run_dir, self.env_steps, self.learner, self.optimizer,
                                                    self._meta(), extra, keep=self.cfg.keep_checkpoints)

    def _resume(self) -> None:
        meta, extra = checkpoints.load_training_checkpoint(self.run_dir, self.learner, self.optimizer)
        self.env_steps, self.updates = int(meta["env_steps"]), int(meta["updates"])
        self.episodes, self.wall_before = int(meta.get("episodes", 0)), float(meta.get("wall_seconds", 0.0))
        self.rng.bit_generator.state = meta["numpy_rng"]
        self._earlier_compute = list(meta.get("compute", {}).get("segments", []))
        if "torch_generator" in extra:
            self.generator.set_state(extra["torch_generator"])

    def _load_encoder(self, path: str) -> None:
        """The localization and object streams (and reconstruction head) of a pretrained policy file."""
        pretrained, _ = checkpoints.load_policy(path)
        if getattr(pretrained, "uses_pose", False) != self.learner.agent.uses_pose:
            raise ValueError(f"pretrained encoder {path} {'takes' if pretrained.uses_pose else 'does not take'} the "
                             f"pose estimate and this run's agent (localization: {self.cfg.localization}) "
                             f"{'does' if self.learner.agent.uses_pose else 'does not'}: the streams' inputs differ")
        wanted = ("localization.", "pose_head.", "objects.", "reconstruction.")
        state = {k: v for k, v in pretrained.state_dict().items() if k.startswith(wanted)}
        missing = self.learner.agent.load_state_dict(state, strict=False)
        if missing.unexpected_keys:
            raise ValueError(f"pretrained encoder {path} has unexpected keys, e.g. {missing.unexpected_keys[0]}")

    def _load_init_policy(self, path: str) -> None:
        """Every network from a policy file (``init_policy``); it must fit this run's agent exactly."""
        from dynenv_ros.agent.checkpoint import check_state_dict_fits
        policy, _ = checkpoints.load_policy(path)
        check_state_dict_fits(self.learner.agent, policy.state_dict(), f"init_policy {path}")
        self.learner.agent.load_state_dict(policy.state_dict())

    # -- the loop ---------------------------------------------------------------------------------------------
    def _elapsed(self) -> float:
        return time.perf_counter() - self._started

    def run(self) -> dict[str, Any]:
        """Train until total_env_steps or max_minutes, then ``finish``. A write that fails (a full or read-only disk:
        OSError) stops the run cleanly: ``stop_reason`` in the summary, the last checkpoint left as it was (they are
        written atomically), nothing more written."""
        try:
            return self._run()
        except OSError as error:
            return self._write_failed(error)

    def _write_failed(self, error: OSError) -> dict[str, Any]:
        from dynenv_ros.core.writable import describe_os_error
        where = f" ({error.filename})" if getattr(error, "filename", None) else ""
        self.stop_reason = f"cannot write to {self.run_dir}: {describe_os_error(error)}{where}; the last " \
                           f"checkpoint is kept (dynenv-train --resume {self.run_dir} once there is room)"
        for close in (getattr(getattr(self, "logger", None), "close", None), self._stop_rollouts):
            try:
                if close is not None:
                    close()
            except Exception:       # noqa: BLE001 - best effort on the way out; the reason is already known
                pass
        summary = self._summary()
        summary["stop_reason"] = self.stop_reason
        return summary

    def _run(self) -> dict[str, Any]:
        cfg = self.cfg
        self._started = time.perf_counter()
        deadline = math.inf if cfg.max_minutes is None else cfg.max_minutes * 60.0
        if not checkpoints.list_checkpoints(self.run_dir):
            self.save_checkpoint()      # the first one at once: a kill from now on leaves a run to --resume
        last_checkpoint = time.perf_counter()
        window = self._new_window()
        returns: list[dict[str, float]] = []
        bar = None
        if self.progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.total_env_steps, initial=self.env_steps, unit="step", dynamic_ncols=True,
                       desc=f"{cfg.algorithm}/{cfg.variant}")
        stats: dict[str, float] = {}
        try:
            while self.env_steps < cfg.total_env_steps and self._elapsed() < deadline:
                t0 = time.perf_counter()
                batch = self._experience(deadline)
                if batch is None:           # (the asynchronous runner: the deadline passed while it waited)
                    break
                t1 = time.perf_counter()
                self.learner.train()
                self.settings.imitation_coef = cfg.imitation_weight(self.env_steps)
                stats = update(self.learner, self.optimizer, batch.rollout.as_tensors(self.device), self.settings,
                               self.generator)
                if cfg.teacher is not None:
                    stats["imitation_coef"] = self.settings.imitation_coef
                t2 = time.perf_counter()
                self.env_steps += batch.env_steps
                self.updates += 1
                self._learned(batch)
                window["steps"] += batch.env_steps
                window["updates"] += 1
                window["rollout"] += t1 - t0
                window["learn"] += t2 - t1
                for key, value in batch.scalars.items():
                    window["extra"].setdefault(key, []).append(value)
                self.episodes += len(batch.finished)
                returns.extend(batch.finished)
                if bar is not None:
                    bar.update(batch.env_steps)
                if self.updates % cfg.log_every_updates == 0:
                    self._log(stats, window, returns, bar)
                    returns = []
                    window = self._new_window()
                if time.perf_counter() - last_checkpoint > cfg.checkpoint_every_minutes * 60.0:
                    self.save_checkpoint()
                    last_checkpoint = time.perf_counter()
            if window["updates"]:           # the updates since the last log line
                self._log(stats, window, returns, bar)
        finally:
            if bar is not None:
                bar.close()
        return self.finish()

    @staticmethod
    def _new_window() -> dict[str, Any]:
        return {"steps": 0, "updates": 0, "time": time.perf_counter(), "rollout": 0.0, "learn": 0.0, "extra": {}}

    def _experience(self, deadline: float) -> Experience | None:
        """The next rollout to learn from: collected here, by the current policy."""
        self.learner.eval()
        self.collector.drive_with_teacher(self._teacher_driven_worlds())
        rollout = self.collector.collect(self.cfg.rollout_length)
        finished, self.collector.finished = self.collector.finished, []
        return Experience(rollout, self.cfg.num_envs * self.cfg.rollout_length, finished, self.env.league_stats())

    def _learned(self, batch: Experience) -> None:
        """After each update: a snapshot opponent takes its copy every ``snapshot_every_updates``."""
        if self.opponent is not None and self.cfg.opponent in ("snapshot", "league") \
                and self.updates % self.cfg.snapshot_every_updates == 0:
            self.opponent.refresh(self.learner.agent)

    def _teacher_driven_worlds(self) -> int:
        return teacher_driven_share(self.cfg, self.env_steps, 0, self.cfg.num_envs)

    # the window's time before each update: collecting (sync) or waiting for the workers (async)
    wait_scalar = "speed/rollout_seconds_per_update"

    def _log(self, stats: dict[str, float], window: dict[str, Any], returns: list[dict[str, float]],
             bar: Any) -> None:
        updates = max(window["updates"], 1)
        elapsed = max(time.perf_counter() - window["time"], 1e-9)
        scalars = {f"train/{k}": v for k, v in stats.items()}
        scalars["speed/env_steps_per_second"] = window["steps"] / elapsed
        scalars[self.wait_scalar] = window["rollout"] / updates
        scalars["speed/learn_seconds_per_update"] = window["learn"] / updates
        for key, values in window["extra"].items():
            scalars[key] = float(np.max(values)) if key.endswith("_max") else float(np.mean(values))
        if returns:
            for key in returns[0]:
                scalars[f"episode/{key}"] = float(np.mean([r[key] for r in returns]))
        self.logger.log(self.env_steps, self.updates, self.wall_before + self._elapsed(), scalars)
        self.compute.sample_load()
        if self.best_policy is not None and "episode/return" in scalars:
            # the value as metrics.csv holds it, so the peak is where training-best finds it
            average = self.best_policy.observe(as_logged(scalars["episode/return"]))
            if average is not None:         # the curve's new peak: keep this policy
                self.best_policy.save(self.run_dir, self.learner.agent, self._policy_meta(), average)
        if bar is not None:
            postfix = {"sps": f"{scalars['speed/env_steps_per_second']:.0f}"}
            if returns:
                postfix["return"] = f"{scalars['episode/return']:.2f}"
            bar.set_postfix(postfix)

    def finish(self) -> dict[str, Any]:
        """Final checkpoint, the shipped policy (safetensors + ONNX), curves and a summary."""
        self.save_checkpoint()
        agent = self.learner.agent
        checkpoints.save_policy(agent, str(self.run_dir / "policy.safetensors"), self._policy_meta())
        from dynenv_ros.agent.export import export_onnx
        compiled.restore()                  # the exporter traces the eager functions
        export_onnx(agent.cpu(), self.run_dir / "policy.onnx")
        agent.to(self.device)
        self.logger.close()
        plot_curves(self.run_dir)
        summary = self._summary()
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        self._stop_rollouts()
        return summary

    def _summary(self) -> dict[str, Any]:
        summary = {"env_steps": self.env_steps, "updates": self.updates, "episodes": self.episodes,
                   "wall_seconds": self.wall_before + self._elapsed(), "compute": self.compute.record(self.env_steps)}
        if self.cfg.init_policy:
            summary["init_policy_sha256"] = checkpoints.sha256(self.cfg.init_policy)
        return summary

    def _stop_rollouts(self) -> None:
        self.env.close()

