"""The trainer of ``dynenv-train``: the agent, PPO or A2C with the paper's auxiliary losses (``algo``), experience
from this process's worlds (``runner: sync``, ``sampling.in_process``) or from rollout workers (``runner: async``,
``distributed.pool_source``: processes or Ray actors), the one training loop (``algo.loop``), logging, atomic
checkpoints and resumption — no ROS. The trainer node learns from messages with the same pieces
(``messages.message_trainer``).

A run directory holds: ``config.json`` (the resolved config), ``metrics.csv`` and ``tensorboard/`` (every scalar),
``checkpoints/`` (the last few, safetensors + JSON, see ``checkpoints``), and at the end ``policy.safetensors``,
``policy.onnx``, ``curves.png`` and ``summary.json`` (with ``best_policy_window``, also ``best_policy.safetensors``:
``learning.run.best_policy``; with ``keep_policy_every_env_steps``, ``kept_policies/``:
``learning.run.kept_policies``). Resuming (``--resume RUN_DIR``) restores the networks, the optimiser, the step
counters, the random generators and a league run's league scores from the latest checkpoint; the worlds restart with fresh episodes seeded from
(seed, update), since a world's physics state is not checkpointed — an episode cut by a kill is simply not counted.

``scenario: driving``: the driving agent (``DynEnvAgent(scenario='driving', action_mode)``) on ``DrivingVectorEnv``
with ``n_cars`` cars per world, every car learning (no opponent); the same run directory. Episode scalars are per
car: return, its terms, ``home`` and ``crashed`` (fractions of finished car-episodes).
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from dynenv_ros.learning.algo import compiled
from dynenv_ros.learning.algo.experience import Experience, Progress
from dynenv_ros.learning.algo.loop import train
from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.algo.ppo import update, update_settings
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.distributed.pool_source import PoolSource
from dynenv_ros.learning.distributed.worker_pool import WorkerPoolError
from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.run.best_policy import BestPolicy
from dynenv_ros.learning.run.kept_policies import KeptPolicies
from dynenv_ros.learning.run.snapshot_history import SnapshotHistory
from dynenv_ros.learning.run.compute import ComputeMeter
from dynenv_ros.learning.run.metrics import RunLogger, as_logged, plot_curves
from dynenv_ros.learning.sampling.in_process import InProcessSource
from dynenv_ros.learning.sampling.worlds import make_env


class Trainer:
    """One run of ``cfg`` in ``run_dir``: ``run`` trains until ``total_env_steps`` or ``max_minutes`` and finishes
    (``finish``). ``progress``: a progress bar on stderr; ``log``: where the workers' one-line reports go (async)."""

    def __init__(self, cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True,
                 log: Callable[[str], None] | None = None) -> None:
        self.cfg, self.run_dir, self.progress_bar = cfg, Path(run_dir), progress
        self._log_line = log or (lambda line: print(f"dynenv-train: {line}", file=sys.stderr, flush=True))
        self.run_dir.mkdir(parents=True, exist_ok=True)
        torch.set_num_threads(cfg.torch_threads)
        self.device = torch.device(cfg.device)
        self.settings = update_settings(cfg)
        seeds = np.random.SeedSequence(cfg.seed).spawn(4)
        self.generator = torch.Generator().manual_seed(int(seeds[0].generate_state(1)[0]))
        self.rng = np.random.default_rng(seeds[1])
        self.env_seed = int(seeds[2].generate_state(1)[0])
        torch.manual_seed(int(seeds[3].generate_state(1)[0]))   # parameter init only; no global RNG use after this
        agent = make_agent(cfg)
        self.networks = TrainingNetworks(agent, cfg.ltp_horizon).to(self.device)
        # fused: one kernel over all 200-odd parameter tensors (CPU and CUDA) — 8x cheaper than the per-tensor loop
        self.optimizer = torch.optim.Adam(self.networks.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps,
                                          fused=self.device.type in ("cpu", "cuda"))
        self.progress = Progress()
        self.wall_before = 0.0
        self.stop_reason = ""
        self._started = time.perf_counter()
        self._earlier_compute: list[dict[str, Any]] = []
        self._league_states: dict[int, dict[str, Any]] = {}        # a resumed league run's, by worker
        self._async_counts: dict[str, int] = {}                    # a resumed async run's, before this segment
        if cfg.torch_compile:
            compiled.compile_hot_paths()
        if resume:
            self._resume()
        elif cfg.pretrained_encoder:
            self._load_encoder(cfg.pretrained_encoder)
        elif cfg.init_policy:
            self._load_init_policy(cfg.init_policy)
        self.compute = ComputeMeter(self.progress.env_steps, self._earlier_compute)
        self.best_policy = None
        if cfg.best_policy_window is not None:
            self.best_policy = (BestPolicy.resume(self.run_dir, cfg.best_policy_window, self.progress.env_steps)
                                if resume else BestPolicy(cfg.best_policy_window))
        self.kept_policies = (KeptPolicies(cfg.keep_policy_every_env_steps, self.progress.env_steps)
                              if cfg.keep_policy_every_env_steps is not None else None)
        # the snapshot opponent's pool as the worlds hold it, checkpointed (run.snapshot_history)
        self.snapshots: SnapshotHistory | None = None
        if cfg.opponent in ("snapshot", "league"):
            self.snapshots = (SnapshotHistory.from_checkpoint(self._resume_extra, cfg.snapshot_every_updates,
                                                              cfg.snapshot_pool, self.networks.agent)
                              if resume else SnapshotHistory(cfg.snapshot_every_updates, cfg.snapshot_pool))
            if not self.snapshots.states:       # a fresh run, or a checkpoint from before the pool was kept
                self.snapshots.take(self.networks.agent)
        (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        self.source: InProcessSource | PoolSource
        # a resumed run's worlds start in the curriculum stage its env steps are in (the checkpoint's: _resume)
        if cfg.runner == "async":
            self.source = PoolSource(cfg, self.networks, self.progress.updates, self.device, self._log_line,
                                     first_env_steps=self.progress.env_steps, league_states=self._league_states,
                                     earlier_counts=self._async_counts, snapshots=self.snapshots)
        else:       # the worlds restart with fresh episodes seeded from (seed, update)
            self.source = InProcessSource(cfg, self.networks, self.generator, self.rng,
                                          self.env_seed + self.progress.updates, self.device,
                                          env_steps=self.progress.env_steps,
                                          league_state=next(iter(self._league_states.values()), None),
                                          log=self._log_line,
                                          snapshot_states=self.snapshots.states if self.snapshots else None)
        self.layout_shapes = self.source.layout_shapes    # async: known once a worker said hello
        self.logger = RunLogger(self.run_dir)

    # -- checkpoints ------------------------------------------------------------------------------------------
    def _meta(self) -> dict[str, Any]:
        meta = {"version": checkpoints.META_VERSION, "config": self.cfg.to_dict(), "variant": self.cfg.variant,
                "algorithm": self.cfg.algorithm, "env_steps": self.progress.env_steps,
                "updates": self.progress.updates, "episodes": self.progress.episodes,
                "wall_seconds": self.wall_before + self._elapsed(), "observation_layout": self.layout_shapes,
                "numpy_rng": self.rng.bit_generator.state, "code_revision": checkpoints.code_revision(),
                "compute": self.compute.record(self.progress.env_steps)}
        if self.cfg.curriculum:             # the stage the run's worlds were in (docs/training.md, curriculum)
            meta["curriculum_stage"] = self.cfg.curriculum_stage(self.progress.env_steps)
        leagues = self.source.league_states if hasattr(self, "source") else self._league_states
        if leagues:                         # a league run: each worker's league, carried on by --resume
            meta["league"] = {str(worker): state for worker, state in sorted(leagues.items())}
        counts = getattr(self.source, "counts", None) if hasattr(self, "source") else None
        if counts is not None:              # async: the summary's counts go on across --resume
            meta["async_counts"] = counts()
        return meta

    def _policy_meta(self) -> dict[str, Any]:
        """What a policy file carries of the run (the checkpoint's meta less the generator state)."""
        return checkpoints.policy_meta(self._meta())

    def save_checkpoint(self) -> Path:
        extra = {"torch_generator": self.generator.get_state()}
        if getattr(self, "snapshots", None) is not None:
            extra.update(self.snapshots.tensors())
        return checkpoints.save_training_checkpoint(self.run_dir, self.progress.env_steps, self.networks,
                                                    self.optimizer, self._meta(), extra,
                                                    keep=self.cfg.keep_checkpoints)

    def _resume(self) -> None:
        meta, extra = checkpoints.load_training_checkpoint(self.run_dir, self.networks, self.optimizer)
        self._resume_extra = extra
        self.progress = Progress(int(meta["env_steps"]), int(meta["updates"]), int(meta.get("episodes", 0)))
        self.wall_before = float(meta.get("wall_seconds", 0.0))
        self.rng.bit_generator.state = meta["numpy_rng"]
        self._earlier_compute = list(meta.get("compute", {}).get("segments", []))
        self._league_states = self._checkpoint_leagues(meta.get("league"))
        saved_counts = meta.get("async_counts")
        if isinstance(saved_counts, dict):
            self._async_counts = {k: int(v) for k, v in saved_counts.items()
                                  if isinstance(v, int) and not isinstance(v, bool) and v >= 0}
        if "torch_generator" in extra:
            self.generator.set_state(extra["torch_generator"])
        if self.cfg.curriculum:
            self._resume_curriculum(meta.get("curriculum_stage"))

    def _checkpoint_leagues(self, saved: Any) -> dict[int, dict[str, Any]]:
        """The checkpoint's leagues by worker (none before they were checkpointed, or when the run is no league:
        then the league starts again from even scores, as it always did)."""
        if not saved or self.cfg.opponent != "league":
            return {}
        if not isinstance(saved, dict) or not all(str(k).isdigit() and isinstance(v, dict) for k, v in saved.items()):
            raise ValueError(f"checkpoint of {self.run_dir}: its league entry is not worker -> league state")
        from dynenv_ros.envs.league import LEAGUE_MEMBERS, League
        for worker, state in saved.items():        # a misfit stops the resume here, not in every worker
            try:
                League(self.cfg.league_members or LEAGUE_MEMBERS, np.random.default_rng(0)).restore(state)
            except ValueError as error:
                raise ValueError(f"checkpoint of {self.run_dir}: worker {worker}'s league: {error}") from None
        self._log_line(f"resuming the league of {len(saved)} worker(s) from the checkpoint")
        return {int(k): v for k, v in saved.items()}

    def _resume_curriculum(self, saved: Any) -> None:
        """Say which curriculum stage the resumed run goes on in: the checkpoint's, which its env steps give again,
        unless the curriculum was changed (``--set curriculum=...``): then the new one's at those env steps."""
        stage = self.cfg.curriculum_stage(self.progress.env_steps)
        last = len(self.cfg.curriculum or ()) - 1
        if saved is None or int(saved) == stage:
            self._log_line(f"resuming at {self.progress.env_steps} env steps in curriculum stage {stage} (of 0..{last})")
        else:
            self._log_line(f"the checkpoint was in curriculum stage {saved}; this run's curriculum puts "
                           f"{self.progress.env_steps} env steps in stage {stage} (of 0..{last}): going on there")

    def _load_encoder(self, path: str) -> None:
        """The localization and object streams (and reconstruction head) of a pretrained policy file."""
        pretrained, _ = checkpoints.load_policy(path)
        if getattr(pretrained, "uses_pose", False) != self.networks.agent.uses_pose:
            raise ValueError(f"pretrained encoder {path} {'takes' if pretrained.uses_pose else 'does not take'} the "
                             f"pose estimate and this run's agent (localization: {self.cfg.localization}) "
                             f"{'does' if self.networks.agent.uses_pose else 'does not'}: the streams' inputs differ")
        wanted = ("localization.", "pose_head.", "objects.", "reconstruction.")
        state = {k: v for k, v in pretrained.state_dict().items() if k.startswith(wanted)}
        missing = self.networks.agent.load_state_dict(state, strict=False)
        if missing.unexpected_keys:
            raise ValueError(f"pretrained encoder {path} has unexpected keys, e.g. {missing.unexpected_keys[0]}")

    def _load_init_policy(self, path: str) -> None:
        """Every network from a policy file (``init_policy``); it must fit this run's agent exactly."""
        from dynenv_ros.agent.checkpoint import check_state_dict_fits
        policy, _ = checkpoints.load_policy(path)
        check_state_dict_fits(self.networks.agent, policy.state_dict(), f"init_policy {path}")
        self.networks.agent.load_state_dict(policy.state_dict())

    # -- the loop ---------------------------------------------------------------------------------------------
    def _elapsed(self) -> float:
        return time.perf_counter() - self._started

    def run(self) -> dict[str, Any]:
        """Train until total_env_steps or max_minutes, then ``finish``. A write that fails (a full or read-only disk:
        OSError) stops the run cleanly: ``stop_reason`` in the summary, the last checkpoint left as it was (they are
        written atomically), nothing more written. Workers that cannot go on (``WorkerPoolError``) stop it with
        what was learnt kept (checkpoint, policy) and the reason in one line."""
        try:
            return self._run()
        except OSError as error:
            return self._write_failed(error)
        except WorkerPoolError as error:
            self._log_line(f"stopping: {error}")
            self.stop_reason = str(error)
            return self.finish()
        finally:
            self.close()

    def _write_failed(self, error: OSError) -> dict[str, Any]:
        from dynenv_ros.core.writable import describe_os_error
        where = f" ({error.filename})" if getattr(error, "filename", None) else ""
        self.stop_reason = f"cannot write to {self.run_dir}: {describe_os_error(error)}{where}; the last " \
                           f"checkpoint is kept (dynenv-train --resume {self.run_dir} once there is room)"
        for close in (getattr(getattr(self, "logger", None), "close", None), self.close):
            try:
                if close is not None:
                    close()
            except Exception:       # noqa: BLE001 - best effort on the way out; the reason is already known
                pass
        return self._summary()

    def _run(self) -> dict[str, Any]:
        cfg = self.cfg
        self._started = time.perf_counter()
        deadline = math.inf if cfg.max_minutes is None else self._started + cfg.max_minutes * 60.0
        if not checkpoints.list_checkpoints(self.run_dir):
            self.save_checkpoint()      # the first one at once: a kill from now on leaves a run to --resume
        self._last_checkpoint = time.perf_counter()
        self._window = self._new_window()
        self._returns: list[dict[str, float]] = []
        self._stats: dict[str, float] = {}
        self._bar = None
        if self.progress_bar:
            from tqdm import tqdm
            self._bar = tqdm(total=cfg.total_env_steps, initial=self.progress.env_steps, unit="step",
                             dynamic_ncols=True, desc=f"{cfg.algorithm}/{cfg.variant}")
        try:
            train(self.source, self.learn, self.progress, self._record,
                  until=lambda progress: progress.env_steps < cfg.total_env_steps, deadline=deadline)
            if self._window["updates"]:           # the updates since the last log line
                self._log(self._stats, self._window, self._returns, self._bar)
        finally:
            if self._bar is not None:
                self._bar.close()
        return self.finish()

    def learn(self, experience: Experience) -> dict[str, float]:
        """The algorithm's step: the update, with this run's imitation weight (``teacher``) at this step count."""
        self.networks.train()
        self.settings.imitation_coef = self.cfg.imitation_weight(self.progress.env_steps)
        stats = update(self.networks, self.optimizer, experience.batch, self.settings, self.generator)
        if self.cfg.teacher is not None:
            stats["imitation_coef"] = self.settings.imitation_coef
        return stats

    def _record(self, experience: Experience, stats: dict[str, float], waited: float, learnt: float) -> None:
        """After each update: the log window (a line every ``log_every_updates``), the progress bar and a checkpoint
        every ``checkpoint_every_minutes``."""
        if self.layout_shapes is None:
            self.layout_shapes = self.source.layout_shapes
        window = self._window
        window["steps"] += experience.env_steps
        window["updates"] += 1
        window["rollout"] += waited
        window["learn"] += learnt
        for key, value in experience.scalars.items():
            window["extra"].setdefault(key, []).append(value)
        self._returns.extend(experience.finished)
        self._stats = stats
        if self._bar is not None:
            self._bar.update(experience.env_steps)
        if self.progress.updates % self.cfg.log_every_updates == 0:
            self._log(stats, window, self._returns, self._bar)
            self._returns = []
            self._window = self._new_window()
        if self.snapshots is not None:
            self.snapshots.after_update(self.progress.updates, self.networks.agent)
        if self.kept_policies is not None:
            self.kept_policies.after_update(self.run_dir, self.progress.env_steps, self.networks.agent,
                                            self._policy_meta())
        if time.perf_counter() - self._last_checkpoint > self.cfg.checkpoint_every_minutes * 60.0:
            self.save_checkpoint()
            self._last_checkpoint = time.perf_counter()

    @staticmethod
    def _new_window() -> dict[str, Any]:
        return {"steps": 0, "updates": 0, "time": time.perf_counter(), "rollout": 0.0, "learn": 0.0, "extra": {}}

    def _log(self, stats: dict[str, float], window: dict[str, Any], returns: list[dict[str, float]],
             bar: Any) -> None:
        updates = max(window["updates"], 1)
        elapsed = max(time.perf_counter() - window["time"], 1e-9)
        scalars = {f"train/{k}": v for k, v in stats.items()}
        scalars["speed/env_steps_per_second"] = window["steps"] / elapsed
        scalars[self.source.wait_scalar] = window["rollout"] / updates
        scalars["speed/learn_seconds_per_update"] = window["learn"] / updates
        for key, values in window["extra"].items():
            scalars[key] = float(np.max(values)) if key.endswith("_max") else float(np.mean(values))
        if self.cfg.curriculum:             # the stage the worlds are told to start their next episodes in
            scalars["curriculum/stage"] = float(self.cfg.curriculum_stage(self.progress.env_steps))
        if returns:
            for key in returns[0]:
                scalars[f"episode/{key}"] = float(np.mean([r[key] for r in returns]))
        self.logger.log(self.progress.env_steps, self.progress.updates, self.wall_before + self._elapsed(), scalars)
        self.compute.sample_load()
        if self.best_policy is not None and "episode/return" in scalars:
            # the value as metrics.csv holds it, so the peak is where training-best finds it
            average = self.best_policy.observe(as_logged(scalars["episode/return"]))
            if average is not None:         # the curve's new peak: keep this policy
                self.best_policy.save(self.run_dir, self.networks.agent, self._policy_meta(), average)
        if bar is not None:
            postfix = {"sps": f"{scalars['speed/env_steps_per_second']:.0f}"}
            if returns:
                postfix["return"] = f"{scalars['episode/return']:.2f}"
            bar.set_postfix(postfix)

    def finish(self) -> dict[str, Any]:
        """Final checkpoint, the shipped policy (safetensors + ONNX), curves and a summary."""
        if self.layout_shapes is None:          # no rollout ever arrived (async): the layout from a one-world env
            env, _ = make_env(self.cfg, 1, "inprocess")
            self.layout_shapes = {k: list(v) for k, v in env.layout.shapes().items()}
            env.close()
        self.save_checkpoint()
        agent = self.networks.agent
        checkpoints.save_policy(agent, str(self.run_dir / "policy.safetensors"), self._policy_meta())
        from dynenv_ros.agent.export import export_onnx
        compiled.restore()                  # the exporter traces the eager functions
        export_onnx(agent.cpu(), self.run_dir / "policy.onnx")
        agent.to(self.device)
        self.logger.close()
        plot_curves(self.run_dir)
        summary = self._summary()
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        self.close()
        return summary

    def _summary(self) -> dict[str, Any]:
        summary = {"env_steps": self.progress.env_steps, "updates": self.progress.updates,
                   "episodes": self.progress.episodes, "wall_seconds": self.wall_before + self._elapsed(),
                   "compute": self.compute.record(self.progress.env_steps)}
        if self.cfg.init_policy:
            summary["init_policy_sha256"] = checkpoints.sha256(self.cfg.init_policy)
        summary.update(self.source.summary() if hasattr(self, "source") else {})
        if self.stop_reason:
            summary["stop_reason"] = self.stop_reason
        return summary

    def close(self) -> None:
        """Stop the worlds or the workers (again: nothing)."""
        if hasattr(self, "source"):
            self.source.close()
