"""The env step's fast paths (issue 42 part 4) give, bit for bit, what the code they stand in for gives:

- ``PhysicsWorld.step`` calling chipmunk's step itself against ``Space.step`` tick by tick, through games with kicks
  (foot bodies added and removed), falls, penalties and returns;
- the compiled feature rows (``row_kernels.clamped_features``) against ``np.clip(as_features(rows))``;
- the compiled observation reward (``soccer_kernels.observation_rewards``) against the numpy expression of
  DynEnv's rule (docs/original.md §6.1: per observer, other robots seen at most ``robot_cap`` frames each, landmarks
  and lines a frame on average at most ``landmark_cap``, the ball at most ``ball_cap`` frames, weighted);
- the realistic mode's compiled rules 1–3 (nearby, misses, table confusions) against the rule-by-rule numpy path
  (``Perceiver._nearby`` and ``_confuse``), which a perceiver takes when its confusion rules are not one table.
"""
import numpy as np
import pytest

from dynenv_ros.envs.padded_layout import FEATURE_BOUND
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.perception.detections import DETECTION_DTYPE, as_features
from dynenv_ros.perception.params import load_preset
from dynenv_ros.perception.row_kernels import clamped_features
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld


def _same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def _walking_actions(rng, robots, steps, head_units):
    """Mostly walking forward (robots leave the field, crowd areas, push), with kicks and turns now and then."""
    actions = rng.integers([0, 0, 0, 0], [5, 3, 3, 2 * head_units + 1], size=(steps, robots, 4))
    actions[:, :, 0] = np.where(rng.random((steps, robots)) < 0.6, 1, actions[:, :, 0])
    return actions


@pytest.mark.parametrize("players", [2, 5])
def test_physics_fast_step_equals_space_step(players):
    config = SoccerConfig(players_per_team=players)
    worlds = [SoccerWorld(config, seed=3), SoccerWorld(config, seed=3)]
    worlds[1].physics.fast_step = False
    assert worlds[0].physics.fast_step, "the pinned pymunk takes the fast path"
    actions = _walking_actions(np.random.default_rng(5), config.n_robots, 400, config.motion.head_units)
    kinds = set()
    for row in actions:
        results = [w.step(list(row)) for w in worlds]
        kinds.update(e.kind for e in results[0].events)
        assert [e.kind for e in results[0].events] == [e.kind for e in results[1].events]
        _same_bits(results[0].rewards, results[1].rewards)
        for a, b in zip(worlds[0].robots + [None], worlds[1].robots + [None]):
            body_a = a.body if a is not None else worlds[0].ball
            body_b = b.body if b is not None else worlds[1].ball
            assert tuple(body_a.position) == tuple(body_b.position)
            assert tuple(body_a.velocity) == tuple(body_b.velocity)
            assert body_a.angle == body_b.angle
        if results[0].truncated:
            for w in worlds:
                w.reset()
    # the games went through what adds and removes bodies while stepping
    assert {"touch", "fall", "penalty"} <= kinds


@pytest.mark.filterwarnings("ignore:invalid value encountered")     # numpy's cos/sin of ±inf: NaN, then 0 here
def test_clamped_features_equal_as_features_clipped_bit_for_bit():
    rng = np.random.default_rng(11)
    rows = np.zeros(3000, DETECTION_DTYPE)
    for name in DETECTION_DTYPE.names:
        kind = DETECTION_DTYPE[name].kind
        if kind == "f":
            rows[name] = rng.normal(0.0, 40.0, len(rows))          # beyond the bound now and then
        elif kind == "b":
            rows[name] = rng.random(len(rows)) < 0.5
        else:
            info = np.iinfo(DETECTION_DTYPE[name])
            rows[name] = rng.integers(max(info.min, -128), min(info.max, 255) + 1, len(rows))
    rows["yaw"][rng.random(len(rows)) < 0.3] = np.nan
    rows["yaw"][:4] = (np.inf, -np.inf, 0.0, -0.0)
    rows["x"][4] = np.nan                                           # np.clip keeps NaN
    expected = np.clip(as_features(rows), -FEATURE_BOUND, FEATURE_BOUND)
    got = clamped_features(rows, FEATURE_BOUND)
    _same_bits(got, expected)
    assert (got == FEATURE_BOUND).any() and (got == -FEATURE_BOUND).any()
    _same_bits(clamped_features(rows[:0], FEATURE_BOUND), expected[:0])
    with pytest.raises(ValueError, match="float32"):
        clamped_features(rows, 0.1)


def _observation_rewards_numpy(seen, lines_seen, n, landmark_index, w):
    frames = len(seen) // n
    counts = seen.reshape(frames, n, -1).sum(axis=0)
    robot_frames = np.minimum(w.observation_robot_cap, counts[:, :n])
    robot_frames[np.arange(n), np.arange(n)] = 0
    landmarks = counts[:, landmark_index].sum(axis=1) + lines_seen.reshape(frames, n).sum(axis=0)
    landmark_term = np.minimum(float(w.observation_landmark_cap), landmarks / frames)
    ball_frames = np.minimum(w.observation_ball_cap, counts[:, n])
    return (w.observation_robot * robot_frames.sum(axis=1) + w.observation_landmark * landmark_term
            + w.observation_ball * ball_frames)


@pytest.mark.parametrize("players", [1, 2, 5])
def test_observation_rewards_kernel_equals_the_numpy_rule(players):
    from dynenv_ros.perception.soccer_kernels import observation_rewards
    w = SoccerConfig(players_per_team=players).rewards
    n, objects, frames = 2 * players, 2 * players + 20, 5
    rng = np.random.default_rng(players)
    landmark_index = np.flatnonzero(rng.random(objects) < 0.4)
    landmark_index = landmark_index[landmark_index > n]
    for density in (0.05, 0.5, 0.95):
        seen = rng.random((frames * n, objects)) < density
        lines_seen = rng.integers(0, 6, frames * n)
        got = observation_rewards(seen, lines_seen, n, landmark_index, w.observation_robot_cap,
                                  float(w.observation_landmark_cap), w.observation_ball_cap, w.observation_robot,
                                  w.observation_landmark, w.observation_ball)
        _same_bits(got, _observation_rewards_numpy(seen, lines_seen, n, landmark_index, w))


def _perceptions(env, steps, seed):
    env.reset(seed=seed)
    pool = _walking_actions(np.random.default_rng(seed), len(env.possible_agents), steps,
                            env.config.motion.head_units)
    out = []
    for row in pool:
        obs, *_ = env.step(dict(zip(env.possible_agents, row)))
        out.append(obs)
        if not env.agents:
            env.reset()
    return out


def test_realistic_rules_compiled_equal_the_rule_by_rule_path():
    """Distinct confusion sources make the table and the rules in order the same rule; a perceiver without the
    table takes the numpy path (``_nearby``, ``_confuse``) with the same draws."""
    preset = load_preset("realistic")
    assert len({c.source for c in preset.confusions}) == len(preset.confusions) > 0
    envs = [parallel_env(players_per_team=2, observation="partial") for _ in range(2)]
    for env in envs:
        env.reset(seed=9)
    envs[1].observations.vision.perceiver._confusion_rate = None          # the rule-by-rule path
    original_reset = envs[1].observations.vision.reset

    def reset_without_table():
        original_reset()
        envs[1].observations.vision.perceiver._confusion_rate = None
    envs[1].observations.vision.reset = reset_without_table
    compiled, numpy_path = (_perceptions(env, 300, 9) for env in envs)
    rows = 0
    for a, b in zip(compiled, numpy_path):
        for name in a:
            for frame_a, frame_b in zip(a[name]["detections"], b[name]["detections"]):
                _same_bits(frame_a, frame_b)
                rows += len(frame_a)
    assert rows > 10_000
