"""Many independent soccer worlds stepped together, as arrays: in this process or in worker processes.

Both backends give identical results for the same seed (each world has its own generator, spawned from one
``SeedSequence``); which is faster depends on the machine — see docs/benchmarks.md (`dynenv-bench vector`).
Finished episodes reset automatically; the last observation of a finished episode is returned separately.
"""
from __future__ import annotations

import multiprocessing as mp
import os
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any, Mapping

import numpy as np

from dynenv_ros.envs.soccer_spaces import GroundTruthEncoder
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld


AUTO_SUBPROCESS_MIN_ENVS = 8


@dataclass
class BatchStep:
    observations: np.ndarray       # (E, A, D) float32, after any automatic reset
    rewards: np.ndarray            # (E, A) sum of the terms
    reward_terms: np.ndarray       # (E, T, A)
    terminated: np.ndarray         # (E,) bool
    truncated: np.ndarray          # (E,) bool
    final_observations: dict[int, np.ndarray]   # env index -> (A, D) last observation of a finished episode


def _seeds(seed: int | None, count: int) -> list[int]:
    children = np.random.SeedSequence(seed).spawn(count)
    return [int(child.generate_state(1, np.uint64)[0]) for child in children]


class InProcessBatch:
    """Worlds stepped one after another in this process."""

    def __init__(self, num_envs: int, config: SoccerConfig) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        self.config = config
        self.worlds = [SoccerWorld(config) for _ in range(num_envs)]
        self.encoder = GroundTruthEncoder(config)

    @property
    def num_envs(self) -> int:
        return len(self.worlds)

    def reset(self, seeds: list[int | None]) -> np.ndarray:
        for world, seed in zip(self.worlds, seeds):
            world.reset(seed=seed)
        return np.stack([self.encoder.observations(w) for w in self.worlds])

    def step(self, actions: np.ndarray) -> BatchStep:
        actions = np.asarray(actions)
        expected = (self.num_envs, self.config.n_robots)
        if actions.shape[:2] != expected:
            raise ValueError(f"actions must have shape {expected + (4,)}, got {actions.shape}")
        # Validate everything before any world moves.
        parsed = [w.parse_actions(list(a), [f"env {e} robot {i}" for i in range(len(a))])
                  for e, (w, a) in enumerate(zip(self.worlds, actions))]
        n_terms = 4
        obs = np.empty((self.num_envs, self.config.n_robots, self.encoder.observation_space.shape[0]), np.float32)
        terms = np.empty((self.num_envs, n_terms, self.config.n_robots))
        terminated = np.zeros(self.num_envs, bool)
        truncated = np.zeros(self.num_envs, bool)
        finals: dict[int, np.ndarray] = {}
        for e, (world, acts) in enumerate(zip(self.worlds, parsed)):
            result = world.step(acts)
            terms[e] = result.rewards
            terminated[e], truncated[e] = result.terminated, result.truncated
            obs[e] = self.encoder.observations(world)
            if result.terminated or result.truncated:
                finals[e] = obs[e].copy()
                world.reset(seed=int(world.rng.integers(2**63)))
                obs[e] = self.encoder.observations(world)
        return BatchStep(obs, terms.sum(axis=1), terms, terminated, truncated, finals)

    def close(self) -> None:
        pass


def _worker(conn: Connection, num_envs: int, config: SoccerConfig) -> None:
    batch = InProcessBatch(num_envs, config)
    while True:
        command, payload = conn.recv()
        try:
            if command == "reset":
                conn.send(("ok", batch.reset(payload)))
            elif command == "step":
                conn.send(("ok", batch.step(payload)))
            elif command == "close":
                conn.send(("ok", None))
                return
        except Exception as exc:     # report to the parent, keep serving
            conn.send(("error", exc))


class SubprocessBatch:
    """Worlds split over worker processes (one per core by default), stepped concurrently."""

    def __init__(self, num_envs: int, config: SoccerConfig, workers: int | None = None) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        workers = min(num_envs, workers or os.cpu_count() or 1)
        self.config = config
        self.num_envs = num_envs
        self.sizes = [num_envs // workers + (1 if w < num_envs % workers else 0) for w in range(workers)]
        context = mp.get_context("forkserver")
        self._conns: list[Connection] = []
        self._procs = []
        for size in self.sizes:
            parent, child = context.Pipe()
            proc = context.Process(target=_worker, args=(child, size, config), daemon=True)
            proc.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(proc)

    def _call(self, command: str, payloads: list[Any]) -> list[Any]:
        for conn, payload in zip(self._conns, payloads):
            conn.send((command, payload))
        replies = []
        for w, conn in enumerate(self._conns):
            try:
                replies.append(conn.recv())
            except (EOFError, OSError) as exc:
                raise RuntimeError(f"soccer worker process {w} died ({exc!r}); see its error output above. Scripts "
                                   "that start workers need an `if __name__ == '__main__':` guard") from exc
        for status, value in replies:
            if status == "error":
                raise value
        return [value for _, value in replies]

    def _split(self, items: Any) -> list[Any]:
        bounds = np.cumsum([0] + self.sizes)
        return [items[a:b] for a, b in zip(bounds[:-1], bounds[1:])]

    def reset(self, seeds: list[int | None]) -> np.ndarray:
        return np.concatenate(self._call("reset", self._split(seeds)))

    def step(self, actions: np.ndarray) -> BatchStep:
        actions = np.asarray(actions)
        expected = (self.num_envs, self.config.n_robots)
        if actions.shape[:2] != expected:
            raise ValueError(f"actions must have shape {expected + (4,)}, got {actions.shape}")
        parts: list[BatchStep] = self._call("step", self._split(actions))
        finals: dict[int, np.ndarray] = {}
        offset = 0
        for size, part in zip(self.sizes, parts):
            finals.update({offset + e: o for e, o in part.final_observations.items()})
            offset += size
        return BatchStep(*(np.concatenate([getattr(p, f) for p in parts])
                           for f in ("observations", "rewards", "reward_terms", "terminated", "truncated")),
                         finals)

    def close(self) -> None:
        for conn in self._conns:
            try:
                conn.send(("close", None))
                conn.recv()
            except (BrokenPipeError, EOFError, OSError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()
        self._conns, self._procs = [], []


class SoccerVectorEnv:
    """``num_envs`` soccer worlds as one batch: ``reset(seed) -> (E, A, D)``, ``step(actions (E, A, 4))``."""

    def __init__(self, num_envs: int, backend: str = "auto", workers: int | None = None,
                 config: SoccerConfig | Mapping[str, Any] | None = None) -> None:
        self.config = config if isinstance(config, SoccerConfig) else SoccerConfig.from_mapping(config)
        if backend == "auto":   # measured crossover on 2 cores: workers pay off from about 8 worlds (benchmarks.md)
            backend = "subprocess" if num_envs >= AUTO_SUBPROCESS_MIN_ENVS and (os.cpu_count() or 1) > 1 \
                else "inprocess"
        if backend == "inprocess":
            self._batch: InProcessBatch | SubprocessBatch = InProcessBatch(num_envs, self.config)
        elif backend == "subprocess":
            self._batch = SubprocessBatch(num_envs, self.config, workers)
        else:
            raise ValueError(f"backend must be 'auto', 'inprocess' or 'subprocess', got {backend!r}")
        self.backend = backend
        self.num_envs = num_envs
        encoder = GroundTruthEncoder(self.config)
        self.single_observation_space = encoder.observation_space

    def reset(self, seed: int | None = None) -> np.ndarray:
        return self._batch.reset(_seeds(seed, self.num_envs))

    def step(self, actions: np.ndarray) -> BatchStep:
        return self._batch.step(actions)

    def close(self) -> None:
        self._batch.close()

    def __enter__(self) -> "SoccerVectorEnv":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
