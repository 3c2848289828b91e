"""The in-process rollouts: ``RolloutCollector`` steps the vectorised batch (``SoccerVectorEnv`` or
``DrivingVectorEnv``) with the current policy, T periods at a time, into a ``Rollout`` (``algo.experience``: what
its arrays hold, soccer and driving). The learning robots act through an ``Acting`` (``sampling.acting``): in this
process, or on the asynchronous runner's inference server.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, cast

import numpy as np
import torch
from torch import Tensor

from dynenv_ros.driving.agent_actions import commands as driving_commands
from dynenv_ros.agent.network import DynEnvAgent, State
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.algo.experience import Rollout
from dynenv_ros.learning.sampling.acting import Acting, LocalActing
from dynenv_ros.scenarios import scenario_of
from dynenv_ros.learning.algo.policy import action_width, can_act

TARGET_KEYS = ("pose", "ball", "robots", "ball_seen", "robots_seen")


def flatten_robots(value: np.ndarray, robots: np.ndarray) -> np.ndarray:
    """(E, A, ...) → (E·len(robots), ...): the learning robots of every world, world by world."""
    picked = value[:, robots]
    return picked.reshape(-1, *picked.shape[2:])


# driving's ego columns (perception.driving_model.EGO_COLUMNS) in the proprioception rows
EGO_CRASHED, EGO_FINISHED = 6, 7




def _record(acted: Any, t: int, steps: int, values: np.ndarray, actions: np.ndarray, log_probs: np.ndarray) -> bool:
    """Period ``t``'s acting into the rollout's arrays: the value always, the action and its log-probability except
    at the bootstrap period (``t == steps``, which gives the value only: True then, the rollout ends)."""
    values[t] = acted.values
    if t == steps:
        return True
    actions[t], log_probs[t] = acted.actions, acted.log_probs
    return False

class Opponent:
    """Who plays the robots the learner does not control. ``act`` gets their observations (E, k, ...) and the
    robots starting an episode (E, k); returns (E, k, 4) integer actions."""

    def act(self, obs: Mapping[str, np.ndarray], starts: np.ndarray) -> np.ndarray:
        raise NotImplementedError


# builds the acting of a collector from its learning robots' first observations (B, ...) and whether the worlds have
# a teacher (requests carry its actions) or privileged seeding (they carry seed poses)
ActingFactory = Callable[[Mapping[str, np.ndarray], bool, bool], Acting]


class RolloutCollector:
    """Steps ``env`` with ``agent`` (and ``opponent`` for the robots not in ``learning_robots``), T periods at a
    time, carrying episode state (recurrent state, seen-so-far memory) across rollouts. The learning robots act
    through ``acting`` (default: ``LocalActing`` with ``agent`` and ``generator``)."""

    def __init__(self, env: SoccerVectorEnv, agent: DynEnvAgent, learning_robots: np.ndarray,
                 opponent: Opponent | None, generator: torch.Generator, seed: int,
                 reward_transform: Callable[[np.ndarray], np.ndarray] | None = None,
                 pose_seeder: Callable[[Tensor], State] | None = None, seed_noise: np.ndarray | None = None,
                 rng: np.random.Generator | None = None, acting: ActingFactory | None = None) -> None:
        self.env, self.agent = env, agent
        world = scenario_of(agent)
        if not isinstance(env.config, world.settings_type):
            raise ValueError("the agent's scenario and the env's differ (a driving agent needs DrivingVectorEnv)")
        self.learning_robots = np.asarray(learning_robots, np.int64)
        self.other_robots = np.setdiff1d(np.arange(world.agent_count(env.config)), self.learning_robots)
        if world.sides == 1 and len(self.other_robots):
            raise ValueError(f"{world.name}: every {world.agent} learns (learning_robots must be all of them)")
        self._collect_steps = getattr(self, f"_collect_{world.name}")
        if len(self.other_robots) and opponent is None:
            raise ValueError("robots outside learning_robots need an opponent")
        self.opponent = opponent
        self.with_targets = bool(getattr(env, "with_targets", False))
        self.reward_transform = reward_transform
        # DynEnv's privileged re-initialisation (docs/original.md §9.6, §12.18), off unless a seeder is given: at every
        # rollout's start the whole recurrent state is replaced by pose_seeder(true pose + N(0, seed_noise²)).
        self.pose_seeder, self.seed_noise, self.rng = pose_seeder, seed_noise, rng
        if pose_seeder is not None and not self.with_targets:
            raise ValueError("privileged pose seeding needs the true pose: SoccerVectorEnv(targets=True)")
        self._obs = env.reset(seed=seed)
        self._targets = env.targets if self.with_targets else {}
        self.with_teacher = getattr(env, "teacher", None) is not None
        self._teacher = env.teacher_actions if self.with_teacher else None
        self.teacher_driven = np.zeros(env.num_envs * len(self.learning_robots), bool)
        batch = env.num_envs * len(self.learning_robots)
        if acting is None:
            self.acting: Acting = LocalActing(agent, generator, batch, pose_seeder)
        else:
            self.acting = acting(self._learning_obs(self._obs), self.with_teacher, pose_seeder is not None)
        self._starts = np.ones(batch, bool)
        self._other_starts = np.ones((env.num_envs, len(self.other_robots)), bool)
        self._known: dict[str, np.ndarray] = {}
        if self.with_targets:
            self._known = {"ball_known": np.zeros(batch, np.float32),
                           "robots_known": np.zeros((batch, self._targets["robots_seen"].shape[-1]), np.float32)}
        self.episode_returns = np.zeros(batch)
        self.episode_terms = np.zeros((batch, 4))
        self.episode_positive = np.zeros(batch)
        self.finished: list[dict[str, float]] = []     # finished episodes since the caller last cleared it
        self._done = np.zeros(batch, bool)             # driving: the car's episode ended, its world's has not

    def drive_with_teacher(self, worlds: int) -> None:
        """From the next step on, the learning robots of the first ``worlds`` worlds execute the teacher's actions
        (DAgger's β = worlds / num_envs); 0 gives every world back to the learner."""
        if worlds and not self.with_teacher:
            raise ValueError("teacher-driven worlds need SoccerVectorEnv(teacher=...)")
        if not 0 <= worlds <= self.env.num_envs:
            raise ValueError(f"worlds must be in 0..{self.env.num_envs}, got {worlds}")
        self.teacher_driven = np.repeat(np.arange(self.env.num_envs) < worlds, len(self.learning_robots))

    def _learning_obs(self, obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: flatten_robots(v, self.learning_robots) for k, v in obs.items()}

    def _remember_seen(self, targets: Mapping[str, np.ndarray], starts: np.ndarray) -> dict[str, np.ndarray]:
        """Seen-before flags including this observation; reset where an episode starts."""
        ball = flatten_robots(targets["ball_seen"], self.learning_robots)
        robots = flatten_robots(targets["robots_seen"], self.learning_robots)
        self._known["ball_known"] = np.maximum(np.where(starts, 0.0, self._known["ball_known"]), ball)
        self._known["robots_known"] = np.maximum(np.where(starts[:, None], 0.0, self._known["robots_known"]),
                                                 robots)
        return dict(self._known)

    def collect(self, steps: int) -> Rollout:
        """The next ``steps`` periods of every world. Acting runs under ``torch.inference_mode`` (cheaper than
        no_grad); the start state the learner re-runs from is copied out of it into an ordinary tensor."""
        with torch.inference_mode():
            rollout = self._collect_steps(steps)
        rollout.initial_state = tuple(s.clone() for s in rollout.initial_state)   # type: ignore[assignment]
        return rollout

    def close(self) -> None:
        self.acting.close()

    def _collect_soccer(self, steps: int) -> Rollout:
        E, k = self.env.num_envs, len(self.learning_robots)
        B = E * k
        first = self._learning_obs(self._obs)
        obs = {key: np.empty((steps + 1, *v.shape), v.dtype) for key, v in first.items()}
        targets: dict[str, np.ndarray] = {}
        actions = np.zeros((steps, B, 4), np.int64)
        log_probs, values = np.zeros((steps, B), np.float32), np.zeros((steps + 1, B), np.float32)
        rewards, terms = np.zeros((steps, B), np.float32), np.zeros((steps, B, 4), np.float32)
        episode_end, truncated = np.zeros((steps, B), bool), np.zeros((steps, B), bool)
        final_values = np.zeros((steps, B), np.float32)
        starts, acting = np.zeros((steps + 1, B), bool), np.zeros((steps + 1, B), bool)
        teacher = np.zeros((steps, B, 4), np.int64) if self.with_teacher else None
        seed_pose = None
        if self.pose_seeder is not None:
            true_pose = flatten_robots(self._targets["pose"], self.learning_robots)
            seed_pose = (true_pose + self.rng.normal(size=true_pose.shape) * self.seed_noise).astype(np.float32)
            self.acting.seed(seed_pose)
            self._starts = np.zeros_like(self._starts)       # the seeded state is this rollout's start
        initial_state: State | None = None
        current = first
        for t in range(steps + 1):
            for key, v in current.items():
                obs[key][t] = v
            starts[t], acting[t] = self._starts, can_act(current["proprioception"])
            if self.with_targets:
                seen = self._remember_seen(self._targets, self._starts)
                values_now = {key: flatten_robots(self._targets[key], self.learning_robots) for key in TARGET_KEYS}
                values_now.update(seen)
                if not targets:          # allocated once per rollout, filled step by step
                    targets = {k: np.empty((steps + 1, *v.shape), np.float32) for k, v in values_now.items()}
                for key, value in values_now.items():
                    targets[key][t] = value
            if teacher is not None and t < steps:
                teacher[t] = flatten_robots(self._teacher, self.learning_robots)
            # the bootstrap period (t == steps) gives the value only; the next rollout acts on this observation
            acted = self.acting.step(current, self._starts, last=t == steps, want_state=t == 0,
                                     teacher=None if teacher is None or t == steps else teacher[t],
                                     driven=self.teacher_driven if teacher is not None else None)
            if t == 0:
                initial_state = acted.start_state
            if _record(acted, t, steps, values, actions, log_probs):
                break
            full = np.zeros((E, self.env.config.n_robots, 4), np.int64)
            full[:, self.learning_robots] = actions[t].reshape(E, k, 4)
            if len(self.other_robots):
                other_obs = {key: v[:, self.other_robots] for key, v in self._obs.items()}
                full[:, self.other_robots] = self.opponent.act(other_obs, self._other_starts)
            result = self.env.step(full)
            step_terms = flatten_robots(result.reward_terms.transpose(0, 2, 1), self.learning_robots)
            terms[t] = step_terms
            rewards[t] = step_terms.sum(-1) if self.reward_transform is None else self.reward_transform(step_terms)
            ended = result.terminated | result.truncated                       # (E,)
            episode_end[t] = np.repeat(ended, k)
            truncated[t] = np.repeat(result.truncated & ~result.terminated, k)
            if result.truncated.any():
                final_values[t] = self._final_values(result, truncated[t])
            self._account(step_terms, episode_end[t])
            self._obs = result.observations
            if self.with_targets:
                self._targets = result.targets
            if self.with_teacher:
                self._teacher = result.teacher_actions
            self._starts = episode_end[t].copy()
            self._other_starts = np.repeat(ended[:, None], len(self.other_robots), axis=1)
            current = self._learning_obs(self._obs)
        return Rollout(obs, actions, log_probs, values, rewards, terms, episode_end, truncated, final_values,
                       starts, acting, cast(State, initial_state), targets, seed_pose, teacher,
                       self.teacher_driven.copy() if self.with_teacher else None)

    def _collect_driving(self, steps: int) -> Rollout:
        """``_collect`` for driving worlds: every car learns; per-car termination (module docstring)."""
        E, k = self.env.num_envs, len(self.learning_robots)
        B = E * k
        first = self._learning_obs(self._obs)
        obs = {key: np.empty((steps + 1, *v.shape), v.dtype) for key, v in first.items()}
        width, dtype = action_width(self.agent)
        actions = np.zeros((steps, B, width), dtype)
        log_probs, values = np.zeros((steps, B), np.float32), np.zeros((steps + 1, B), np.float32)
        rewards, terms = np.zeros((steps, B), np.float32), np.zeros((steps, B, 4), np.float32)
        episode_end, truncated = np.zeros((steps, B), bool), np.zeros((steps, B), bool)
        final_values = np.zeros((steps, B), np.float32)
        starts, alive = np.zeros((steps + 1, B), bool), np.zeros((steps + 1, B), bool)
        teacher = np.zeros((steps, B, width), dtype) if self.with_teacher else None
        initial_state: State | None = None
        current = first
        for t in range(steps + 1):
            for key, v in current.items():
                obs[key][t] = v
            starts[t], alive[t] = self._starts, ~self._done
            acted = self.acting.step(current, self._starts, last=t == steps, want_state=t == 0)
            if t == 0:
                initial_state = acted.start_state
            if _record(acted, t, steps, values, actions, log_probs):
                break
            if teacher is not None:
                teacher[t] = flatten_robots(self._teacher, self.learning_robots)
            sent = actions[t].reshape(E, k, width)
            result = self.env.step(sent if dtype == np.int64 else     # normalised steering → rad/s
                                   driving_commands(sent, "continuous", self.env.config.cars.max_yaw_rate))
            live = alive[t]
            step_terms = flatten_robots(result.reward_terms.transpose(0, 2, 1), self.learning_robots)
            step_terms = np.where(live[:, None], step_terms, 0.0)          # a finished car earns nothing
            terms[t] = step_terms
            rewards[t] = step_terms.sum(-1) if self.reward_transform is None else self.reward_transform(step_terms)
            world_end = np.repeat(result.terminated | result.truncated, k)
            car_done = flatten_robots(result.agents_terminated, self.learning_robots)
            ended = live & (car_done | world_end)                            # this car's episode ends here
            episode_end[t] = ended | ~live                                   # dead steps: no return across them
            truncated[t] = live & ~car_done & np.repeat(result.truncated & ~result.terminated, k)
            if truncated[t].any():
                final_values[t] = self._final_values(result, truncated[t])
            self._account_driving(step_terms, ended, world_end, result)
            self._obs = result.observations
            if self.with_teacher:
                self._teacher = result.teacher_actions
            self._done = (self._done | car_done) & ~world_end
            self._starts = world_end.copy()          # the recurrent state restarts with the world's next episode
            current = self._learning_obs(self._obs)
        return Rollout(obs, actions, log_probs, values, rewards, terms, episode_end, truncated, final_values,
                       starts, alive.copy(), cast(State, initial_state), teacher_actions=teacher, alive=alive)

    def _account_driving(self, terms: np.ndarray, ended: np.ndarray, world_end: np.ndarray, result: Any) -> None:
        """Per-car episode sums; a finished car's record with ``home`` (finished, not crashed) and ``crashed``,
        read from its ego flags after its last step (the world's final observation when the world ended)."""
        self.episode_terms += terms
        self.episode_returns += terms.sum(-1)
        k = len(self.learning_robots)
        for r in np.flatnonzero(ended):
            e, car = int(r // k), int(self.learning_robots[r % k])
            source = result.final_observations[e] if world_end[r] else \
                {key: v[e] for key, v in result.observations.items()}
            ego = source["proprioception"][car, -1]
            crashed = bool(ego[EGO_CRASHED] > 0.5)
            t = self.episode_terms[r]
            self.finished.append({"return": float(self.episode_returns[r]), "primary": float(t[0]),
                                  "rule": float(t[1]), "auxiliary": float(t[2]), "observation": float(t[3]),
                                  "home": float(ego[EGO_FINISHED] > 0.5 and not crashed), "crashed": float(crashed)})
        self.episode_returns[ended] = 0.0
        self.episode_terms[ended] = 0.0

    def _final_values(self, result: Any, truncated: np.ndarray) -> np.ndarray:
        """V(final observation) for the robots of truncated worlds, from the state the episode left them in."""
        out = np.zeros(len(truncated), np.float32)
        rows = np.flatnonzero(truncated)
        k = len(self.learning_robots)
        final = {key: np.stack([result.final_observations[int(r // k)][key][self.learning_robots[r % k]]
                                for r in rows]) for key in self._obs}
        out[rows] = self.acting.final_values(final, rows)
        return out

    def _account(self, terms: np.ndarray, ended: np.ndarray) -> None:
        self.episode_terms += terms
        self.episode_returns += terms.sum(-1)
        self.episode_positive += np.maximum(terms, 0.0).sum(-1)
        for r in np.flatnonzero(ended & ~self.teacher_driven):     # the learner's own episodes only
            t = self.episode_terms[r]
            # the paper's metric (docs/original.md §6.1, §11): the positive parts of every term, per period, minus the
            # observation reward
            self.finished.append({"return": float(self.episode_returns[r]), "primary": float(t[0]),
                                  "rule": float(t[1]), "auxiliary": float(t[2]), "observation": float(t[3]),
                                  "paper_metric": float(self.episode_positive[r] - t[3])})
        self.episode_returns[ended] = 0.0
        self.episode_terms[ended] = 0.0
        self.episode_positive[ended] = 0.0
