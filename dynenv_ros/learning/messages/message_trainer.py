"""The trainer fed by message-assembled experience (``learning.messages.assembly``): the in-process trainer's networks,
losses (``algo.ppo.update``), run directory, logs and checkpoints, with no simulator of its own. The trainer node
runs it in a background thread (``TrainingThread``).

Off-policy correction (docs/decisions.md, "Learning from experience that lags"): PPO's clipped ratio against the
behaviour log-probabilities the policy nodes sent (``Action.log_prob``), with a bound on staleness — a sequence any
step of which was chosen more than ``max_policy_lag`` versions ago is dropped (counted). Advantages use the values
the behaviour policy sent (``Action.value``), as PPO does with its rollout values.

Both scenarios: ``cfg.scenario`` 'driving' learns the driving agent (``cfg.action_mode``) from the cars' sequences;
they hold no step after a car's own episode end (``learning.messages.assembly``), so no alive mask is needed.

Recurrent state: a sequence that ``continues`` its stream's previous one starts from the state the learner's
network reached at the end of that one (computed after each update, no gradient — R2D2's "stored state", stale
by at most one update); a stream's first sequence, one after a cut, and one whose predecessor was dropped start from
zeros with ``starts[0]`` set.
"""
from __future__ import annotations

import json
import threading
import time
from collections import Counter, deque
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from dynenv_ros.agent.checkpoint import policy_bytes
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.algo.experience import Experience, Progress, arrays_as_tensors
from dynenv_ros.learning.algo.loop import learn_from, train
from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.algo.policy import log_prob_entropy, run_sequence
from dynenv_ros.learning.algo.ppo import NONFINITE_SKIPS, update, update_settings
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.messages.assembly import Sequence, batch
from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.run.metrics import RunLogger

MAX_QUEUE = 4096          # sequences waiting for the learner; beyond, the oldest are dropped (counted)


class MessageTrainer:
    """Updates on batches of ``batch_sequences`` sequences. ``version`` = 1 + updates: what the weights it hands
    out are called (``WeightsAnnouncement.version``, ``Action.policy_version``)."""

    def __init__(self, cfg: TrainConfig, run_dir: str | Path, resume: bool = False, batch_sequences: int = 8,
                 max_policy_lag: int = 4, log: bool = True, reward_weights=(1.0, 1.0, 1.0, 1.0),
                 initial_policy: str | Path | None = None, max_batch_sequences: int | None = None) -> None:
        if cfg.algorithm != "ppo":
            raise ConfigError("algorithm", "learning from message experience needs 'ppo' (its ratio corrects the "
                             "policy lag; A2C is on-policy only)")
        if cfg.head_mode != "discrete":
            raise ConfigError("head_mode", "learning from message experience supports the discrete head only")
        if batch_sequences < 1 or batch_sequences < cfg.ppo_minibatches:
            raise ConfigError("batch_sequences", f"must be >= 1 and >= ppo_minibatches ({cfg.ppo_minibatches}), "
                             f"got {batch_sequences}")
        if max_policy_lag < 0:
            raise ConfigError("max_policy_lag", f"must be >= 0, got {max_policy_lag}")
        if cfg.best_policy_window is not None:
            raise ConfigError("best_policy_window", "dynenv-train's runners (in-process, async) keep the training "
                                                    "curve's best policy; the trainer node and --from-bag do not: "
                                                    "use null here")
        if cfg.localization != "none":
            raise ConfigError("localization", "'estimate' trains on the simulator's pose estimates; experience "
                                              "over ROS (the trainer node, --from-bag) carries none yet: use "
                                              "localization: none here")
        if cfg.curriculum is not None:
            raise ConfigError("curriculum", "the trainer node and --from-bag learn from episodes that the simulator "
                                            "or the bag started; a curriculum of start states applies to "
                                            "dynenv-train's runners (in-process, async): use null here")
        self.cfg, self.run_dir = cfg, Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.batch_sequences, self.max_policy_lag = batch_sequences, max_policy_lag
        self.max_batch_sequences = max(batch_sequences, max_batch_sequences or 4 * batch_sequences)
        # The reward learnt: a weighted sum of the four terms of StepFeedback (primary, rule, auxiliary,
        # observation); all ones is the simulator's total.
        self.reward_weights = np.asarray(reward_weights, np.float32)
        if self.reward_weights.shape != (4,) or not np.isfinite(self.reward_weights).all():
            raise ConfigError("reward_weights", f"must be 4 finite numbers, got {list(reward_weights)}")
        torch.set_num_threads(cfg.torch_threads)
        self.settings = update_settings(cfg)
        seeds = np.random.SeedSequence(cfg.seed).spawn(4)
        self.generator = torch.Generator().manual_seed(int(seeds[0].generate_state(1)[0]))
        torch.manual_seed(int(seeds[3].generate_state(1)[0]))   # parameter init only
        agent = make_agent(cfg)   # the in-process trainer's agent for cfg (driving: its action mode's heads)
        self.networks = TrainingNetworks(agent, cfg.ltp_horizon).eval()
        self.optimizer = torch.optim.Adam(self.networks.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
        self.progress = Progress()
        self.wall_before = 0.0
        self._started = time.perf_counter()
        if initial_policy and not resume:      # a warm start: a policy file (e.g. dynenv-train --from-bag's)
            try:
                self._load_initial(Path(initial_policy))
            except ValueError as error:
                raise ConfigError("initial_policy", str(error)) from None
        if resume:
            try:
                meta, _ = checkpoints.load_training_checkpoint(self.run_dir, self.networks, self.optimizer)
            except ValueError as error:
                raise ConfigError("resume", str(error)) from None
            self.progress = Progress(int(meta["env_steps"]), int(meta["updates"]), int(meta.get("episodes", 0)))
            self.wall_before = float(meta.get("wall_seconds", 0.0))
        (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
        self.logger = RunLogger(self.run_dir) if log else None
        self.states: dict[tuple[str, str], tuple[int, tuple[torch.Tensor, ...]]] = {}   # stream -> (index, state)
        self.returns: dict[tuple[str, str], float] = {}      # running episode return per stream
        self.finished: list[dict[str, float]] = []           # episodes finished: version, return
        self.counts: Counter[str] = Counter()
        self.published: dict[int, float] = {self.version: time.time()}   # version -> wall time handed out
        self.last_stats: dict[str, float] = {}
        self._learning: tuple[list[Sequence], dict[str, Any]] | None = None      # what the update in hand is on

    def _load_initial(self, path: Path) -> None:
        from dynenv_ros.agent.checkpoint import agent_config, load_policy
        loaded, _ = load_policy(path)
        if agent_config(loaded) != agent_config(self.agent):
            raise ValueError(f"initial_policy {path} does not fit the learner: its network is {agent_config(loaded)}, "
                             f"the learner's {agent_config(self.agent)} (set feature_size to match)")
        self.agent.load_state_dict(loaded.state_dict())

    @property
    def version(self) -> int:
        return self.progress.updates + 1

    @property
    def agent(self) -> DynEnvAgent:
        return self.networks.agent

    def set_learning_rate(self, value: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = value

    # -- one update ---------------------------------------------------------------------------------------------
    def fresh(self, sequence: Sequence) -> bool:
        """Within the staleness bound (else counted and dropped; its stream's stored state is forgotten)."""
        lag = self.version - int(sequence.versions.min())
        if lag > self.max_policy_lag:
            self.counts["stale_sequences"] += 1
            self.states.pop(sequence.stream, None)
            self.returns[sequence.stream] = float("nan")           # that episode's return is incomplete now
            return False
        return True

    def learn(self, sequences: list[Sequence]) -> dict[str, float]:
        """One PPO update on these sequences (one step of the training loop, ``algo.loop``). A stream may bring
        several, consecutive ones (a learner that fell behind takes what waits rather than letting it go stale): the
        first starts from the stream's stored state, each next one from the state the current network reaches at
        the end of the one before (no gradient)."""
        return learn_from(self.experience(sequences), self.step, self.progress, self)

    def experience(self, sequences: list[Sequence]) -> Experience:
        """The update's experience of these sequences: their batch with each row's start state, the episodes their
        ends finish (counted from here on), and what the update logs of them (lag, behaviour alignment)."""
        now = time.time()
        sequences = sorted(sequences, key=lambda q: (q.stream, q.index))
        arrays = batch(sequences)
        arrays["rewards"] = arrays["reward_terms"] @ self.reward_weights
        B = len(sequences)
        initial = [torch.zeros(B, s.shape[-1]) for s in self.agent.initial_state(1)]
        known_state = np.zeros(B, bool)         # the learner starts from the state the policy had (up to lag)
        follows = np.full(B, -1)                # the row this one continues within the batch
        for b, sequence in enumerate(sequences):
            before = sequences[b - 1] if b else None
            stored = self.states.get(sequence.stream)
            if sequence.keys[0][1] == 0:                        # an episode's first observation: zero state
                known_state[b] = True
            elif (sequence.continues and before is not None and before.stream == sequence.stream
                  and before.index == sequence.index - 1):
                follows[b], known_state[b] = b - 1, known_state[b - 1]
            elif sequence.continues and stored is not None and stored[0] == sequence.index - 1:
                for part, value in zip(initial, stored[1]):
                    part[b] = value
                known_state[b] = True
            else:                                               # after a cut or a dropped predecessor
                arrays["starts"][0, b] = True
                self.counts["state_restarts"] += 1
        tensors = arrays_as_tensors({k: v for k, v in arrays.items() if k != "versions"}, tuple(initial))
        self._chain_states(tensors, follows)
        alignment = self._alignment(tensors, known_state)
        versions = arrays["versions"]
        lag = self.version - versions
        scalars = {"lag_versions_mean": float(lag.mean()), "lag_versions_max": float(lag.max()),
                   "lag_seconds_mean": float(np.mean([now - self.published.get(int(v), now)
                                                      for v in versions.ravel()]))}
        if alignment is not None:
            scalars["behaviour_log_prob_error"] = alignment
        finished = self._account(sequences, arrays["rewards"])
        self._learning = (sequences, tensors)
        T = arrays["actions"].shape[0]
        return Experience(tensors, T * B, finished, scalars)

    def step(self, experience: Experience) -> dict[str, float]:
        """The algorithm's step: the update, its skipped steps counted, with what it logs of the experience."""
        self.networks.train()
        stats = update(self.networks, self.optimizer, experience.batch, self.settings, self.generator)
        self.networks.eval()
        for name in NONFINITE_SKIPS:            # skipped steps (logged at ERROR by update): the node's diagnostics
            self.counts[name] += int(stats.get(name, 0))
        stats.update(experience.scalars)
        self.last_stats = stats
        return stats

    def learned(self, progress: Progress) -> None:
        """After the update: each stream's next start state from the new weights, and the new version's time."""
        if self._learning is not None:
            sequences, tensors = self._learning
            self._store_states(sequences, tensors)
            self._learning = None
        self.published[self.version] = time.time()
        for old in [v for v in self.published if v < self.version - 4 * (self.max_policy_lag + 1)]:
            del self.published[old]

    @torch.no_grad()
    def _alignment(self, tensors: dict[str, Any], known_state: np.ndarray) -> float | None:
        """Mean |log π_learner(a|s) − Action.log_prob| before the update, over the sequences whose recurrent state
        the learner knows: 0 (to float precision) when the learner's weights are those that acted, and the
        observations, previous actions, recurrent state and action indices it rebuilt are the policy node's — the
        check that experience from the wire means what the policy saw (docs/ros_graph.md)."""
        rows = torch.from_numpy(np.flatnonzero(known_state))
        if not len(rows):
            return None
        T = tensors["actions"].shape[0]
        obs = {k: v[:T, rows] for k, v in tensors["obs"].items()}
        state = tuple(s[rows] for s in tensors["initial_state"])
        out = run_sequence(self.agent, obs, state, tensors["starts"][:T, rows])
        log_prob, _ = log_prob_entropy(self.agent, out, tensors["actions"][:, rows])
        return float((log_prob - tensors["log_probs"][:, rows]).abs().mean())

    def _end_states(self, tensors: dict[str, Any], rows: list[int]) -> tuple[torch.Tensor, ...]:
        """The state after observations 0..T-1 of these rows (the next sequence's start), no gradient."""
        T = tensors["actions"].shape[0]
        index = torch.as_tensor(rows)
        obs = {k: v[:T, index] for k, v in tensors["obs"].items()}
        state = tuple(s[index] for s in tensors["initial_state"])
        with torch.no_grad():
            return run_sequence(self.agent, obs, state, tensors["starts"][:T, index]).state

    def _chain_states(self, tensors: dict[str, Any], follows: np.ndarray) -> None:
        """Initial states of rows that continue another row of the batch, level by level (a stream's 2nd sequences
        from its 1st ones' end states in one forward, then its 3rd ones …)."""
        done = follows < 0
        while not done.all():
            level = [b for b in np.flatnonzero(~done) if done[follows[b]]]
            ends = self._end_states(tensors, [int(follows[b]) for b in level])
            for i, b in enumerate(level):
                for part, end in zip(tensors["initial_state"], ends):
                    part[b] = end[i]
                done[b] = True

    def _store_states(self, sequences: list[Sequence], tensors: dict[str, Any]) -> None:
        """The state each stream's next sequence starts from: the updated network run over its last row."""
        last = {sequence.stream: b for b, sequence in enumerate(sequences)}      # sorted: the last one wins
        rows = list(last.values())
        ends = self._end_states(tensors, rows)
        for i, b in enumerate(rows):
            self.states[sequences[b].stream] = (sequences[b].index, tuple(s[i].clone() for s in ends))

    def _account(self, sequences: list[Sequence], rewards: np.ndarray) -> list[dict[str, float]]:
        """Episode returns of the reward learnt: the episodes these sequences end (each under the version that
        chose its last action), added to ``finished``; an episode counts once its end is learnt from."""
        finished: list[dict[str, float]] = []
        for b, sequence in enumerate(sequences):
            total = self.returns.get(sequence.stream, 0.0)
            if sequence.starts[0]:      # an episode's start, or a cut (its beginning unknown: not counted)
                total = 0.0 if sequence.keys[0][1] == 0 else float("nan")
            for t in range(len(sequence.rewards)):
                if sequence.starts[t] and t > 0:
                    total = 0.0
                total += float(rewards[t, b])
                if sequence.episode_end[t]:
                    if total == total:                            # whole episodes only
                        finished.append({"version": float(sequence.versions[t]), "return": total})
                    total = 0.0
            self.returns[sequence.stream] = total
        self.finished.extend(finished)
        return finished

    # -- weights, logs, checkpoints ---------------------------------------------------------------------------------
    def meta(self) -> dict[str, Any]:
        return {"version": checkpoints.META_VERSION, "config": self.cfg.to_dict(), "variant": self.cfg.variant,
                "algorithm": self.cfg.algorithm, "env_steps": self.progress.env_steps,
                "updates": self.progress.updates, "episodes": self.progress.episodes, "wall_seconds": self.wall_before + time.perf_counter() - self._started,
                "source": "messages", "code_revision": checkpoints.code_revision(),
                # what dynenv-train --resume restores (its worlds' generator): the same run directory serves both
                "numpy_rng": np.random.default_rng(self.cfg.seed + self.progress.updates).bit_generator.state}

    def weights(self) -> bytes:
        """The current policy as a policy file's bytes (what the trainer node announces and serves); its meta's updates give
        ``version_of`` = ``self.version``."""
        return policy_bytes(self.agent, self.policy_meta())

    def policy_meta(self) -> dict[str, Any]:
        """What a policy file carries of the run (no config, no generator state)."""
        return {k: v for k, v in self.meta().items() if k not in ("config", "numpy_rng")}

    def log(self, scalars: dict[str, float]) -> None:
        if self.logger is not None:
            self.logger.log(self.progress.env_steps, self.progress.updates, self.meta()["wall_seconds"], scalars)

    def save_checkpoint(self) -> Path:
        return checkpoints.save_training_checkpoint(self.run_dir, self.progress.env_steps, self.networks, self.optimizer,
                                                    self.meta(), {}, keep=self.cfg.keep_checkpoints)

    def close(self) -> None:
        if self.logger is not None:
            self.logger.close()
            self.logger = None


class TrainingThread:
    """``MessageTrainer`` in a thread of its own, which runs the training loop (``algo.loop``) with this queue as its
    experience source: ``put`` (from ROS callbacks) never waits for a gradient step. Each batch takes the oldest waiting sequence of up to ``batch_sequences`` streams (a stream's next sequence
    waits for the next batch: it needs the state this one ends in). ``on_update(trainer, stats)`` runs in the
    thread after each update (the node publishes the weights from it); checkpoints every
    ``cfg.checkpoint_every_minutes``."""

    def __init__(self, trainer: MessageTrainer, on_update: Callable[[MessageTrainer, dict[str, float]], None]
                 | None = None, max_queue: int = MAX_QUEUE) -> None:
        self.trainer, self.on_update = trainer, on_update
        self.queue: deque[Sequence] = deque()
        self.max_queue = max_queue
        self.lock = threading.Lock()
        self.wake = threading.Condition(self.lock)
        self.counts: Counter[str] = Counter()
        self.error = ""
        self._stop = threading.Event()
        self._last_checkpoint = time.monotonic()
        self.thread = threading.Thread(target=self._run, name="learner", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def put(self, sequences: list[Sequence]) -> None:
        with self.wake:
            for sequence in sequences:
                self.queue.append(sequence)
                self.counts["received"] += 1
                if len(self.queue) > self.max_queue:
                    self.queue.popleft()
                    self.counts["queue_dropped"] += 1
            self.wake.notify()

    def depth(self) -> int:
        with self.lock:
            return len(self.queue)

    def _next_batch(self) -> list[Sequence] | None:
        """Under the lock: a batch once ``batch_sequences`` streams have a fresh sequence waiting — with every
        waiting sequence of those streams that continues the one before it, up to ``max_batch_sequences``."""
        trainer = self.trainer
        for sequence in [q for q in self.queue if not trainer.fresh(q)]:
            self.queue.remove(sequence)
        by_stream: dict[tuple[str, str], list[Sequence]] = {}
        for sequence in self.queue:
            chain = by_stream.setdefault(sequence.stream, [])
            if not chain or (sequence.index == chain[-1].index + 1 and sequence.continues):
                chain.append(sequence)
        if len(by_stream) < trainer.batch_sequences:
            return None
        chosen = [chain[0] for chain in by_stream.values()]
        for depth in range(1, max(len(c) for c in by_stream.values())):
            for chain in by_stream.values():
                if depth < len(chain) and len(chosen) < trainer.max_batch_sequences:
                    chosen.append(chain[depth])
        taken = {id(q) for q in chosen}
        self.queue = deque(q for q in self.queue if id(q) not in taken)
        return chosen

    def next(self, progress: Progress, deadline: float) -> Experience | None:
        """The trainer's experience of the next batch of waiting sequences (the loop's source); None once stopped."""
        while not self._stop.is_set():
            with self.wake:
                sequences = self._next_batch()
                if sequences is None:
                    self.wake.wait(timeout=0.2)
                    continue
            return self.trainer.experience(sequences)
        return None

    def learned(self, progress: Progress) -> None:
        self.trainer.learned(progress)

    def close(self) -> None:
        self.stop()

    def _record(self, experience: Experience, stats: dict[str, float], waited: float, learnt: float) -> None:
        """After each update: ``on_update``, and a checkpoint every ``checkpoint_every_minutes``."""
        if self.on_update is not None:
            self.on_update(self.trainer, stats)
        every = self.trainer.cfg.checkpoint_every_minutes * 60.0
        if time.monotonic() - self._last_checkpoint > every:
            self.trainer.save_checkpoint()
            self._last_checkpoint = time.monotonic()

    def _run(self) -> None:
        """The training loop over the queue, until ``stop``."""
        try:
            train(self, self.trainer.step, self.trainer.progress, self._record,
                  until=lambda progress: not self._stop.is_set())
        except Exception as error:         # a learner that fails says so and stops learning; nothing crashes
            self.error = f"{type(error).__name__}: {error}"
            self.counts["failed_updates"] += 1

    def stop(self, timeout: float = 30.0) -> None:
        self._stop.set()
        with self.wake:
            self.wake.notify()
        if self.thread.is_alive():
            self.thread.join(timeout)
