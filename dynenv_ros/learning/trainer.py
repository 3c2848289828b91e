"""The in-process trainer: the vectorised soccer batch, the agent, PPO or A2C with the paper's auxiliary losses,
logging, atomic checkpoints and resumption — no ROS. ``dynenv-train`` (``train_cli``) runs it; the trainer node
reuses its pieces (``RolloutCollector``, ``update``, ``checkpoints``).

A run directory holds: ``config.json`` (the resolved config), ``metrics.csv`` and ``tensorboard/`` (every scalar),
``checkpoints/`` (the last few, safetensors + JSON, see ``checkpoints``), and at the end ``policy.safetensors``,
``policy.onnx``, ``curves.png`` and ``summary.json``. Resuming (``--resume RUN_DIR``) restores the networks, the
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
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dynenv_ros.envs.vector import DrivingVectorEnv, SoccerVectorEnv
from dynenv_ros.learning import checkpoints
from dynenv_ros.learning.agents import make_agent
from dynenv_ros.learning.algorithms import UpdateSettings, update
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.heads import Learner
from dynenv_ros.learning.opponents import SCRIPTED_TEAM, RandomOpponent, SnapshotOpponent, WorldScriptedOpponent
from dynenv_ros.learning.rollout import RolloutCollector
from dynenv_ros.learning.run_log import RunLogger, plot_curves
from dynenv_ros.soccer.config import SoccerConfig

VERSION = "dynenv_ros.learning/1"
# DynEnv's privileged seeding noise: N(0, 0.05²) in its normalised units (1 unit = 5.2 m) on x, y; 0.05 on the
# unit-vector components of the pose (facts §9.6).
SEED_NOISE = np.array([0.26, 0.26, 0.05, 0.05, 0.05, 0.05], np.float32)


def update_settings(cfg: TrainConfig) -> UpdateSettings:
    """The variant's loss switches and the config's numbers, in the form ``update`` takes. ``use_forward`` is on
    for ICM's plain forward model *and* RCM's attention-weighted one (``use_rcm`` picks the weighting): ``update``
    adds the forward loss only under ``use_forward``."""
    losses = cfg.losses()
    ppo = cfg.algorithm == "ppo"
    return UpdateSettings(
        algorithm=cfg.algorithm, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda,
        epochs=cfg.ppo_epochs if ppo else 1, minibatches=cfg.ppo_minibatches if ppo else 1, clip=cfg.ppo_clip,
        clip_value_loss=cfg.clip_value_loss, normalize_advantages=cfg.normalize_advantages,
        target_kl=cfg.target_kl, value_coef=cfg.value_coef, entropy_coef=cfg.entropy_coef,
        max_grad_norm=cfg.max_grad_norm, forward_coef=cfg.forward_coef, inverse_coef=cfg.inverse_coef,
        ltp_coef=cfg.ltp_coef, self_supervised_coef=cfg.self_supervised_coef,
        use_forward=losses.forward, use_rcm=losses.rcm_attention, use_inverse=losses.inverse, use_ltp=losses.ltp,
        use_localization=losses.localization, use_reconstruction=losses.reconstruction,
        intrinsic_reward_coef=cfg.intrinsic_reward_coef, imitation_coef=cfg.imitation_weight(0))


class Trainer:
    def __init__(self, cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True) -> None:
        self.cfg, self.run_dir, self.progress = cfg, Path(run_dir), progress
        self.run_dir.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(cfg.torch_threads)
        self.device = torch.device(cfg.device)
        self.settings = update_settings(cfg)
        soccer = SoccerConfig.from_mapping({"players_per_team": cfg.players_per_team, "head_mode": cfg.head_mode})
        self.soccer = soccer
        seeds = np.random.SeedSequence(cfg.seed).spawn(4)
        self.generator = torch.Generator().manual_seed(int(seeds[0].generate_state(1)[0]))
        self.rng = np.random.default_rng(seeds[1])
        self.env_seed = int(seeds[2].generate_state(1)[0])
        agent = make_agent(cfg)
        torch.manual_seed(int(seeds[3].generate_state(1)[0]))   # parameter init only; no global RNG use after this
        self.learner = Learner(agent, cfg.ltp_horizon).to(self.device)
        # fused: one kernel over all 200-odd parameter tensors (CPU and CUDA) — 8x cheaper than the per-tensor loop
        self.optimizer = torch.optim.Adam(self.learner.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps,
                                          fused=self.device.type in ("cpu", "cuda"))
        self.env_steps = self.updates = self.episodes = 0
        self.wall_before = 0.0
        if resume:
            self._resume()
        elif cfg.pretrained_encoder:
            self._load_encoder(cfg.pretrained_encoder)
        (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        needs_targets = self.settings.use_localization or self.settings.use_reconstruction \
            or cfg.privileged_pose_seeding
        if cfg.driving:
            self.env: Any = DrivingVectorEnv(cfg.num_envs, backend=cfg.backend, observation="padded",
                                             config={"n_cars": cfg.n_cars, "action_mode": cfg.action_mode},
                                             perception=cfg.perception, teacher=cfg.teacher)
            agent.layout_spec = self.env.layout.spec
            learning = np.arange(cfg.n_cars)
        else:
            self.env = SoccerVectorEnv(cfg.num_envs, backend=cfg.backend, config=soccer, observation="padded",
                                       perception=cfg.perception, targets=needs_targets,
                                       scripted_team_b=SCRIPTED_TEAM if cfg.opponent == "scripted" else None,
                                       teacher=cfg.teacher)
            n = cfg.players_per_team
            learning = np.arange(2 * n) if cfg.opponent == "self" else np.arange(n)
        self.opponent: Any = None
        if cfg.opponent == "random":
            self.opponent = RandomOpponent(self.rng, 2 * soccer.motion.head_units + 1)
        elif cfg.opponent == "snapshot":
            self.opponent = SnapshotOpponent(agent, cfg.snapshot_pool, self.generator, self.rng)
        elif cfg.opponent == "scripted":
            self.opponent = WorldScriptedOpponent()
        seeding: dict[str, Any] = {}
        if cfg.privileged_pose_seeding:
            seeding = {"pose_seeder": self.learner.seeded_state, "seed_noise": SEED_NOISE, "rng": self.rng}
        self.collector = RolloutCollector(self.env, agent, learning, self.opponent, self.generator,
                                          seed=self.env_seed + self.updates, **seeding)
        self.logger = RunLogger(self.run_dir)

    # -- checkpoints ------------------------------------------------------------------------------------------
    def _meta(self) -> dict[str, Any]:
        return {"version": VERSION, "config": self.cfg.to_dict(), "variant": self.cfg.variant,
                "algorithm": self.cfg.algorithm, "env_steps": self.env_steps, "updates": self.updates,
                "episodes": self.episodes, "wall_seconds": self.wall_before + self._elapsed(),
                "observation_layout": {k: list(v) for k, v in self.env.layout.shapes().items()},
                "numpy_rng": self.rng.bit_generator.state, "code_revision": checkpoints.code_revision()}

    def save_checkpoint(self) -> Path:
        extra = {"torch_generator": self.generator.get_state()}
        return checkpoints.save_training_checkpoint(self.run_dir, self.env_steps, self.learner, self.optimizer,
                                                    self._meta(), extra, keep=self.cfg.keep_checkpoints)

    def _resume(self) -> None:
        meta, extra = checkpoints.load_training_checkpoint(self.run_dir, self.learner, self.optimizer)
        self.env_steps, self.updates = int(meta["env_steps"]), int(meta["updates"])
        self.episodes, self.wall_before = int(meta.get("episodes", 0)), float(meta.get("wall_seconds", 0.0))
        self.rng.bit_generator.state = meta["numpy_rng"]
        if "torch_generator" in extra:
            self.generator.set_state(extra["torch_generator"])

    def _load_encoder(self, path: str) -> None:
        """The localization and object streams (and reconstruction head) of a pretrained policy file."""
        pretrained, _ = checkpoints.load_policy(path)
        wanted = ("localization.", "pose_head.", "objects.", "reconstruction.")
        state = {k: v for k, v in pretrained.state_dict().items() if k.startswith(wanted)}
        missing = self.learner.agent.load_state_dict(state, strict=False)
        if missing.unexpected_keys:
            raise ValueError(f"pretrained encoder {path} has unexpected keys, e.g. {missing.unexpected_keys[0]}")

    # -- the loop ---------------------------------------------------------------------------------------------
    def _elapsed(self) -> float:
        return time.perf_counter() - self._started

    def run(self) -> dict[str, Any]:
        cfg = self.cfg
        self._started = time.perf_counter()
        per_update = cfg.num_envs * cfg.rollout_length
        deadline = math.inf if cfg.max_minutes is None else cfg.max_minutes * 60.0
        last_checkpoint = time.perf_counter()
        window = {"steps": 0, "time": time.perf_counter(), "rollout": 0.0, "learn": 0.0}
        returns: list[dict[str, float]] = []
        bar = None
        if self.progress:
            from tqdm import tqdm
            bar = tqdm(total=cfg.total_env_steps, initial=self.env_steps, unit="step", dynamic_ncols=True,
                       desc=f"{cfg.algorithm}/{cfg.variant}")
        try:
            while self.env_steps < cfg.total_env_steps and self._elapsed() < deadline:
                t0 = time.perf_counter()
                self.learner.eval()
                self.collector.drive_with_teacher(self._teacher_driven_worlds())
                rollout = self.collector.collect(cfg.rollout_length)
                t1 = time.perf_counter()
                self.learner.train()
                self.settings.imitation_coef = cfg.imitation_weight(self.env_steps)
                stats = update(self.learner, self.optimizer, rollout.as_tensors(self.device), self.settings,
                               self.generator)
                if cfg.teacher is not None:
                    stats["imitation_coef"] = self.settings.imitation_coef
                t2 = time.perf_counter()
                self.env_steps += per_update
                self.updates += 1
                window["steps"] += per_update
                window["rollout"] += t1 - t0
                window["learn"] += t2 - t1
                finished, self.collector.finished = self.collector.finished, []
                self.episodes += len(finished)
                returns.extend(finished)
                if self.opponent is not None and cfg.opponent == "snapshot" \
                        and self.updates % cfg.snapshot_every_updates == 0:
                    self.opponent.refresh(self.learner.agent)
                if bar is not None:
                    bar.update(per_update)
                if self.updates % cfg.log_every_updates == 0:
                    self._log(stats, window, returns, bar)
                    returns = []
                    window = {"steps": 0, "time": time.perf_counter(), "rollout": 0.0, "learn": 0.0}
                if time.perf_counter() - last_checkpoint > cfg.checkpoint_every_minutes * 60.0:
                    self.save_checkpoint()
                    last_checkpoint = time.perf_counter()
            if window["steps"]:             # the updates since the last log line
                self._log(stats, window, returns, bar, updates=window["steps"] // per_update)
        finally:
            if bar is not None:
                bar.close()
        return self.finish()

    def _teacher_driven_worlds(self) -> int:
        cfg = self.cfg
        done = cfg.teacher_driven_env_steps and self.env_steps >= cfg.teacher_driven_env_steps
        return 0 if done else cfg.teacher_driven_worlds

    def _log(self, stats: dict[str, float], window: dict[str, float], returns: list[dict[str, float]],
             bar: Any, updates: int | None = None) -> None:
        updates = updates or self.cfg.log_every_updates
        elapsed = max(time.perf_counter() - window["time"], 1e-9)
        scalars = {f"train/{k}": v for k, v in stats.items()}
        scalars["speed/env_steps_per_second"] = window["steps"] / elapsed
        scalars["speed/rollout_seconds_per_update"] = window["rollout"] / updates
        scalars["speed/learn_seconds_per_update"] = window["learn"] / updates
        if returns:
            for key in returns[0]:
                scalars[f"episode/{key}"] = float(np.mean([r[key] for r in returns]))
        self.logger.log(self.env_steps, self.updates, self.wall_before + self._elapsed(), scalars)
        if bar is not None:
            postfix = {"sps": f"{scalars['speed/env_steps_per_second']:.0f}"}
            if returns:
                postfix["return"] = f"{scalars['episode/return']:.2f}"
            bar.set_postfix(postfix)

    def finish(self) -> dict[str, Any]:
        """Final checkpoint, the shipped policy (safetensors + ONNX), curves and a summary."""
        self.save_checkpoint()
        meta = {k: v for k, v in self._meta().items() if k != "numpy_rng"}
        agent = self.learner.agent
        checkpoints.save_policy(agent, str(self.run_dir / "policy.safetensors"), meta)
        from dynenv_ros.agent.export import export_onnx
        export_onnx(agent.cpu(), self.run_dir / "policy.onnx")
        agent.to(self.device)
        self.logger.close()
        plot_curves(self.run_dir)
        summary = {"env_steps": self.env_steps, "updates": self.updates, "episodes": self.episodes,
                   "wall_seconds": self.wall_before + self._elapsed()}
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        self.env.close()
        return summary
