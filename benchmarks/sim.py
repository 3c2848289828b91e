"""dynenv-bench sim: env steps per second and peak memory of the in-process simulator.

One env step is one motion period (50 physics ticks by default) for every robot; for ``--scenario driving`` one
100 ms period (10 ticks) of every car (``--observation none``: the world alone; ``full`` / ``partial``: the whole
``driving_v0`` step, ``partial`` with the driving perception preset ``--perception``). Random high-level actions come from a pre-drawn pool, so the policy costs
nothing; the first 50 steps warm up and are not timed.

Without ``--observation`` it times the step training runs: the whole env step with realistic perception, ``partial``
for one world (the layout of the original's partial step), ``padded`` for a batch (``--envs > 1``); the figures name
what was measured (``measures``). ``--repeat`` runs of ``--steps`` steps each: every rate is the median and
[min, max] of the runs, per wall second and per CPU second (``benchmarks/timing.py``; the subprocess batch's workers'
CPU time included).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
from typing import Any, Callable

import numpy as np

from benchmarks.timing import inverse, measure, pin_cores, print_table, scaled, summarise, table_rows

WARMUP_STEPS = 50
ACTION_POOL = 256


def _world_stepper(args: Any, config: Any, pool: np.ndarray) -> Callable[[int], None]:
    from dynenv_ros.soccer.actions import Kick, SoccerAction, Turn, Walk
    from dynenv_ros.soccer.world import SoccerWorld
    world = SoccerWorld(config, seed=args.seed)
    units, step_rad = config.motion.head_units, config.motion.head_step
    actions = [[SoccerAction(Walk(a[0]), Turn(a[1]), Kick(a[2]), (a[3] - units) * step_rad) for a in row]
               for row in pool]

    def run(steps: int) -> None:
        for k in range(steps):
            result = world.step(actions[k % ACTION_POOL])
            if result.truncated:
                world.reset()
    return run


def perception_setting(args: Any) -> Any:
    """The ``perception`` argument of the envs from ``--noise``, ``--preset`` and ``--noise-magnitude``."""
    if args.noise == "none":
        return "none"
    return {"preset": args.preset, "mode": args.noise, "noise_magnitude": args.noise_magnitude}


def _parallel_env_runner(env: Any, seed: int, pool: np.ndarray) -> Callable[[int], None]:
    """Steps of a PettingZoo parallel env (soccer's or driving's) with the pool's actions, one row per step, a new
    episode when no agent is left; the env is reset with ``seed`` first."""
    env.reset(seed=seed)
    names = env.possible_agents
    actions = [dict(zip(names, row)) for row in pool]

    def run(steps: int) -> None:
        for k in range(steps):
            env.step(actions[k % ACTION_POOL])
            if not env.agents:
                env.reset()
    return run


def _pettingzoo_stepper(args: Any, config: Any, pool: np.ndarray) -> Callable[[int], None]:
    from dynenv_ros.envs.robocup_v0 import parallel_env
    env = parallel_env(players_per_team=args.players_per_team, observation=args.observation,
                       perception=perception_setting(args), image_size=_image_size(args.image_size))
    return _parallel_env_runner(env, args.seed, pool)


def _vector_stepper(args: Any, config: Any, pool: np.ndarray) -> tuple[Callable[[int], None], Any]:
    from dynenv_ros.envs.vector import SoccerVectorEnv
    env = SoccerVectorEnv(args.envs, backend=args.backend, config=config, observation=args.observation,
                          perception=perception_setting(args) if args.observation == "padded" else "none")
    env.reset(seed=args.seed)
    batches = np.stack([np.roll(pool, e, axis=0) for e in range(args.envs)], axis=1)

    def run(steps: int) -> None:
        for k in range(steps):
            env.step(batches[k % ACTION_POOL])
    return run, env


def _image_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise SystemExit(f"--image-size must look like 160x120, got {text!r}") from None
    return width, height


def _driving_stepper(args: Any, config: Any, pool: np.ndarray) -> Callable[[int], None]:
    from dynenv_ros.driving.world import DrivingWorld
    world = DrivingWorld(config, seed=args.seed)

    def run(steps: int) -> None:
        for k in range(steps):
            result = world.step(pool[k % ACTION_POOL])
            if result.terminated or result.truncated:
                world.reset()
    return run


def _driving_env_stepper(args: Any, config: Any, pool: np.ndarray) -> Callable[[int], None]:
    """The whole ``driving_v0`` step (world, observations, rewards, infos); a new episode when every car is done."""
    from dynenv_ros.envs.driving_v0 import parallel_env
    perception = args.perception if args.observation == "partial" else None
    env = parallel_env(n_cars=args.cars, observation=args.observation, perception=perception)
    return _parallel_env_runner(env, args.seed, pool)


DRIVING_OBSERVATIONS = ("none", "full", "partial")


def run_driving(args: Any) -> int:
    """One env step = one 100 ms period of every car; random discrete actions [acceleration, steering].
    ``--observation none``: the world alone; ``full`` / ``partial``: the whole ``driving_v0`` step with that
    observation (``partial``: the driving perception with the ``--perception`` preset)."""
    _resolve_observation(args)
    if not 1 <= args.cars <= 10:
        print("--cars must be in 1..10", file=sys.stderr)
        return 2
    if args.observation not in DRIVING_OBSERVATIONS or args.envs != 1:
        print(f"the driving scenario observes {' / '.join(DRIVING_OBSERVATIONS)} with --envs 1 (got --observation "
              f"{args.observation}, --envs {args.envs})", file=sys.stderr)
        return 2
    if args.steps < 1:
        print("--steps must be at least 1", file=sys.stderr)
        return 2
    cores = pin_cores(args.cores)
    from dynenv_ros.driving.config import DrivingConfig
    config = DrivingConfig(n_cars=args.cars)
    pool = np.random.default_rng(args.seed).integers(0, 3, size=(ACTION_POOL, args.cars, 2))
    stepper = (_driving_stepper if args.observation == "none" else _driving_env_stepper)(args, config, pool)
    perception = args.perception if args.observation == "partial" else "n/a"
    figures = {
        "scenario": args.scenario, "cars": args.cars, "steps": args.steps, "observation": args.observation,
        "perception": perception,
        "measures": _measures(args, f"{args.cars} cars", f"{perception} perception"),
        "envs": 1, "backend": "single", "cores": len(cores), "repeat": args.repeat,
        **_timed(stepper, args.steps, args.repeat, config.rates.motion_period_ticks),
    }
    if args.observation == "partial":
        figures["car_frames_per_s"] = scaled(figures["env_steps_per_s"], config.rates.frames_per_period * args.cars)
    return _report(args, figures, f"dynenv-bench sim: driving, {args.cars} cars")


def _measures(args: Any, who: str, perception: str) -> str:
    """What a run times, in words: the table's first line, ``measures`` in JSON."""
    if args.observation == "none":
        what = "the world alone (physics and rules, no observation)"
    elif args.observation == "full":
        what = "the whole env step, full observations (ground truth, no perception)"
    else:
        what = f"the whole env step, {args.observation} observations, {perception}"
    batch = f", {args.envs} worlds as one batch ({args.backend})" if args.envs > 1 else ""
    default = " [the default observation]" if args.observation_defaulted else ""
    return f"{args.scenario} {who}: {what}{batch}{default}"


def _resolve_observation(args: Any) -> None:
    """No ``--observation``: the step training runs — padded for a batch, partial for one world."""
    args.observation_defaulted = args.observation is None
    if args.observation is None:
        args.observation = "padded" if args.envs > 1 and args.scenario == "robocup" else "partial"


def _timed(stepper: Callable[[int], None], steps: int, repeat: int, ticks_per_step: int, envs: int = 1,
           pids: Any = ()) -> dict[str, Any]:
    """Warm up, then ``repeat`` timed runs of ``steps`` steps: the rates (median, range; per wall and per CPU
    second), ms per env step by both clocks, physics ticks per second, peak RSS."""
    stepper(WARMUP_STEPS)

    def work() -> int:
        stepper(steps)
        return steps * envs
    runs = measure(work, repeat, pids=pids)
    figures = summarise(runs, "env_steps")
    return {**figures, "ms_per_env_step": inverse(figures["env_steps_per_s"]),
            "cpu_ms_per_env_step": inverse(figures["env_steps_per_cpu_s"]),
            "physics_ticks_per_s": scaled(figures["env_steps_per_s"], ticks_per_step, 0),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
            "torch_imported": "torch" in sys.modules, "python": platform.python_version()}


def _report(args: Any, figures: dict[str, Any], title: str) -> int:
    if args.json:
        print(json.dumps(figures))
    else:
        print(f"measures: {figures['measures']}")
        print_table(f"{title} (median [min–max] of {args.repeat} runs)", table_rows(figures, ["measures"]))
    return 0


def run(args: Any) -> int:
    if getattr(args, "scenario", "robocup") == "driving":
        return run_driving(args)
    if not 1 <= args.players_per_team <= 5:
        print("--players-per-team must be in 1..5", file=sys.stderr)
        return 2
    if args.steps < 1 or args.envs < 1:
        print("--steps and --envs must be at least 1", file=sys.stderr)
        return 2
    _resolve_observation(args)
    if args.envs > 1 and args.observation not in ("padded", "full"):
        print("vectorised batches (--envs > 1) observe 'padded' (perception; the default) or 'full' (ground truth)",
              file=sys.stderr)
        return 2
    figures = measure_soccer(args)
    return _report(args, figures, f"dynenv-bench sim: {args.scenario} {figures['players_per_team']}v"
                                  f"{figures['players_per_team']}")


def one_world_padded(steps: int, seed: int = 0) -> dict[str, Any]:
    """The figures of ``dynenv-bench sim --observation padded --steps STEPS --repeat 1`` (one 2v2 world, realistic
    perception, the layout training packs, pinned to one core): the one-world simulation rate another suite reports
    beside its own (``train --config async``). The calling thread's CPU affinity is given back afterwards."""
    from benchmarks.sim_options import add_arguments
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(["--observation", "padded", "--steps", str(steps), "--seed", str(seed)])
    args.repeat = 1
    _resolve_observation(args)
    allowed = os.sched_getaffinity(0)
    try:
        return measure_soccer(args)
    finally:
        os.sched_setaffinity(0, allowed)


def measure_soccer(args: Any) -> dict[str, Any]:
    """The soccer figures of checked ``args`` (``run``'s), this process pinned to ``--cores``."""
    cores = pin_cores(args.cores)
    from dynenv_ros.soccer.config import SoccerConfig
    config = SoccerConfig(players_per_team=args.players_per_team)
    rng = np.random.default_rng(args.seed)
    pool = rng.integers([0, 0, 0, 0], [5, 3, 3, 2 * config.motion.head_units + 1],
                        size=(ACTION_POOL, config.n_robots, 4))
    closer, pids = None, ()
    if args.envs > 1:
        stepper, closer = _vector_stepper(args, config, pool)
        pids = [proc.pid for proc in getattr(closer._batch, "_procs", [])]     # workers' CPU time counts too
    elif args.observation != "none":
        stepper = _pettingzoo_stepper(args, config, pool)
    else:
        stepper = _world_stepper(args, config, pool)
    perceives = args.observation in ("partial", "padded", "image")
    noise = args.noise if perceives else "n/a"
    size = f"{args.players_per_team}v{args.players_per_team}"
    figures = {
        "scenario": args.scenario, "players_per_team": args.players_per_team, "steps": args.steps,
        "observation": args.observation, "noise": noise, "preset": args.preset,
        "noise_magnitude": args.noise_magnitude,
        "measures": _measures(args, size, f"{args.preset} perception ({noise} errors, magnitude "
                                          f"{args.noise_magnitude:g})" if noise != "none" else "perception without errors"),
        "image_size": args.image_size if args.observation == "image" else None, "envs": args.envs,
        "backend": args.backend if args.envs > 1 else "single", "cores": len(cores), "repeat": args.repeat,
    }
    try:
        figures.update(_timed(stepper, args.steps, args.repeat, config.rates.motion_period_ticks, args.envs, pids))
    finally:
        if closer is not None:
            closer.close()
    if perceives:
        figures["robot_frames_per_s"] = scaled(figures["env_steps_per_s"],
                                               config.rates.frames_per_period * config.n_robots, 0)
    return figures
