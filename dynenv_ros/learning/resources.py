"""What a training run needs of this machine, checked before anything is allocated or started, so a setting the
machine cannot hold is refused in one line naming the key — not a traceback minutes later, nor a machine swapping
itself to a halt.

Estimates (measured on the 2-core development machine, soccer 2v2, docs/training.md "What a run needs"):

- a rollout holds (rollout_length + 1) periods of every learning robot's padded observation and its learning
  arrays: about 19.4 kB per robot-period (the layout's size, read from a one-world env of the run's settings);
- a minibatch's forward and backward keep about 360 kB of activations per robot-period (peak RSS over one update:
  343–355 kB at 512 and 2048 robot-periods);
- the asynchronous runner keeps ``slots`` rollouts per worker in shared memory (/dev/shm) beside the learner's copy.

The limits: the estimate must fit in 80 % of the memory available now (MemAvailable), shared memory in 90 % of
/dev/shm's free space, worker processes in the cores this process may use, and a Ray cluster must answer at its
address within ``ray_connect_timeout_s``.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.distributed.rollout_worker import resolve_workers, usable_cores

ACTIVATION_BYTES_PER_ROBOT_STEP = 360_000
MEMORY_SHARE, SHM_SHARE = 0.8, 0.9
GB = 1e9


def available_memory() -> int:
    """Bytes of memory available to new work now (Linux MemAvailable; the total elsewhere)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def shared_memory_free() -> int | None:
    try:
        stats = os.statvfs("/dev/shm")
    except OSError:
        return None
    return stats.f_bavail * stats.f_frsize


def robot_step_bytes(cfg: TrainConfig) -> int:
    """Bytes a rollout stores per learning robot and period: the padded observation of the run's settings (from a
    one-world env) plus the per-step learning arrays and targets (a fixed allowance)."""
    from dynenv_ros.learning.sampling.worlds import make_env
    env, _ = make_env(cfg, 1, "inprocess")
    try:
        observation = sum(math.prod(shape) * 4 for shape in env.layout.shapes().values())
    finally:
        env.close()
    return observation + 512


def rollout_bytes(cfg: TrainConfig, per_robot_step: int) -> int:
    return (cfg.rollout_length + 1) * cfg.learning_robots * per_robot_step


def check_machine(cfg: TrainConfig) -> None:
    """ConfigError (key and a one-line reason) for a run this machine cannot hold or reach; see the module docstring."""
    cores = usable_cores()
    if cfg.torch_threads > cores:
        raise ConfigError("torch_threads", f"{cfg.torch_threads} threads on the {cores} cores this process may use")
    async_processes = cfg.runner == "async" and cfg.backend != "ray"
    workers = resolve_workers(cfg, cores) if cfg.runner == "async" else 1
    if cfg.runner == "async" and cfg.backend == "ray" and cfg.ray_address is None and workers > cores:
        raise ConfigError("workers", f"{workers} Ray actors need {workers} CPUs; this machine has {cores} "
                                     f"(give ray_address to use a cluster)")
    if async_processes and workers > cores:
        raise ConfigError("workers", f"{workers} worker processes on the {cores} cores this process may use "
                                     f"(each steps its worlds on a core of its own)")
    per_step = robot_step_bytes(cfg)
    rollout = rollout_bytes(cfg, per_step)
    minibatch_steps = cfg.rollout_length * math.ceil(cfg.learning_robots / max(1, cfg.ppo_minibatches)) \
        if cfg.algorithm == "ppo" else cfg.rollout_length * cfg.learning_robots
    shared = 0
    if cfg.runner == "async":
        per_update = cfg.rollouts_per_update * rollout / workers
        slots = max(2, math.ceil(cfg.rollouts_per_update / workers) + 1)
        shared = int(slots * rollout) if async_processes else 0
        needed = shared + 2 * per_update + minibatch_steps * ACTIVATION_BYTES_PER_ROBOT_STEP * \
            cfg.rollouts_per_update / workers
    else:
        needed = 2 * rollout + minibatch_steps * ACTIVATION_BYTES_PER_ROBOT_STEP
    available = available_memory()
    if needed > MEMORY_SHARE * available:
        raise ConfigError("num_envs", f"{cfg.num_envs} worlds x {cfg.rollout_length} periods need about "
                                      f"{needed / GB:.1f} GB (rollouts and a minibatch's activations); this machine "
                                      f"has {available / GB:.1f} GB available (lower num_envs, rollout_length, or "
                                      f"raise ppo_minibatches)")
    free = shared_memory_free()
    if shared and free is not None and shared > SHM_SHARE * free:
        raise ConfigError("num_envs", f"the rollout workers' slots need {shared / GB:.1f} GB of shared memory; "
                                      f"/dev/shm has {free / GB:.1f} GB free")
    if cfg.runner == "async" and cfg.backend == "ray" and cfg.ray_address is not None:
        from dynenv_ros.learning.distributed.ray_connection import RayConnectionError, probe
        try:
            probe(cfg.ray_address, cfg.ray_connect_timeout_s)
        except RayConnectionError as error:
            raise ConfigError("ray_address", str(error).removeprefix("ray_address ")) from None
