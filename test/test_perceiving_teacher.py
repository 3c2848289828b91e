"""Imitation of the perceiving scripted team (issue 26 item 3): ``teacher: perceiving`` labels every robot with the
perceiving chaser's action (``soccer.perceiving``) on exactly that robot's padded observation and pose estimate, with
a ball memory that follows each world's episodes; the worlds run their localization for it; every runner trains
with it; bad combinations are refused with the reason.

The expected labels are computed here by calling ``PerceivingPolicy`` itself on the env's own observations and
estimates (``soccer.perceiving``, not the teacher plumbing of ``envs.teacher`` / ``envs.vector`` under test)."""
from __future__ import annotations

import numpy as np
import pytest

from dynenv_ros.envs.teacher import action_indices
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.config import ConfigError, TrainConfig, load_config
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.perceiving import perceiving_team
from imitation_helpers import follow_labels

CONFIG = SoccerConfig.from_mapping({"players_per_team": 2, "episode_seconds": 2.0})   # 4 periods an episode


def _actions(labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Team A follows its labels, team B acts at random: both the teacher's states and others."""
    actions = labels.copy()
    actions[:, 2:] = rng.integers(0, (5, 3, 3, 7), size=actions[:, 2:].shape)
    return actions


def _reference(policies, observations, estimate, world: int) -> np.ndarray:
    m = CONFIG.motion
    return np.array([action_indices(policy.act({k: v[world, i] for k, v in observations.items()}, estimate[i]),
                                    m.head_step, m.head_units) for i, policy in enumerate(policies)])


@pytest.mark.parametrize("localization", ["none", "estimate"])
def test_labels_are_the_perceiving_chasers_actions_on_the_robots_own_observation_and_estimate(localization):
    """Over several 4-period episodes (automatic resets inside the run), every label equals PerceivingPolicy.act on
    the env's returned observation and its worlds' estimate, with the policies reset at each episode start. A
    reference that keeps its memory across the resets disagrees somewhere: the test sees the reset."""
    worlds, periods = 2, 24
    rng = np.random.default_rng(0)
    fresh = [perceiving_team(2, CONFIG.period_seconds, CONFIG.field, CONFIG.motion, kind="chaser")
             for _ in range(worlds)]
    stale = [perceiving_team(2, CONFIG.period_seconds, CONFIG.field, CONFIG.motion, kind="chaser")
             for _ in range(worlds)]
    stale_differs = False
    with SoccerVectorEnv(worlds, backend="inprocess", config=CONFIG, teacher="perceiving",
                         localization=localization) as env:
        observations = env.reset(seed=3)
        assert ("pose_estimate" in observations) == (localization == "estimate")
        observers = env._batch.observers
        assert all(o.localization for o in observers)         # run for the teacher, observed or not
        labels, starts = env.teacher_actions, np.ones(worlds, bool)
        for t in range(periods + 1):
            for e in range(worlds):
                if starts[e]:
                    for policy in fresh[e]:
                        policy.reset()
                estimate = observers[e].vision.estimate.copy()
                expected = _reference(fresh[e], observations, estimate, e)
                np.testing.assert_array_equal(labels[e], expected, err_msg=f"period {t}, world {e}")
                stale_differs |= bool((_reference(stale[e], observations, estimate, e) != expected).any())
            if t == periods:
                break
            step = env.step(_actions(labels, rng))
            observations, labels = step.observations, step.teacher_actions
            starts = step.terminated | step.truncated
            assert starts.all() == ((t + 1) % 4 == 0)
    assert stale_differs
    assert (labels[..., 0] != 0).any() or (labels[..., 1] != 0).any()     # it plays, not only searches


def test_the_labels_agree_across_backends_and_do_not_depend_on_observing_the_estimate():
    """In-process and worker-process worlds give the same labels; observing the pose changes no label (the estimate
    runs either way, only the key is added)."""
    runs = {}
    for localization in ("none", "estimate"):
        runs[localization], _ = follow_labels(
            lambda backend: SoccerVectorEnv(3, backend=backend, workers=2, config=CONFIG, teacher="perceiving",
                                            localization=localization), 10, seed=7)
    np.testing.assert_array_equal(runs["none"], runs["estimate"])
    # robots that follow the perceiving chaser walk: the labels are not the search's turning on the spot only
    assert (runs["none"][..., 0] == 1).any()


def test_the_teacher_is_the_perceiving_chaser_in_every_slot():
    """One shared network has no slot input: no keeper in slot 0, unlike dynenv-eval's perceiving team."""
    from dynenv_ros.soccer.scripted import ChaserPolicy, GoalkeeperPolicy
    team = perceiving_team(2, 0.5, kind="chaser")
    assert all(isinstance(p.inner, ChaserPolicy) for p in team) and [p.team for p in team] == [1, 1, -1, -1]
    assert isinstance(perceiving_team(2, 0.5)[0].inner, GoalkeeperPolicy)
    with pytest.raises(ValueError, match="kind must be one of"):
        perceiving_team(2, 0.5, kind="random")


@pytest.mark.parametrize("kwargs, message", [
    ({"observation": "full"}, "needs observation='padded'"),
    ({"config": {"head_mode": "continuous"}}, "discrete"),
])
def test_the_env_refuses_what_the_perceiving_teacher_cannot_label(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SoccerVectorEnv(1, backend="inprocess", teacher="perceiving", **kwargs)


@pytest.mark.parametrize("changes, key, message", [
    ({"scenario": "driving"}, "teacher", "'perceiving' is a soccer teacher"),
    ({"head_mode": "continuous"}, "head_mode", "only 'discrete'"),
    ({"teacher": "keeper_and_chasers"}, "teacher", "unknown value"),
])
def test_bad_training_combinations_are_refused_naming_the_key(changes, key, message):
    settings = {"teacher": "perceiving", "imitation_coef": 1.0, **changes}
    with pytest.raises(ConfigError) as caught:
        TrainConfig(**settings)
    assert caught.value.key == key and message in str(caught.value)


def test_the_async_teacher_preset_imitates_the_perceiving_team_with_the_estimate():
    from dynenv_ros.learning.train_cli import preset_path
    cfg = load_config(preset_path("async_teacher"), [])
    assert (cfg.runner, cfg.teacher, cfg.localization) == ("async", "perceiving", "estimate")
    assert cfg.imitation_coef > cfg.imitation_final_coef > 0 and cfg.imitation_decay_env_steps > 0


SMALL = {"algorithm": "ppo", "variant": "pred", "players_per_team": 1, "num_envs": 2, "perception": "realistic",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "episode_seconds": 5.0,
         "teacher": "perceiving", "imitation_coef": 1.0}


@pytest.mark.parametrize("runner, extra", [
    ("sync", {"backend": "inprocess", "localization": "estimate"}),
    ("sync", {"backend": "subprocess", "teacher_driven_worlds": 1}),         # localization: none, teacher drives
    ("async", {"workers": 1, "localization": "estimate", "teacher_driven_worlds": 1}),
])
def test_a_tiny_run_with_the_perceiving_teacher_trains_and_checkpoints(tmp_path, runner, extra):
    from dynenv_ros.learning.run.checkpoints import read_checkpoint_meta
    from dynenv_ros.learning.run.metrics import CSV_NAME, read_metrics
    from dynenv_ros.learning.trainer import Trainer
    cfg = TrainConfig(**SMALL, runner=runner, **extra, total_env_steps=16)
    run = tmp_path / "run"
    summary = Trainer(cfg, run, progress=False).run()
    assert summary["env_steps"] >= 16 and summary["updates"] >= 2
    assert (run / "policy.safetensors").exists()
    assert read_checkpoint_meta(run)["config"]["teacher"] == "perceiving"
    logged = set(read_metrics(run / CSV_NAME))
    assert {"train/imitation_loss", "train/teacher_agreement", "train/teacher_agreement_walk"} <= logged, logged
