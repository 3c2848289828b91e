"""Evaluate a soccer team policy against an opponent: many episodes per seed, seeds as the statistical unit.

ROS-free. A *team policy* drives the ``players_per_team`` robots of one side (``TeamPolicy``: ``reset`` at every
episode start, ``act`` once per motion period); both sides use the same interface, so any pairing works — a
checkpoint against ``random``, ``scripted`` or another checkpoint, and ``random`` or ``scripted`` as the evaluated
side too (baseline rows produced the same way)::

    result = evaluate("runs/agent.pt", "scripted", episodes=4, seeds=[0, 1, 2])
    print(format_table(result)); write_json(result, "results.json")      # write_json: evaluation.results

Policies (``make_team_policy``):

- a checkpoint path: ``load_policy(path)``; actions sampled from the policy (``greedy=True``: the most likely
  action); one recurrent state per robot, fresh at every episode start.
- ``"scripted"``: ``keeper_and_chasers`` (``soccer.scripted``: a goalkeeper in slot 0, chasers elsewhere; a team
  of one is a chaser), the default of ``dynenv-play`` and the nearer to a real SPL line-up; ``"chaser"`` and
  ``"keeper_and_chasers"`` name a kind explicitly.
- ``"perceiving"``: ``keeper_and_chasers`` on each robot's own padded observation and self-pose estimate
  (``soccer.perceiving``): the fair opponent of a learning agent, which sees no ground truth either;
  ``"perceiving_chasers"``: the same with chasers in every slot, the imitation teacher ``perceiving`` as a team.
- ``"random"``: every action dimension uniform over the env's action space, from a seeded generator.

Sides: with ``sides="alternate"`` (default) the evaluated team is team A in the even episodes of a seed and team B
in the odd ones (team A kicks off, as in the env), so neither the side nor the kick-off favours it; ``"a"`` or
``"b"`` fix the side.

Seeding: for seed s and episode e, ``SeedSequence(s, spawn_key=(e,))`` spawns three children — the env's reset
seed (world, physics noise, perception), the evaluated team's generator and the opponent's — so every episode is
reproducible on its own and the same call gives the same result; two policies evaluated with the same seeds meet
the same env seeds (common random numbers).

Per episode and side the record holds each reward term summed over the episode and averaged over the team's
robots, their total, the paper's metric (``paper_metric``), goals for and against, the result, and the team's
falls and penalties (counted from the world's ``fall`` and ``penalty`` events, so a robot that falls again while
getting up counts twice, and a penalty is counted when given). Per seed, each number is averaged over that seed's
episodes; the summary gives the mean and standard deviation over seeds.
"""
from __future__ import annotations

import copy
from types import SimpleNamespace
from typing import Any, Callable, Hashable, Iterable, Mapping, Sequence

import numpy as np

from dynenv_ros.evaluation.episodes import episode_seeds, load_evaluated_policy, sample_space
from dynenv_ros.evaluation.results import FORMAT, TERMS, float_mean, summarize
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.soccer.agent_actions import head_radians
from dynenv_ros.soccer.scripted import DEFAULT_SCRIPTED, SCRIPTED_KINDS, team_policies

OBSERVATION = RewardTerm.OBSERVATION.name.lower()
SIDES = ("alternate", "a", "b")
RESULTS = ("win", "draw", "loss")
# The team names make_team_policy knows (anything else is a checkpoint path).
TEAM_NAMES = ("random", "scripted", *SCRIPTED_KINDS, "perceiving", "perceiving_chasers")
# Per-seed numbers (means over the seed's episodes); ``compare`` metrics are these names.
SEED_METRICS = ("total", "paper_metric", "positive", *TERMS, "goals_for", "goals_against", "goal_difference",
                "win_rate", "draw_rate", "loss_rate", "falls", "penalties", "opponent_total",
                "opponent_paper_metric")


# -- the paper's metric ------------------------------------------------------------------------------------------
def positive_part(terms: Mapping[str, float]) -> float:
    """Σ over the reward terms of one robot and one env step of max(0, term)."""
    return float(sum(max(0.0, float(v)) for v in terms.values()))


def positive_reward(step_terms: Iterable[Mapping[str, float]]) -> float:
    """DynEnv's ``episode_p_r`` for one robot: the positive-only reward, Σ over env steps of ``positive_part``.

    DynEnv summed, per env step, the positive parts of the team reward and of the observation reward plus the
    positive personal rewards (docs/original.md §6.1). This world books the team share and the touch-chain share of a
    ball event into one term, so the positive part is taken per reward term (primary, rule, auxiliary, observation)
    and per env step (one motion period) — the same granularity as DynEnv's step, with team and personal parts
    of one step netted within a term.
    """
    return float(sum(positive_part(terms) for terms in step_terms))


def paper_metric(step_terms: Iterable[Mapping[str, float]]) -> float:
    """The RoboCup metric of the paper (docs/original.md §11): positive reward minus observation reward, for one robot
    and episode — ``positive_reward(step_terms)`` minus Σ over steps of the ``observation`` term. The observation
    reward is never negative, so this is Σ over steps and over the non-observation terms of max(0, term)."""
    steps = list(step_terms)
    return positive_reward(steps) - float(sum(float(t.get(OBSERVATION, 0.0)) for t in steps))


# -- team policies -----------------------------------------------------------------------------------------------
class TeamPolicy:
    """Drives one side. ``reset`` at each episode start with the env, the robot indexes it drives (into
    ``env.possible_agents``; team A is 0..n-1, team B n..2n-1) and its SeedSequence; ``act`` gets the padded
    observations of those robots in that order and returns one env action per robot. ``needs_localization``: the
    env steps every robot's self-pose estimate (``env.observations.vision.estimate``); its draws come from a
    generator of its own, so the episodes are the same with it on or off. ``observes_pose``: the observations must
    also carry it as ``pose_estimate`` (the env is made with ``localization="estimate"``; implies
    ``needs_localization``)."""

    kind = "team"
    needs_localization = False
    observes_pose = False

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind}

    def reset(self, env: Any, robots: Sequence[int], seed: np.random.SeedSequence) -> None:
        raise NotImplementedError

    def act(self, env: Any, observations: Sequence[Mapping[str, np.ndarray]]) -> list[Any]:
        raise NotImplementedError

    def for_another_game(self) -> "TeamPolicy":
        """The same team for a game played at the same time as this one's (``evaluate``'s ``games_at_once``):
        a shallow copy, sharing what never changes (a checkpoint's network) and getting its own per-game state from
        its own ``reset``."""
        return copy.copy(self)

    def batch_key(self) -> Hashable | None:
        """Teams with one key (not None) act in one ``act_together`` call when their games are played at once."""
        return None

    @classmethod
    def act_together(cls, teams: Sequence["TeamPolicy"], envs: Sequence[Any],
                     observations: Sequence[Sequence[Mapping[str, np.ndarray]]]) -> list[list[Any]]:
        """Each team's ``act`` for its own game; a team with a ``batch_key`` does it in one call for them all."""
        return [team.act(env, obs) for team, env, obs in zip(teams, envs, observations)]


class RandomTeam(TeamPolicy):
    """Each robot's action uniform over the env's action space (every dimension independent)."""

    kind = "random"

    def reset(self, env, robots, seed):
        self.rng = np.random.default_rng(seed)
        self.spaces = [env.action_space(env.possible_agents[i]) for i in robots]

    def act(self, env, observations):
        return [sample_space(space, self.rng) for space in self.spaces]


class ScriptedTeam(TeamPolicy):
    """A team of ``soccer.scripted`` policies (they read the ground-truth snapshot, not the observations)."""

    kind = "scripted"

    def __init__(self, team: str = DEFAULT_SCRIPTED) -> None:
        if team not in SCRIPTED_KINDS:
            raise ValueError(f"scripted team must be one of {', '.join(SCRIPTED_KINDS)}, got {team!r}")
        self.team = team

    def describe(self):
        return {"kind": self.kind, "team": self.team}

    def reset(self, env, robots, seed):
        c = env.config
        policies = team_policies(c.players_per_team, self.team, np.random.default_rng(seed), field=c.field,
                                 head_mode=c.head_mode, motion=c.motion)
        self.robots = list(robots)
        self.policies = [policies[i] for i in self.robots]

    def act(self, env, observations):
        snapshot = env.world.snapshot()
        return [policy.act(snapshot, i) for policy, i in zip(self.policies, self.robots)]


class PerceivingTeam(TeamPolicy):
    """``keeper_and_chasers`` on each robot's own observation and self-pose estimate (``soccer.perceiving``), not on
    the ground truth: the opponent that knows only what a robot can know."""

    kind = "perceiving"
    needs_localization = True
    roles = "keeper_and_chasers"

    def reset(self, env, robots, seed):
        from dynenv_ros.soccer.perceiving import perceiving_team
        c = env.config
        team = perceiving_team(c.players_per_team, c.period_seconds, field=c.field, motion=c.motion,
                               kind=self.roles)
        self.robots = list(robots)
        self.policies = [team[i] for i in self.robots]
        for policy in self.policies:
            policy.reset()

    def act(self, env, observations):
        estimate = env.observations.vision.estimate
        return [policy.act(observation, estimate[i])
                for policy, i, observation in zip(self.policies, self.robots, observations)]


class PerceivingChasersTeam(PerceivingTeam):
    """Perceiving chasers in every slot: the imitation teacher ``perceiving`` (``envs.teacher``) played as a team,
    so that what imitating it can reach is measured against the perceiving keeper and chasers."""

    kind = "perceiving_chasers"
    roles = "chaser"


class AgentTeam(TeamPolicy):
    """A ``DynEnvAgent`` driving every robot of the side in one batch, one recurrent state per robot (fresh at each
    episode start); stochastic from a seeded torch generator unless ``greedy``. Needs padded observations."""

    kind = "checkpoint"

    def __init__(self, model: Any, greedy: bool = False, path: str | None = None,
                 sha256: str | None = None) -> None:
        self.model = model.eval()
        self.greedy = bool(greedy)
        self.path, self.sha256 = path, sha256
        # a checkpoint trained with localization: estimate reads pose_estimate from its observations
        self.observes_pose = self.needs_localization = bool(getattr(model, "uses_pose", False))

    def describe(self):
        described = {"kind": self.kind, "path": self.path, "sha256": self.sha256, "greedy": self.greedy}
        if self.observes_pose:
            described["uses_pose"] = True
        return described

    def reset(self, env, robots, seed):
        import torch
        self.n = len(robots)
        self.state = self.model.initial_state(self.n)
        self.generator = torch.Generator().manual_seed(int(seed.generate_state(1, np.uint32)[0]))
        self.env_head_max = float(env.config.motion.head_max_delta)

    def act(self, env, observations):
        return AgentTeam.act_together([self], [env], [observations])[0]

    def batch_key(self):
        return (id(self.model), self.greedy, self.observes_pose)

    @classmethod
    def act_together(cls, teams, envs, observations):
        """One forward of every team's robots (teams sharing one network: ``batch_key``), then each team's actions
        drawn from its own generator over its own rows, as its own ``act`` would: a game's actions do not depend on
        which games are played beside it (up to the float rounding of a larger batch's products)."""
        import torch
        from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
        from dynenv_ros.learning.algo.policy import head_outputs
        teams = list(teams)
        if len({team.batch_key() for team in teams}) != 1:
            raise ValueError("AgentTeam.act_together needs teams of one network (one batch_key)")
        for team, obs in zip(teams, observations):
            if len(obs) != team.n:
                raise ValueError(f"AgentTeam drives {team.n} robots, got {len(obs)} observations")
            if not all(isinstance(o, Mapping) and "landmarks" in o for o in obs):
                raise ValueError("AgentTeam needs padded observations (robocup_v0 observation='padded')")
        first, rows = teams[0], [o for obs in observations for o in obs]
        batch = {key: np.stack([np.asarray(o[key]) for o in rows]) for key in rows[0]}
        head_max = float(first.model.head_max)
        sizes = [team.n for team in teams]
        state = tuple(torch.cat(parts) for parts in zip(*(team.state for team in teams))) if len(teams) > 1 \
            else first.state
        with torch.inference_mode():
            landmarks, objects = streams_from_padded(batch)
            previous, proprioception = side_inputs(batch, head_max, pose=first.observes_pose)
            step = first.model(landmarks, objects, previous, proprioception, state)
            heads = vars(head_outputs(step))
            units = _head_units(first.model, step)
            out, start = [], 0
            for team, states in zip(teams, zip(*(s.split(sizes) for s in step.state))):
                rows_of = slice(start, start + team.n)
                start += team.n
                own = SimpleNamespace(**{k: None if v is None else v[rows_of] for k, v in heads.items()})
                actions = first.model.act(own, generator=team.generator, greedy=team.greedy).numpy()
                team.state = tuple(states) if len(teams) > 1 else step.state
                out.append(team._soccer_actions(actions, units, head_max))
        return out

    def _soccer_actions(self, actions: np.ndarray, units: int, head_max: float) -> list[Any]:
        from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
        result = []
        for walk, turn, kick, head in actions:
            # The checkpoint's own head discretisation: index 0..2u ↦ (index − u)·head_max/u rad per period.
            delta = head_radians(int(head), units, head_max=head_max) if units else float(head)
            delta = max(-self.env_head_max, min(self.env_head_max, delta))
            result.append(SoccerAction(Walk(int(walk)), Turn(int(turn)), Kick(int(kick)), delta))
        return result


def _head_units(model: Any, step: Any) -> int:
    """Head units of a discrete-head model (0 for a continuous head)."""
    if getattr(model, "head_mode", "discrete") != "discrete":
        return 0
    units = getattr(model, "head_units", None)
    if units is None:
        units = (int(step.head.shape[-1]) - 1) // 2
    return int(units)


def make_team_policy(spec: str | TeamPolicy, greedy: bool = False) -> TeamPolicy:
    """``"random"``, ``"scripted"`` (= ``keeper_and_chasers``), ``"chaser"``, ``"keeper_and_chasers"`` or a
    checkpoint path (loaded with ``load_policy``; its ValueError passes through). A TeamPolicy is returned
    as is."""
    if isinstance(spec, TeamPolicy):
        return spec
    if spec == "random":
        return RandomTeam()
    if spec == "scripted":
        return ScriptedTeam(DEFAULT_SCRIPTED)
    if spec == "perceiving":
        return PerceivingTeam()
    if spec == "perceiving_chasers":
        return PerceivingChasersTeam()
    if spec in SCRIPTED_KINDS:
        return ScriptedTeam(spec)
    model, digest = load_evaluated_policy(spec)
    from dynenv_ros.scenarios import SOCCER         # here: torch is loaded with the policy, not with this module
    problem = SOCCER.evaluation_problem(model)
    if problem:
        raise ValueError(f"{spec} {problem}")
    return AgentTeam(model, greedy=greedy, path=str(spec), sha256=digest)


# -- one episode -------------------------------------------------------------------------------------------------
class _Game:
    """One episode in progress: its env, its two teams and what is counted of it (``play_episode``'s numbers)."""

    def __init__(self, env: Any, team_a: TeamPolicy, team_b: TeamPolicy, env_seed: int,
                 seed_a: np.random.SeedSequence, seed_b: np.random.SeedSequence, kickoff: str = "a") -> None:
        self.env = env
        n = env.config.players_per_team
        self.robots = {"a": list(range(n)), "b": list(range(n, 2 * n))}
        self.observations, _ = env.reset(seed=env_seed, options={"kickoff_team": kickoff})
        self.names = names = env.possible_agents
        team_a.reset(env, self.robots["a"], seed_a)
        team_b.reset(env, self.robots["b"], seed_b)
        self.teams = {"a": team_a, "b": team_b}
        self.terms = np.zeros((len(names), len(TERMS)))
        self.positive = np.zeros(len(names))
        self.falls = np.zeros(len(names), np.int64)
        self.penalties = np.zeros(len(names), np.int64)
        self.periods = 0
        self.actions: dict[str, Any] = {}

    @property
    def over(self) -> bool:
        return not self.env.agents

    def observed_by(self, side: str) -> list[Mapping[str, np.ndarray]]:
        return [self.observations[self.names[i]] for i in self.robots[side]]

    def chose(self, side: str, chosen: Sequence[Any]) -> None:
        n = len(self.robots[side])
        if len(chosen) != n:
            raise ValueError(f"team {side} returned {len(chosen)} actions for {n} robots")
        self.actions.update({self.names[i]: a for i, a in zip(self.robots[side], chosen)})

    def step(self) -> None:
        """The env step of both sides' chosen actions, and its counts."""
        self.observations, _, _, _, infos = self.env.step(self.actions)
        self.actions = {}
        self.periods += 1
        for i, name in enumerate(self.names):
            step_terms = {t: float(infos[name]["reward_terms"][t]) for t in TERMS}
            self.terms[i] += list(step_terms.values())
            self.positive[i] += positive_part(step_terms)
        for event in self.env.world.events:
            if event.robot is not None and event.kind == "fall":
                self.falls[event.robot] += 1
            elif event.robot is not None and event.kind == "penalty":
                self.penalties[event.robot] += 1

    def outcome(self) -> dict[str, Any]:
        snapshot = self.env.world.snapshot()
        goals = {"a": int(snapshot.score_team_a), "b": int(snapshot.score_team_b)}
        observation = self.terms[:, TERMS.index(OBSERVATION)]
        out: dict[str, Any] = {"periods": self.periods}
        for side, other in (("a", "b"), ("b", "a")):
            idx = self.robots[side]
            out[side] = {"terms": {t: float(self.terms[idx, k].mean()) for k, t in enumerate(TERMS)},
                         "total": float(self.terms[idx].sum(axis=1).mean()),
                         "positive": float(self.positive[idx].mean()),
                         "paper_metric": float((self.positive[idx] - observation[idx]).mean()),
                         "goals_for": goals[side], "goals_against": goals[other],
                         "falls": int(self.falls[idx].sum()), "penalties": int(self.penalties[idx].sum())}
        return out


def play_games(games: Sequence[_Game]) -> list[dict[str, Any]]:
    """Step every game, period by period, until each is over; each period the teams that share a ``batch_key``
    act in one call (one forward of a network for every game's robots). Gives each game's ``play_episode`` record."""
    games = list(games)
    while True:
        live = [game for game in games if not game.over]
        if not live:
            break
        requests = [(game, side) for game in live for side in ("a", "b")]
        groups: dict[Any, list[tuple[_Game, str]]] = {}
        for game, side in requests:
            key = game.teams[side].batch_key()
            groups.setdefault(("alone", id(game), side) if key is None else ("together", key), []).append((game, side))
        for members in groups.values():
            teams = [game.teams[side] for game, side in members]
            chosen = type(teams[0]).act_together(teams, [game.env for game, _ in members],
                                                 [game.observed_by(side) for game, side in members])
            for (game, side), actions in zip(members, chosen):
                game.chose(side, actions)
        for game in live:
            game.step()
    return [game.outcome() for game in games]


def play_episode(env: Any, team_a: TeamPolicy, team_b: TeamPolicy, env_seed: int,
                 seed_a: np.random.SeedSequence, seed_b: np.random.SeedSequence,
                 kickoff: str = "a") -> dict[str, Any]:
    """One episode of ``team_a`` (robots 0..n-1) against ``team_b``; per side: terms, total, positive and paper
    metric (each summed over the episode, averaged over the side's robots), goals, falls and penalties."""
    return play_games([_Game(env, team_a, team_b, env_seed, seed_a, seed_b, kickoff)])[0]


def _result(goals_for: int, goals_against: int) -> str:
    return "win" if goals_for > goals_against else "loss" if goals_for < goals_against else "draw"


# -- evaluation --------------------------------------------------------------------------------------------------
def evaluate(evaluated: str | TeamPolicy, opponent: str | TeamPolicy, *, episodes: int = 4,
             seeds: Sequence[int] = (0, 1, 2), players_per_team: int = 2, perception: Any = "realistic",
             sides: str = "alternate", greedy: bool = False, env_config: Mapping[str, Any] | None = None,
             progress: Callable[[str], None] | None = None, torch_threads: int | None = 1,
             games_at_once: int = 1) -> dict[str, Any]:
    """Play ``episodes`` episodes per seed of ``evaluated`` against ``opponent`` (specs for ``make_team_policy``
    or TeamPolicy instances; ``greedy`` applies to checkpoints given by path). ``env_config``: further
    ``SoccerConfig`` settings (e.g. ``{"episode_seconds": 30}``). Returns the JSON-ready result: ``settings``,
    ``evaluated`` / ``opponent`` descriptions, ``episodes`` (every record), ``per_seed`` (means over each seed's
    episodes), ``summary`` (mean, sd and n over seeds of each per-seed number) and ``counts`` (wins, draws,
    losses, episodes).

    ``torch_threads``: torch's intra-op threads while a checkpoint plays (restored afterwards; None leaves them
    alone). One thread is the default: a period's batch is a team of robots, far too small to split, and on busy
    cores several threads made each decision 50 times slower (200 ms instead of 4 ms).

    ``games_at_once``: how many of the games (in their order: seed by seed, episode by episode) are played side by
    side, each in its own env, a checkpoint's robots of all of them in one forward per period. The games and their
    records are the same (each game keeps its own env seed and generators); only the float rounding of the larger
    batch's products differs, which could tip a near-tie between two actions (none has been seen: the records so far
    were equal to the last digit). A checkpoint's forward of a team of two costs nearly as much as one of forty
    robots: 20 games at once took 2.5 times less CPU time than one by one (docs/benchmarks.md, "Evaluation: games at
    once")."""
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    seeds = list(seeds)
    if not seeds:
        raise ValueError("give at least one seed")
    for seed in seeds:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seeds must be non-negative integers, got {seed!r}")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct, got {seeds}")
    if sides not in SIDES:
        raise ValueError(f"sides must be one of {', '.join(SIDES)}, got {sides!r}")
    if isinstance(games_at_once, bool) or not isinstance(games_at_once, (int, np.integer)) or games_at_once < 1:
        raise ValueError(f"games_at_once must be a positive integer, got {games_at_once!r}")
    config = dict(env_config or {})
    for key in ("players_per_team", "observation", "perception", "render_mode", "localization"):
        if key in config:
            raise ValueError(f"env_config must not set {key!r}; it is an argument of evaluate")
    ours, theirs = make_team_policy(evaluated, greedy), make_team_policy(opponent, greedy)
    if ours is theirs:
        raise ValueError("the evaluated team and the opponent must be two TeamPolicy instances")
    if torch_threads is not None and (isinstance(ours, AgentTeam) or isinstance(theirs, AgentTeam)):
        import torch
        threads = torch.get_num_threads()
        torch.set_num_threads(int(torch_threads))
        try:
            return _evaluate(ours, theirs, evaluated, opponent, episodes, seeds, players_per_team, perception,
                             sides, greedy, config, progress, int(games_at_once))
        finally:
            torch.set_num_threads(threads)
    return _evaluate(ours, theirs, evaluated, opponent, episodes, seeds, players_per_team, perception, sides, greedy,
                     config, progress, int(games_at_once))


def _evaluate(ours: TeamPolicy, theirs: TeamPolicy, evaluated: str | TeamPolicy, opponent: str | TeamPolicy,
              episodes: int, seeds: list[int], players_per_team: int, perception: Any, sides: str, greedy: bool,
              config: dict[str, Any], progress: Callable[[str], None] | None, games_at_once: int) -> dict[str, Any]:
    from dynenv_ros.envs.robocup_v0 import parallel_env
    observed = ours.observes_pose or theirs.observes_pose
    jobs = [(int(seed), episode) for seed in seeds for episode in range(int(episodes))]
    at_once = min(games_at_once, len(jobs))
    envs = []
    for _ in range(at_once):
        env = parallel_env(players_per_team=players_per_team, observation="padded", perception=perception,
                           localization="estimate" if observed else "none", **config)
        env.observations.localization = ours.needs_localization or theirs.needs_localization or observed
        envs.append(env)
    # one pair of teams per env: a team holds its game's state between reset and the game's end
    pairs = [(ours, theirs)] + [(ours.for_another_game(), theirs.for_another_game()) for _ in range(at_once - 1)]
    records = []
    for first in range(0, len(jobs), at_once):
        games, sides_of = [], []
        for (seed, episode), env, (evaluated_team, opponent_team) in zip(jobs[first:first + at_once], envs, pairs):
            env_seed, our_seed, their_seed = episode_seeds(seed, episode)
            side = sides if sides != "alternate" else ("a" if episode % 2 == 0 else "b")
            games.append(_Game(env, evaluated_team, opponent_team, env_seed, our_seed, their_seed) if side == "a"
                         else _Game(env, opponent_team, evaluated_team, env_seed, their_seed, our_seed))
            sides_of.append((seed, episode, side, env_seed))
        for (seed, episode, side, env_seed), game in zip(sides_of, play_games(games)):
            mine, other = game[side], game["b" if side == "a" else "a"]
            record = {"seed": seed, "episode": episode, "side": side, "env_seed": env_seed, "kickoff": "a",
                      "periods": game["periods"], **mine,
                      "result": _result(mine["goals_for"], mine["goals_against"]),
                      "opponent": {k: other[k] for k in ("terms", "total", "positive", "paper_metric", "falls",
                                                         "penalties")}}
            records.append(record)
            if progress is not None:
                progress(f"seed {seed} episode {episode} ({side}): {record['result']} "
                         f"{mine['goals_for']}:{mine['goals_against']}, total {mine['total']:.2f}")
    per_seed = [seed_means(int(seed), [r for r in records if r["seed"] == int(seed)]) for seed in seeds]
    settings = {"episodes": int(episodes), "seeds": [int(s) for s in seeds], "players_per_team": players_per_team,
                "perception": perception, "sides": sides, "greedy": bool(greedy), "env_config": config,
                "scripted_default": DEFAULT_SCRIPTED,
                "seeding": "SeedSequence(seed, spawn_key=(episode,)).spawn(3) -> env, evaluated, opponent"}
    if games_at_once > 1:
        settings["games_at_once"] = games_at_once
    return {"format": FORMAT, "settings": settings,
            "evaluated": {"spec": _spec_name(evaluated), **ours.describe()},
            "opponent": {"spec": _spec_name(opponent), **theirs.describe()},
            "episodes": records, "per_seed": per_seed, "summary": summarize(per_seed, SEED_METRICS),
            "counts": {"episodes": len(records), "wins": sum(r["result"] == "win" for r in records),
                       "draws": sum(r["result"] == "draw" for r in records),
                       "losses": sum(r["result"] == "loss" for r in records)}}


def _spec_name(spec: str | TeamPolicy) -> str:
    return spec if isinstance(spec, str) else type(spec).__name__


def seed_means(seed: int, records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One seed's numbers (``SEED_METRICS``), each the mean over its episode records."""
    row: dict[str, Any] = {"seed": seed, "episodes": len(records)}
    row["total"] = float_mean(r["total"] for r in records)
    row["paper_metric"] = float_mean(r["paper_metric"] for r in records)
    row["positive"] = float_mean(r["positive"] for r in records)
    for term in TERMS:
        row[term] = float_mean(r["terms"][term] for r in records)
    row["goals_for"] = float_mean(r["goals_for"] for r in records)
    row["goals_against"] = float_mean(r["goals_against"] for r in records)
    row["goal_difference"] = float_mean(r["goals_for"] - r["goals_against"] for r in records)
    for result in RESULTS:
        row[f"{result}_rate"] = float_mean(r["result"] == result for r in records)
    row["falls"] = float_mean(r["falls"] for r in records)
    row["penalties"] = float_mean(r["penalties"] for r in records)
    row["opponent_total"] = float_mean(r["opponent"]["total"] for r in records)
    row["opponent_paper_metric"] = float_mean(r["opponent"]["paper_metric"] for r in records)
    return row


# -- output ------------------------------------------------------------------------------------------------------
def format_table(result: Mapping[str, Any]) -> str:
    """A Markdown table: one row per seed and a mean ± sd row over seeds."""
    ev, op = result["evaluated"], result["opponent"]
    columns = [("W/D/L", None), ("GF", "goals_for"), ("GA", "goals_against"), ("total", "total"),
               ("paper", "paper_metric"), ("obs", OBSERVATION), ("falls", "falls"), ("pen", "penalties")]
    lines = [f"{ev['spec']} vs {op['spec']}: {result['settings']['episodes']} episodes x "
             f"{len(result['per_seed'])} seeds, {result['settings']['players_per_team']} per team, "
             f"sides {result['settings']['sides']}", "",
             "| seed | " + " | ".join(name for name, _ in columns) + " |",
             "|---:|" + "---:|" * len(columns)]
    for row in result["per_seed"]:
        n = row["episodes"]
        wdl = "/".join(str(round(row[f"{r}_rate"] * n)) for r in RESULTS)
        cells = [wdl] + [f"{row[key]:.3g}" if abs(row[key]) < 1000 else f"{row[key]:.4g}"
                         for _, key in columns[1:]]
        lines.append(f"| {row['seed']} | " + " | ".join(cells) + " |")
    summary, counts = result["summary"], result["counts"]
    wdl = f"{counts['wins']}/{counts['draws']}/{counts['losses']}"
    cells = [wdl] + [_mean_sd(summary[key]) for _, key in columns[1:]]
    lines.append("| mean ± sd | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _mean_sd(stats: Mapping[str, float]) -> str:
    return f"{stats['mean']:.3g} ± {stats['sd']:.2g}"


__all__ = ["TeamPolicy", "RandomTeam", "ScriptedTeam", "AgentTeam", "PerceivingTeam",
           "PerceivingChasersTeam", "make_team_policy", "play_episode", "play_games", "evaluate",
           "seed_means", "format_table", "positive_part", "positive_reward", "paper_metric", "SEED_METRICS", "RESULTS",
           "SIDES"]
