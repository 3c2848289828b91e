"""Evaluate a driving policy: many episodes per seed, seeds as the statistical unit (``dynenv-eval --scenario
driving``). ROS-free; the soccer evaluation's JSON format, so ``dynenv-eval compare`` (BEST) works on it.

What "against random" and "against scripted" mean for driving: there is no opposing team. The evaluated driver
drives **every car** of the world (``n_cars``, 2 as in the paper); a baseline is another driver driving the same
cars in the same episodes — the same env seeds (common random numbers: same spawn spots, destinations, car types,
pedestrians and obstacles). So a checkpoint is compared with ``random`` and with ``scripted`` by evaluating each of
the three with the same ``--episodes`` and ``--seeds`` and comparing the JSON files (``dynenv-eval compare``)::

    result = evaluate_driving("runs/driving/pred_s0/policy.safetensors", episodes=4, seeds=[0, 1, 2])
    print(format_driving_table(result)); write_json(result, "pred.json")    # write_json: evaluation.results

Drivers (``make_driver``):

- a checkpoint path (a driving policy, ``scenario: driving``; a soccer policy is refused): one recurrent state per
  car, fresh at every episode start; actions sampled (``greedy``: the most likely); the checkpoint's action mode
  sets the env's.
- ``"random"``: each car's action uniform over its action space (discrete: acceleration and steering each uniform
  over 3; continuous: throttle, brake, steering uniform in their bounds), from a seeded generator.
- ``"scripted"``: ``driving.scripted.ScriptedDriver`` reading the world's ground truth (not the observations).

Per episode the record holds, per car and then averaged over the cars: each reward term summed over the episode,
their total (``total``; the paper's driving figure is this per-car episode reward: random 0.7, Pred 26.47, so
``paper_metric`` = ``total`` here), and counts over the cars: ``cars_home`` (reached their destination without
crashing), ``crashes`` (cars crashed). Per seed: means over its episodes, with ``home_rate`` and ``crash_rate`` the
fractions of cars; the summary: mean, sd and n over seeds.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from dynenv_ros.evaluation.episodes import episode_seeds, load_evaluated_policy, sample_space
from dynenv_ros.evaluation.results import FORMAT, TERMS, float_mean, summarize

SEED_METRICS = ("total", "paper_metric", *TERMS, "cars_home", "crashes", "home_rate", "crash_rate", "periods")
DRIVER_KINDS = ("random", "scripted")


class Driver:
    """Drives every car. ``reset`` at each episode start with the env and a SeedSequence; ``act`` gets the padded
    observations of the cars still driving (``env.agents``) and returns one action per such car."""

    kind = "driver"
    action_mode: str | None = None        # None: any (the env's); a checkpoint's own otherwise

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind}

    def reset(self, env: Any, seed: np.random.SeedSequence) -> None:
        raise NotImplementedError

    def act(self, env: Any, observations: Mapping[str, Mapping[str, np.ndarray]]) -> dict[str, Any]:
        raise NotImplementedError


class RandomDriver(Driver):
    kind = "random"

    def reset(self, env, seed):
        self.rng = np.random.default_rng(seed)

    def act(self, env, observations):
        return {name: sample_space(env.action_space(name), self.rng) for name in observations}


class ScriptedDrivers(Driver):
    kind = "scripted"

    def reset(self, env, seed):
        from dynenv_ros.driving.scripted import ScriptedDriver
        self.driver = ScriptedDriver(env.config)

    def act(self, env, observations):
        actions = self.driver.actions(env.world)
        return {name: actions[env.possible_agents.index(name)] for name in observations}


class AgentDrivers(Driver):
    """A driving ``DynEnvAgent`` driving every car in one batch, one recurrent state per car."""

    kind = "checkpoint"

    def __init__(self, model: Any, greedy: bool = False, path: str | None = None, sha256: str | None = None) -> None:
        from dynenv_ros.scenarios import DRIVING       # here: torch is loaded with the policy, not with this module
        problem = DRIVING.evaluation_problem(model)
        if problem:
            raise ValueError(f"{path or 'the policy'} {problem}")
        self.model, self.greedy, self.path, self.sha256 = model.eval(), bool(greedy), path, sha256
        self.action_mode = model.action_mode

    def describe(self):
        return {"kind": self.kind, "path": self.path, "sha256": self.sha256, "greedy": self.greedy,
                "action_mode": self.action_mode}

    def reset(self, env, seed):
        import torch
        from dynenv_ros.envs.driving_observations import driving_layout_spec
        self.state = self.model.initial_state(len(env.possible_agents))
        self.generator = torch.Generator().manual_seed(int(seed.generate_state(1, np.uint32)[0]))
        self.spec = driving_layout_spec(env.config)
        self.limit = float(env.config.cars.max_yaw_rate)

    def act(self, env, observations):
        import torch
        from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
        names = list(observations)
        rows = torch.tensor([env.possible_agents.index(n) for n in names])
        batch = {key: np.stack([np.asarray(observations[n][key]) for n in names]) for key in observations[names[0]]}
        with torch.inference_mode():
            static, objects = streams_from_padded(batch, self.spec)
            previous, self_state = side_inputs(batch, None, self.spec)
            state = tuple(s[rows] for s in self.state)
            step = self.model(static, objects, previous, self_state, state)
            actions = self.model.act(step, generator=self.generator, greedy=self.greedy).numpy()
        for full, new in zip(self.state, step.state):
            full[rows] = new
        if self.action_mode == "discrete":
            return {n: a.astype(np.int64) for n, a in zip(names, actions)}
        scale = np.array([1.0, 1.0, self.limit])
        return {n: (a.astype(np.float64) * scale).astype(np.float32) for n, a in zip(names, actions)}


def make_driver(spec: str | Driver, greedy: bool = False) -> Driver:
    """``"random"``, ``"scripted"``, a driving policy file or a training checkpoint folder
    (``episodes.load_evaluated_policy``); a Driver is returned as is."""
    if isinstance(spec, Driver):
        return spec
    if spec == "random":
        return RandomDriver()
    if spec == "scripted":
        return ScriptedDrivers()
    model, digest = load_evaluated_policy(spec)
    return AgentDrivers(model, greedy=greedy, path=str(spec), sha256=digest)


def play_driving_episode(env: Any, driver: Driver, env_seed: int, seed: np.random.SeedSequence) -> dict[str, Any]:
    """One episode of ``driver`` driving every car; per car terms and flags, then their means and counts."""
    observations, infos = env.reset(seed=env_seed)
    driver.reset(env, seed)
    names = env.possible_agents
    terms = np.zeros((len(names), len(TERMS)))
    status = {name: infos[name] for name in names}
    periods = 0
    while env.agents:
        actions = driver.act(env, {name: observations[name] for name in env.agents})
        observations, _, _, _, infos = env.step(actions)
        periods += 1
        for name, info in infos.items():
            i = names.index(name)
            terms[i] += [float(info["reward_terms"][t]) for t in TERMS]
            status[name] = info
    home = [bool(status[n]["at_goal"]) and not bool(status[n]["crashed"]) for n in names]
    crashed = [bool(status[n]["crashed"]) for n in names]
    total = terms.sum(axis=1)
    return {"periods": periods, "terms": {t: float(terms[:, k].mean()) for k, t in enumerate(TERMS)},
            "total": float(total.mean()), "paper_metric": float(total.mean()),
            "cars_home": int(sum(home)), "crashes": int(sum(crashed)),
            "cars": [{"total": float(total[i]), "home": home[i], "crashed": crashed[i]} for i in range(len(names))]}


def evaluate_driving(driver: str | Driver, *, episodes: int = 4, seeds: Sequence[int] = (0, 1, 2), n_cars: int = 2,
                     perception: Any = "realistic", action_mode: str | None = None, greedy: bool = False,
                     env_config: Mapping[str, Any] | None = None, progress: Callable[[str], None] | None = None,
                     torch_threads: int | None = 1) -> dict[str, Any]:
    """Play ``episodes`` episodes per seed with ``driver`` driving all ``n_cars`` cars (module docstring); returns
    the JSON-ready result (``format`` dynenv_eval/1, ``scenario`` driving): ``settings``, ``evaluated``,
    ``episodes``, ``per_seed``, ``summary``. ``action_mode``: the env's (random and scripted; default discrete);
    a checkpoint brings its own and a different one given here is refused. ``env_config``: further
    ``DrivingConfig`` settings (e.g. ``{"episode_seconds": 30}``)."""
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    seeds = list(seeds)
    if not seeds or len(set(seeds)) != len(seeds) or any(
            isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0 for s in seeds):
        raise ValueError(f"seeds must be distinct non-negative integers, got {seeds}")
    config = dict(env_config or {})
    for key in ("n_cars", "action_mode", "observation", "perception", "render_mode"):
        if key in config:
            raise ValueError(f"env_config must not set {key!r}; it is an argument of evaluate_driving")
    ours = make_driver(driver, greedy)
    if ours.action_mode is not None:
        if action_mode is not None and action_mode != ours.action_mode:
            raise ValueError(f"the policy acts in action mode {ours.action_mode!r}, not {action_mode!r}")
        action_mode = ours.action_mode
    action_mode = action_mode or "discrete"
    from dynenv_ros.envs.driving_v0 import parallel_env
    env = parallel_env(n_cars=n_cars, action_mode=action_mode, observation="padded", perception=perception,
                       **config)
    threads = None
    if torch_threads is not None and isinstance(ours, AgentDrivers):
        import torch
        threads = torch.get_num_threads()
        torch.set_num_threads(int(torch_threads))
    try:
        records = []
        for seed in seeds:
            for episode in range(int(episodes)):
                env_seed, our_seed, _ = episode_seeds(int(seed), episode)
                game = play_driving_episode(env, ours, env_seed, our_seed)
                records.append({"seed": int(seed), "episode": episode, "env_seed": env_seed, **game})
                if progress is not None:
                    progress(f"seed {seed} episode {episode}: total {game['total']:.2f}, home {game['cars_home']}"
                             f"/{n_cars}, crashes {game['crashes']}, {game['periods']} periods")
    finally:
        if threads is not None:
            import torch
            torch.set_num_threads(threads)
        env.close()
    per_seed = [driving_seed_means(seed, [r for r in records if r["seed"] == seed], n_cars) for seed in seeds]
    spec = driver if isinstance(driver, str) else type(driver).__name__
    return {"format": FORMAT, "scenario": "driving",
            "settings": {"episodes": int(episodes), "seeds": seeds, "n_cars": n_cars, "perception": perception,
                         "action_mode": action_mode, "greedy": greedy, "env_config": config},
            "evaluated": {"spec": spec, **ours.describe()},
            "episodes": records, "per_seed": per_seed, "summary": summarize(per_seed, SEED_METRICS)}


def driving_seed_means(seed: int, records: Sequence[Mapping[str, Any]], n_cars: int) -> dict[str, Any]:
    row: dict[str, Any] = {"seed": seed, "episodes": len(records)}
    for key in ("total", "paper_metric", "cars_home", "crashes", "periods"):
        row[key] = float_mean(r[key] for r in records)
    for term in TERMS:
        row[term] = float_mean(r["terms"][term] for r in records)
    row["home_rate"] = row["cars_home"] / n_cars
    row["crash_rate"] = row["crashes"] / n_cars
    return row


def format_driving_table(result: Mapping[str, Any]) -> str:
    """A Markdown table: one row per seed and a mean ± sd row over seeds (rewards per car per episode)."""
    s = result["settings"]
    columns = [("total", "total"), ("primary", "primary"), ("rule", "rule"), ("progress", "auxiliary"),
               ("home", "home_rate"), ("crashed", "crash_rate"), ("periods", "periods")]
    lines = [f"{result['evaluated']['spec']} driving {s['n_cars']} cars ({s['action_mode']}): {s['episodes']} "
             f"episodes x {len(result['per_seed'])} seeds; rewards per car per episode, home/crashed fractions of "
             f"cars", "",
             "| seed | " + " | ".join(name for name, _ in columns) + " |", "|---:|" + "---:|" * len(columns)]
    for row in result["per_seed"]:
        lines.append(f"| {row['seed']} | " + " | ".join(f"{row[key]:.3g}" for _, key in columns) + " |")
    summary = result["summary"]
    lines.append("| mean ± sd | " + " | ".join(f"{summary[k]['mean']:.3g} ± {summary[k]['sd']:.2g}"
                                                for _, k in columns) + " |")
    return "\n".join(lines)


__all__ = ["Driver", "RandomDriver", "ScriptedDrivers", "AgentDrivers", "make_driver", "play_driving_episode",
           "evaluate_driving", "format_driving_table", "SEED_METRICS", "DRIVER_KINDS"]
