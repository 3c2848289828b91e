"""The vectorised batch with perception: the padded layout as arrays, identical backends, the same arrays as the
PettingZoo env, final observations, shared memory that never leaks, and actions refused before any world moves."""
import gc
import os

import numpy as np
import pytest

from dynenv_ros.envs import vector
from dynenv_ros.envs.padded_layout import PaddedLayout
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.vector import SoccerVectorEnv, _seeds
from soccer_helpers import assert_identical

# 10 s episodes = 20 motion periods; robots fall now and then, so the worlds' generators matter.
SHORT = {"players_per_team": 1, "episode_seconds": 10.0, "falls": {"p_walk": 0.05}}


def _actions(rng, envs, robots):
    return rng.integers([0, 0, 0, 0], [5, 3, 3, 7], size=(envs, robots, 4))


def _shm_blocks():
    return {name for name in os.listdir("/dev/shm") if name.startswith("psm_")}


def _rollout(backend, steps, envs=3, seed=11, workers=2, **kwargs):
    rng = np.random.default_rng(5)
    with SoccerVectorEnv(envs, backend=backend, workers=workers, config=SHORT, **kwargs) as env:
        out = [env.reset(seed=seed)]
        for _ in range(steps):
            result = env.step(_actions(rng, envs, 2))
            out.append((result.observations, result.rewards, result.reward_terms, result.terminated,
                        result.truncated, result.final_observations, result.dropped_detections))
    return out


# (workers, parent_steps) -> worlds stepped by this process, worker processes: 3 worlds in shards of 2 and 1, or 1,1,1.
ARRANGEMENTS = {(2, True): (2, 1), (2, False): (0, 2), (3, True): (1, 2), (1, True): (0, 1)}


def test_backends_give_bit_identical_padded_batches_across_episode_ends():
    a = _rollout("inprocess", 300)
    b = _rollout("subprocess", 300)   # 2 shards: worlds 0-1 in this process, world 2 in a worker
    assert_identical(a, b)
    ends = [k for k, step in enumerate(a[1:]) if step[4].any()]
    assert ends == [19 + 20 * i for i in range(15)]     # 15 episode ends crossed


@pytest.mark.parametrize("workers, parent_steps", list(ARRANGEMENTS))
def test_every_arrangement_of_shards_gives_the_in_process_batches(workers, parent_steps):
    """This process stepping a shard or not, one worker or several: the same arrays, across episode ends."""
    with SoccerVectorEnv(3, backend="subprocess", workers=workers, config=SHORT, parent_steps=parent_steps) as env:
        assert (env._batch.parent_envs, len(env._batch._procs)) == ARRANGEMENTS[workers, parent_steps]
    a = _rollout("inprocess", 45)
    b = _rollout("subprocess", 45, workers=workers, parent_steps=parent_steps)
    assert_identical(a, b)
    assert sum(bool(step[4].any()) for step in a[1:]) == 2


def test_backends_agree_with_few_slots_and_dropped_rows():
    a = _rollout("inprocess", 30, max_landmarks=2, max_objects=1)
    b = _rollout("subprocess", 30, max_landmarks=2, max_objects=1)
    assert_identical(a, b)
    assert sum(int(step[6].sum()) for step in a[1:]) > 0


def test_arrays_have_the_layouts_keys_shapes_and_dtypes():
    with SoccerVectorEnv(2, backend="inprocess", config={"players_per_team": 2}) as env:
        obs = env.reset(seed=3)
        result = env.step(np.zeros((2, 4, 4), int))
        layout = PaddedLayout.for_players(2, env.config.rates.frames_per_period)
        assert env.layout == layout
        space = env.single_observation_space
        for batch in (obs, result.observations):
            empty = layout.empty(2, 4)
            assert list(batch) == list(empty)
            for key, value in batch.items():
                assert value.shape == empty[key].shape == (2, 4) + space[key].shape
                assert value.dtype == empty[key].dtype == space[key].dtype
            for e in range(2):
                for i in range(4):
                    assert space.contains({k: v[e, i] for k, v in batch.items()})
        assert result.rewards.shape == (2, 4) and result.reward_terms.shape == (2, 4, 4)
        assert result.dropped_detections.shape == (2, 4) and result.dropped_detections.dtype == np.int64
        assert obs["landmark_mask"].sum() > 0 and result.observations["object_mask"].sum() > 0


@pytest.mark.parametrize("backend", ["inprocess", "subprocess"])
def test_world_e_equals_the_pettingzoo_env_with_its_child_seed(backend):
    """Also across an automatic reset: the batch reseeds a finished world from its own generator."""
    config = {"players_per_team": 2, "episode_seconds": 4.0, "falls": {"p_walk": 0.05}}   # 8 periods
    envs, seed, steps = 3, 21, 12
    rng = np.random.default_rng(9)
    actions = [_actions(rng, envs, 4) for _ in range(steps)]
    with SoccerVectorEnv(envs, backend=backend, config=config, perception="realistic") as batch:
        first = batch.reset(seed=seed)
        results = [batch.step(a) for a in actions]
    for e, child in enumerate(_seeds(seed, envs)):
        env = parallel_env(observation="padded", perception="realistic", **config)
        obs, _ = env.reset(seed=child)
        names = env.possible_agents
        for i, name in enumerate(names):
            for key, value in obs[name].items():
                np.testing.assert_array_equal(first[key][e, i], value, err_msg=f"reset {key}")
        for k, result in enumerate(results):
            obs, rewards, _, truncs, infos = env.step(dict(zip(names, actions[k][e])))
            assert bool(result.truncated[e]) == truncs[names[0]]
            for i, name in enumerate(names):
                assert result.rewards[e, i] == rewards[name]
                assert list(result.reward_terms[e, :, i]) == list(infos[name]["reward_terms"].values())
                assert result.dropped_detections[e, i] == infos[name]["dropped_detections"]
            shown = result.final_observations[e] if truncs[names[0]] else \
                {key: value[e] for key, value in result.observations.items()}
            for i, name in enumerate(names):
                for key, value in obs[name].items():
                    np.testing.assert_array_equal(shown[key][i], value, err_msg=f"step {k} {key}")
            if truncs[names[0]]:     # the batch resets the world with a seed drawn from its generator
                obs, _ = env.reset(seed=int(env.world.rng.integers(2**63)))
                for i, name in enumerate(names):
                    for key, value in obs[name].items():
                        np.testing.assert_array_equal(result.observations[key][e, i], value)
        assert any(r.truncated[e] for r in results)


def test_final_observations_exactly_at_episode_ends():
    rng = np.random.default_rng(1)
    with SoccerVectorEnv(2, backend="inprocess", config=SHORT) as env:
        env.reset(seed=0)
        for k in range(45):
            result = env.step(_actions(rng, 2, 2))
            done = result.terminated | result.truncated
            assert sorted(result.final_observations) == list(np.flatnonzero(done))
            assert list(done) == [k % 20 == 19] * 2
            for e, final in result.final_observations.items():
                assert sorted(final) == sorted(result.observations)
                for key, value in final.items():
                    assert value.shape == result.observations[key].shape[1:]
                # The finished episode's last frame shows no time left; the new episode's shows all of it.
                np.testing.assert_array_equal(final["game"][:, 2], 0.0)
                np.testing.assert_array_equal(result.observations["game"][e, :, 2], 10.0)
                np.testing.assert_array_equal(result.observations["previous_action"][e], 0.0)


def test_full_observation_is_the_ground_truth_without_an_observation_reward():
    with SoccerVectorEnv(2, backend="inprocess", config=SHORT, observation="full") as env:
        obs = env.reset(seed=0)
        assert isinstance(obs, np.ndarray) and obs.shape == (2, 2) + env.single_observation_space.shape
        assert env.layout is None
        result = env.step(np.zeros((2, 2, 4), int))
        assert not result.reward_terms[:, 3].any()
    with pytest.raises(ValueError, match="observation"):
        SoccerVectorEnv(2, observation="image")


def test_auto_backend_takes_workers_from_two_worlds_with_perception():
    several = len(os.sched_getaffinity(0)) > 1
    with SoccerVectorEnv(2, config=SHORT) as env:
        assert env.backend == ("subprocess" if several else "inprocess")
    with SoccerVectorEnv(1, config=SHORT) as env, SoccerVectorEnv(7, config=SHORT, observation="full") as full:
        assert env.backend == full.backend == "inprocess"


@pytest.mark.parametrize("parent_steps", [True, False])
def test_pinned_workers_run_on_one_cpu_each(parent_steps):
    """The worker of shard s on the s-th CPU; this process (shard 0 when it steps one) keeps its own affinity."""
    cpus = sorted(os.sched_getaffinity(0))
    with SoccerVectorEnv(3, backend="subprocess", workers=2, config=SHORT, pin_workers=True,
                         parent_steps=parent_steps) as env:
        env.reset(seed=0)
        shards = range(1, 2) if parent_steps else range(2)
        assert [os.sched_getaffinity(p.pid) for p in env._batch._procs] == [{cpus[s % len(cpus)]} for s in shards]
        assert sorted(os.sched_getaffinity(0)) == cpus


def test_copy_false_hands_out_the_batchs_own_arrays():
    with SoccerVectorEnv(2, backend="subprocess", config=SHORT, copy=False) as env:
        first = env.reset(seed=0)
        second = env.step(np.zeros((2, 2, 4), int)).observations
        assert all(np.shares_memory(first[k], second[k]) for k in first)
    with SoccerVectorEnv(2, backend="subprocess", config=SHORT) as env:
        first = env.reset(seed=0)
        kept = {k: v.copy() for k, v in first.items()}
        env.step(np.zeros((2, 2, 4), int))
        assert_identical(first, kept)


def _blocks_of(env):
    """The /dev/shm names of an env's blocks (only its own: other tests may run beside this one, pytest -n 2)."""
    return {block.name.lstrip("/") for block in env._batch._shared.blocks.values()}


def test_shared_memory_is_released_on_close_collection_and_errors(monkeypatch):
    env = SoccerVectorEnv(3, backend="subprocess", workers=2, config=SHORT)
    env.reset(seed=0)
    ours = _blocks_of(env)
    # One block per key: observations, finals, the step's items and the actions.
    assert len(ours) == 2 * 7 + 4 + 1 and ours <= _shm_blocks()
    env.step(np.zeros((3, 2, 4), int))
    env.close()
    env.close()                                           # twice is harmless
    assert not ours & _shm_blocks()
    with pytest.raises(RuntimeError, match="closed"):
        env.step(np.zeros((3, 2, 4), int))
    # Garbage collection alone cleans up and stops the workers.
    env = SoccerVectorEnv(2, backend="subprocess", config=SHORT)
    env.reset(seed=0)
    procs, ours = list(env._batch._procs), _blocks_of(env)
    del env
    gc.collect()
    assert not ours & _shm_blocks()
    assert not any(p.is_alive() for p in procs)
    # A worker that dies: the step fails with a clear error, close() still cleans up. Shard 0 is this process's.
    env = SoccerVectorEnv(3, backend="subprocess", workers=3, config=SHORT)
    env.reset(seed=0)
    ours = _blocks_of(env)
    env._batch._procs[1].kill()
    env._batch._procs[1].join()
    with pytest.raises(RuntimeError, match="worker process 1 died"):
        env.step(np.zeros((3, 2, 4), int))
    env.close()
    assert not ours & _shm_blocks()
    # Interrupted while waiting for the workers (Ctrl-C): the env refuses to go on out of step, close() cleans up.
    env = SoccerVectorEnv(2, backend="subprocess", workers=2, config=SHORT, parent_steps=False)
    env.reset(seed=0)
    ours = _blocks_of(env)
    conn = env._batch._conns[1]

    def interrupted():
        del conn.recv_bytes
        raise KeyboardInterrupt
    conn.recv_bytes = interrupted
    with pytest.raises(KeyboardInterrupt):
        env.step(np.zeros((2, 2, 4), int))
    with pytest.raises(RuntimeError, match="interrupted"):
        env.step(np.zeros((2, 2, 4), int))
    env.close()
    assert not ours & _shm_blocks()
    # Blocks made before a failure are unlinked.
    made = []
    real = vector.shared_memory.SharedMemory

    def failing(*args, **kwargs):
        if len(made) == 5:
            raise OSError("no space left on /dev/shm")
        made.append(real(*args, **kwargs))
        return made[-1]
    monkeypatch.setattr(vector.shared_memory, "SharedMemory", failing)
    with pytest.raises(OSError, match="no space"):
        SoccerVectorEnv(2, backend="subprocess", config=SHORT)
    assert len(made) == 5 and not {block.name.lstrip("/") for block in made} & _shm_blocks()


@pytest.mark.parametrize("parent_steps", [True, False])
def test_errors_in_any_shard_reach_the_caller_and_the_batch_goes_on(parent_steps):
    """A world that raises — in a worker or in this process's shard — gives its error here, after every worker has
    answered (the pipes stay in step: the next calls work); a worker killed meanwhile gives a clear error, no hang."""
    with SoccerVectorEnv(3, backend="subprocess", workers=3, config=SHORT, parent_steps=parent_steps) as env:
        batch = env._batch
        for bad in (2, 0):                       # a worker's world; the first shard's (this process's, if it steps)
            seeds = [1, 2, 3]
            seeds[bad] = -1
            with pytest.raises(ValueError, match="negative"):
                batch.reset(seeds)
            env.reset(seed=0)
            env.step(np.zeros((3, 2, 4), int))
        batch._procs[-1].kill()
        batch._procs[-1].join()
        with pytest.raises(RuntimeError, match=f"worker process {len(batch._procs) - 1} died"):
            env.step(np.zeros((3, 2, 4), int))


@pytest.mark.parametrize("backend", ["inprocess", "subprocess"])
def test_bad_actions_are_refused_before_any_world_moves(backend):
    good = np.zeros((3, 2, 4), int)
    good[..., 3] = 3
    with SoccerVectorEnv(3, backend=backend, workers=2, config=SHORT) as env, \
            SoccerVectorEnv(3, backend=backend, workers=2, config=SHORT) as twin:
        env.reset(seed=4)
        twin.reset(seed=4)
        with pytest.raises(RuntimeError, match="before reset"):
            SoccerVectorEnv(1, backend="inprocess", config=SHORT).step(good[:1])
        with pytest.raises(ValueError, match=r"shape \(3, 2, 4\)"):
            env.step(np.zeros((2, 2, 4), int))
        bad = good.copy()
        bad[2, 1, 0] = 9                                   # the last world, in the second worker
        with pytest.raises(ValueError, match="env 2 robot 1: action field 'walk'=9"):
            env.step(bad)
        bad = good.astype(float)
        bad[0, 0, 3] = 2.5
        with pytest.raises(ValueError, match="env 0 robot 0: action field 'head'"):
            env.step(bad)
        assert_identical(env.step(good).observations, twin.step(good).observations)
    with pytest.raises(ValueError, match="backend"):
        SoccerVectorEnv(2, backend="threads")
    with pytest.raises(ValueError, match="parent_steps must be True or False"):
        SoccerVectorEnv(2, backend="subprocess", parent_steps="no")


@pytest.mark.parametrize("kind, perception, periods", [("chaser", "none", 120), ("perceiving", "realistic", 240)])
def test_scripted_team_b_plays_in_the_worlds_and_ignores_given_rows(kind, perception, periods):
    """Team B driven by the worlds' chasers (ground truth), or by the perceiving team (each robot on its own
    detections and pose estimate): the rows given for team B make no difference, both backends agree, and team B
    scores against a team that stands still (the perceiving team does so in dynenv-eval too: docs/results.md, "The
    perceiving scripted team", 75:0 in 50 games against random)."""
    import numpy as np
    from dynenv_ros.envs.vector import SoccerVectorEnv
    config = {"players_per_team": 1, "episode_seconds": 60.0}
    results = []
    for backend, junk in (("inprocess", 0), ("inprocess", 4), ("subprocess", 2)):
        with SoccerVectorEnv(2, backend=backend, config=config, perception=perception,
                             scripted_team_b=kind) as env:
            env.reset(seed=11)
            actions = np.zeros((2, 2, 4), np.int64)
            actions[:, 0] = [0, 1, 0, 3]          # team A stands still, head centred
            actions[:, 1] = [junk, 0, junk % 3, junk]
            total = np.zeros((2, 4, 2))
            for _ in range(periods):
                total += env.step(actions).reward_terms
            results.append(total)
    np.testing.assert_array_equal(results[0], results[1])
    np.testing.assert_array_equal(results[0], results[2])
    primary = results[0][:, 0].sum(axis=0)        # (robots,): goal rewards over both worlds
    assert primary[1] > 0 > primary[0]            # team B scored against the team standing still


def test_scripted_team_b_refuses_unknown_kinds():
    import pytest
    from dynenv_ros.envs.vector import SoccerVectorEnv
    with pytest.raises(ValueError, match="scripted_team_b"):
        SoccerVectorEnv(1, backend="inprocess", scripted_team_b="random")
    with pytest.raises(ValueError, match="needs observation='padded'"):
        SoccerVectorEnv(1, backend="inprocess", observation="full", scripted_team_b="perceiving")


# configure: a curriculum's next start (docs/soccer.md "Start states"), taken by each world at its next episode only
ATTACK_NEXT = {"players_per_team": 1, "episode_seconds": 2.0,
               "start": {"kind": "attack", "ball_distance_min": 1.0, "ball_distance_max": 2.0, "defenders": "absent"}}


def _configured_run(backend):
    """2-s episodes (4 periods): configured after the first period, the worlds finish their kickoff (the ball stays
    on the centre spot, nobody moves), and the next episode (the worlds' second since the reset: team A's turn to
    attack) starts with the ball 1-2 m from the goal team A attacks, at (4.5, 0), and team B's robot out of play."""
    penalized = list(PaddedLayout.for_players(1, 5).spec.proprioception_columns).index("penalized")
    with SoccerVectorEnv(3, backend=backend, workers=2, config={**ATTACK_NEXT, "start": {"kind": "kickoff"}},
                         targets=True, perception="none") as env:
        env.reset(seed=4)
        idle = np.zeros((3, 2, 4), np.int64)
        idle[..., 3] = 3                                                   # head index 3: no head turn
        results = [env.step(idle)]
        env.configure(ATTACK_NEXT)
        results += [env.step(idle) for _ in range(3)]
        for result in results[:-1]:                                        # the kickoff episode goes on
            assert not result.truncated.any()
            np.testing.assert_allclose(result.targets["ball"][..., :2], 0.0, atol=1e-9)
        last = results[-1]
        assert last.truncated.all()                                        # then the next one starts
        ball = last.targets["ball"][:, 0, :2]                              # team A's frame = the field frame
        distance = np.hypot(ball[:, 0] - 4.5, ball[:, 1])
        assert ((distance >= 1.0) & (distance <= 2.0)).all()
        assert (last.observations["proprioception"][:, 1, -1, penalized] == 1.0).all()
        assert (last.observations["proprioception"][:, 0, -1, penalized] == 0.0).all()
        with pytest.raises(ValueError, match="only start and episode_seconds"):
            env.configure({**ATTACK_NEXT, "players_per_team": 2})
    return [(r.observations, r.reward_terms, r.targets) for r in results]


def test_configure_changes_the_start_at_each_worlds_next_episode_only_in_both_backends_alike():
    runs = [_configured_run(backend) for backend in ("inprocess", "subprocess")]
    assert_identical(runs[0], runs[1])
