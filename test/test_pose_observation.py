"""The self-localization estimate as an observation and as an input of the agent (issue 26, item 1):
``localization: none`` changes nothing (no key, the same arrays and spaces, old checkpoints load and act alike);
``estimate`` adds ``pose_estimate`` in the robot's team frame to every perceived observation mode and to the
vectorised batch, the agent takes it (``uses_pose``) through training, checkpoints, ONNX and evaluation."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from dynenv_ros.agent.checkpoint import agent_config, load_policy, policy_bytes, safetensors_header, save_policy
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.envs.soccer_observations import SoccerObservations
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.config import ConfigError, TrainConfig, load_config
from dynenv_ros.soccer.config import SoccerConfig

ROOT = Path(__file__).resolve().parent.parent
OLD_RUN = ROOT / "docs" / "results_data" / "async_vs_ppo" / "ppo_pred_s0"   # written before uses_pose existed
HEAD_MAX = math.radians(37.5)


def _random_actions(env, rng):
    return {a: np.array([rng.integers(n) for n in env.action_space(a).nvec]) for a in env.agents}


def _play(localization: str | None, steps: int = 3):
    """A few periods of random play (the same actions whatever the option); ``None``: the option not given."""
    option = {} if localization is None else {"localization": localization}
    env = parallel_env(players_per_team=2, observation="padded", **option)
    rng = np.random.default_rng(5)
    observations, _ = env.reset(seed=11)
    history = [observations]
    for _ in range(steps):
        observations, *_ = env.step(_random_actions(env, rng))
        history.append(observations)
    return env, history


# -- the env option ------------------------------------------------------------------------------------------------
def test_localization_none_changes_nothing():
    env_default, default = _play(None)
    env_none, with_none = _play("none")
    assert env_default.observation_space("team_a_0") == env_none.observation_space("team_a_0")
    assert "pose_estimate" not in env_none.observation_space("team_a_0").spaces
    for a, b in zip(default, with_none):
        for agent in a:
            assert a[agent].keys() == b[agent].keys() and "pose_estimate" not in b[agent]
            for key in a[agent]:
                assert a[agent][key].tobytes() == b[agent][key].tobytes()


def test_estimate_adds_the_team_frame_pose_and_leaves_every_other_array_as_it_was():
    env_none, plain = _play("none")
    env, with_pose = _play("estimate")
    space = env.observation_space("team_b_1")["pose_estimate"]
    assert space.shape == (7,) and space.dtype == np.float32
    assert list(space.low) == [-50, -50, -1, -1, 0, 0, 0] and list(space.high) == [50, 50, 1, 1, 50, 50, 50]
    for a, b in zip(plain, with_pose):
        for agent in a:
            assert set(b[agent]) == set(a[agent]) | {"pose_estimate"}
            for key in a[agent]:
                assert a[agent][key].tobytes() == b[agent][key].tobytes()
    # the last observation against the vision's estimate, by the documented formula (envs/pose_features.py):
    # team A as it is; team B turned by π: (−x, −y, cos(θ+π), sin(θ+π)); σ = √ of the covariance's diagonal
    estimate, covariance = env.observations.vision.estimate, env.observations.vision.covariance
    assert covariance[:, 0, 0].min() > 0            # realistic: a real uncertainty
    for i, agent in enumerate(env.possible_agents):
        x, y, yaw = estimate[i]
        if agent.startswith("team_b"):
            x, y, yaw = -x, -y, yaw + math.pi
        expected = [x, y, math.cos(yaw), math.sin(yaw), *np.sqrt(np.diagonal(covariance[i]))]
        row = with_pose[-1][agent]["pose_estimate"]
        assert row.dtype == np.float32 and row.shape == (7,)
        np.testing.assert_allclose(row, expected, rtol=1e-6, atol=1e-6)
        assert env.observation_space(agent).contains(with_pose[-1][agent])


@pytest.mark.parametrize("mode", ["partial", "image"])
def test_partial_and_image_observations_carry_the_key_too(mode):
    env = parallel_env(players_per_team=1, observation=mode, localization="estimate", image_size=(32, 24))
    observations, _ = env.reset(seed=3)
    observations, *_ = env.step({a: np.zeros(4, np.int64) for a in env.agents})
    for i, agent in enumerate(env.possible_agents):
        assert env.observation_space(agent).contains(observations[agent])
        x, y, yaw = env.observations.vision.estimate[i]
        sign = 1.0 if agent.startswith("team_a") else -1.0
        np.testing.assert_allclose(observations[agent]["pose_estimate"][:4],
                                   [sign * x, sign * y, sign * math.cos(yaw), sign * math.sin(yaw)], atol=1e-6)
    plain = parallel_env(players_per_team=1, observation=mode, image_size=(32, 24))
    assert "pose_estimate" not in plain.observation_space("team_a_0").spaces


@pytest.mark.parametrize("kwargs, message", [
    ({"observation": "full", "localization": "estimate"}, "needs a perceived observation"),
    ({"observation": "padded", "localization": "estimated"}, "localization must be one of"),
    ({"observation": "padded", "localization": True}, "localization must be one of"),
])
def test_bad_env_options_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        parallel_env(players_per_team=1, **kwargs)


def test_the_vector_batch_carries_the_pose_alike_in_process_and_in_workers():
    def run(backend):
        with SoccerVectorEnv(2, backend=backend, workers=2, config={"players_per_team": 1}, perception="realistic",
                             localization="estimate") as env:
            assert env.layout.shapes()["pose_estimate"] == (7,)
            first = env.reset(seed=4)
            step = env.step(np.zeros((2, 2, 4), np.int64))
            return first, step.observations
    (a0, a1), (b0, b1) = run("inprocess"), run("subprocess")
    for a, b in ((a0, b0), (a1, b1)):
        assert a.keys() == b.keys() and a["pose_estimate"].shape == (2, 2, 7)
        for key in a:
            assert np.array_equal(a[key], b[key])
    assert a1["pose_estimate"][..., 4:].min() > 0
    with SoccerVectorEnv(1, backend="inprocess", config={"players_per_team": 1}) as plain:
        assert "pose_estimate" not in plain.reset(seed=4)


def test_the_env_batch_agrees_with_the_single_env():
    config = {"players_per_team": 1}
    with SoccerVectorEnv(1, backend="inprocess", config=config, localization="estimate") as vector:
        batch = vector.reset(seed=9)
    # the same world seed the vector env derives for its world 0 (vector._seeds)
    seed = int(np.random.SeedSequence(9).spawn(1)[0].generate_state(1, np.uint64)[0])
    env = parallel_env(observation="padded", localization="estimate", **config)
    observations, _ = env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):
        assert np.array_equal(batch["pose_estimate"][0, i], observations[agent]["pose_estimate"])


# -- the agent -----------------------------------------------------------------------------------------------------
def _batch(robots: int = 3, seed: int = 0) -> dict[str, np.ndarray]:
    obs = SoccerObservations(SoccerConfig(players_per_team=2), "padded", localization="estimate")
    rng = np.random.default_rng(seed)
    arrays = obs.layout.empty(robots)
    arrays["landmarks"][..., :3, :] = rng.normal(size=arrays["landmarks"][..., :3, :].shape)
    arrays["landmarks"][..., :3, 0] = 3                 # goalposts
    arrays["landmark_mask"][..., :3] = 1
    arrays["objects"][..., :1, :] = rng.normal(size=arrays["objects"][..., :1, :].shape)
    arrays["objects"][..., :1, 0] = 1                   # the ball
    arrays["object_mask"][..., :1] = 1
    arrays["game"][:] = [1.0, 5.0, 300.0]
    arrays["pose_estimate"][:] = np.c_[rng.uniform(-4, 4, (robots, 2)), np.cos([0.3] * robots),
                                       np.sin([0.3] * robots), rng.uniform(0.01, 1.0, (robots, 3))]
    return arrays


def test_an_agent_without_the_pose_ignores_the_key_and_one_with_it_needs_it():
    torch.manual_seed(0)
    plain = DynEnvAgent(16).eval()
    torch.manual_seed(0)
    explicit = DynEnvAgent(16, uses_pose=False).eval()
    assert plain.uses_pose is False and agent_config(plain) == agent_config(explicit)
    assert "uses_pose" not in agent_config(plain)
    batch = _batch()
    without = {k: v for k, v in batch.items() if k != "pose_estimate"}
    with torch.no_grad():
        a = plain(*streams_from_padded(batch), *side_inputs(batch, HEAD_MAX), plain.initial_state(3))
        b = explicit(*streams_from_padded(without), *side_inputs(without, HEAD_MAX), explicit.initial_state(3))
    assert torch.equal(a.walk, b.walk) and torch.equal(a.value, b.value)

    posed = DynEnvAgent(16, uses_pose=True).eval()
    previous, state = side_inputs(batch, HEAD_MAX, pose=True)
    assert state.shape == (3, 14) and torch.equal(state[:, 7:], torch.from_numpy(batch["pose_estimate"]))
    with torch.no_grad():
        step = posed(*streams_from_padded(batch), previous, state, posed.initial_state(3))
        moved = dict(batch, pose_estimate=batch["pose_estimate"] + np.float32(0.5))
        other = posed(*streams_from_padded(moved), *side_inputs(moved, HEAD_MAX, pose=True), posed.initial_state(3))
    assert not torch.allclose(step.value, other.value)          # the pose reaches the outputs
    with pytest.raises(ValueError, match="needs 'pose_estimate'"):
        side_inputs(without, HEAD_MAX, pose=True)
    with pytest.raises(ValueError, match="uses the pose estimate"):
        posed(*streams_from_padded(batch), *side_inputs(batch, HEAD_MAX), posed.initial_state(3))
    with pytest.raises(ValueError, match="does not use the pose"):
        plain(*streams_from_padded(batch), previous, state, plain.initial_state(3))
    with pytest.raises(ValueError, match="soccer input"):
        DynEnvAgent(16, scenario="driving", uses_pose=True)


def test_policy_files_record_uses_pose_and_old_files_load_without_it(tmp_path):
    torch.manual_seed(1)
    posed = DynEnvAgent(16, uses_pose=True)
    save_policy(posed, tmp_path / "posed.safetensors", {"run": "x"})
    loaded, meta = load_policy(tmp_path / "posed.safetensors")
    assert loaded.uses_pose is True and meta == {"run": "x"}
    batch = _batch()
    inputs = (*streams_from_padded(batch), *side_inputs(batch, HEAD_MAX, pose=True))
    with torch.no_grad():
        assert torch.equal(posed.eval()(*inputs, posed.initial_state(3)).walk,
                           loaded(*inputs, loaded.initial_state(3)).walk)
    # a file written before the option: no uses_pose in its config; it loads as False, writes back the same
    # metadata and tensor data, and acts on a batch that carries the pose as on one that does not
    old_file = OLD_RUN / "policy.safetensors"
    old, old_meta = load_policy(old_file)
    assert old.uses_pose is False
    (written, start), (original, original_start) = (safetensors_header(data) for data in
                                                    (policy_bytes(old, old_meta), old_file.read_bytes()))
    assert written["__metadata__"] == original["__metadata__"]
    assert "uses_pose" not in json.loads(written["__metadata__"]["config"])
    assert policy_bytes(old, old_meta)[start:] == old_file.read_bytes()[original_start:]
    without = {k: v for k, v in batch.items() if k != "pose_estimate"}
    with torch.no_grad():
        a = old(*streams_from_padded(batch), *side_inputs(batch, old.head_max, pose=old.uses_pose),
                old.initial_state(3))
        b = old(*streams_from_padded(without), *side_inputs(without, old.head_max), old.initial_state(3))
    assert torch.equal(a.walk, b.walk) and torch.equal(a.head, b.head)
    # its training config has no localization setting: it reads as none
    saved = json.loads((OLD_RUN / "config.json").read_text())
    assert "localization" not in saved and TrainConfig.from_dict(saved).localization == "none"


def test_onnx_export_takes_the_pose_as_an_input_and_matches_torch(tmp_path):
    pytest.importorskip("onnxruntime")
    from dynenv_ros.agent.export import OnnxPolicy, TorchPolicy, export_onnx
    torch.manual_seed(2)
    model = DynEnvAgent(16, uses_pose=True).eval()
    export_onnx(model, tmp_path / "posed.onnx", frames=5, max_landmarks=40, max_objects=8)
    onnx_policy, torch_policy = OnnxPolicy(tmp_path / "posed.onnx"), TorchPolicy(model)
    assert onnx_policy.uses_pose is True and torch_policy.uses_pose is True
    assert onnx_policy.config["uses_pose"] is True
    names = [i.name for i in onnx_policy.session.get_inputs()]
    assert names[7:9] == ["proprioception", "pose_estimate"]
    assert tuple(onnx_policy.session.get_inputs()[8].shape[1:]) == (7,)
    state_onnx, state_torch = onnx_policy.initial_state(3), torch_policy.initial_state(3)
    for period in range(3):                     # consecutive periods: the recurrent state carried
        batch = _batch(seed=period)
        inputs = (*streams_from_padded(batch), *side_inputs(batch, HEAD_MAX, pose=onnx_policy.uses_pose))
        a, b = onnx_policy(*inputs, state_onnx), torch_policy(*inputs, state_torch)
        for name in ("walk", "turn", "kick", "head", "value", "pose"):
            np.testing.assert_allclose(getattr(a, name).numpy(), getattr(b, name).numpy(), atol=1e-5, rtol=0)
        for x, y in zip(a.state, b.state):
            np.testing.assert_allclose(x.numpy(), y.numpy(), atol=1e-5, rtol=0)
        state_onnx, state_torch = a.state, b.state
    with pytest.raises(ValueError, match="uses the pose estimate"):
        onnx_policy(*streams_from_padded(batch), *side_inputs(batch, HEAD_MAX), onnx_policy.initial_state(3))
    export_onnx(DynEnvAgent(16), tmp_path / "plain.onnx")
    plain = OnnxPolicy(tmp_path / "plain.onnx")
    assert plain.uses_pose is False and "pose_estimate" not in [i.name for i in plain.session.get_inputs()]


# -- the training setting ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("changes, message", [
    ({"localization": "estimated"}, "localization: unknown value 'estimated'; expected one of none, estimate"),
    ({"localization": True}, "localization: expected a string"),
    ({"localization": None}, "localization: expected str, got null"),
    ({"scenario": "driving", "localization": "estimate"}, "localization: is soccer-only"),
])
def test_bad_localization_settings_are_refused_naming_the_key(changes, message):
    with pytest.raises(ConfigError) as caught:
        TrainConfig(**changes)
    assert caught.value.key == "localization" and str(caught.value).startswith(message)


def test_the_setting_reads_from_an_override_and_reaches_the_agent_and_the_worlds():
    from dynenv_ros.learning.algo.networks import make_agent
    from dynenv_ros.learning.sampling.worlds import make_env
    cfg = load_config(None, ["localization=estimate", "players_per_team=1", "perception=none"])
    assert cfg.localization == "estimate" and make_agent(cfg).uses_pose is True
    env, _ = make_env(cfg, 1, "inprocess")
    try:
        assert "pose_estimate" in env.reset(seed=0)
    finally:
        env.close()
    assert make_agent(TrainConfig()).uses_pose is False


def test_ros_experience_refuses_the_estimate_with_the_reason(tmp_path):
    from dynenv_ros.learning.messages.message_trainer import MessageTrainer
    with pytest.raises(ConfigError, match="carries none yet"):
        MessageTrainer(TrainConfig(localization="estimate", algorithm="ppo", players_per_team=1), tmp_path / "run")


def test_learning_from_bags_refuses_the_estimate_with_the_reason(tmp_path):
    # a recording holds no pose estimate: an agent that takes one cannot be cloned from it (it was built without one)
    from dynenv_ros.learning.messages.bags import train_from_bags
    with pytest.raises(ValueError, match="carries none yet"):
        train_from_bags(TrainConfig(localization="estimate"), [ROOT / "bags" / "sample_2v2_realistic_30s"],
                        tmp_path / "run")
    assert not (tmp_path / "run").exists()


SMALL = {"algorithm": "ppo", "variant": "pred", "players_per_team": 1, "num_envs": 2, "perception": "realistic",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "episode_seconds": 5.0,
         "localization": "estimate"}


@pytest.mark.parametrize("runner", ["sync", "async"])
def test_a_tiny_run_with_the_estimate_trains_checkpoints_resumes_and_evaluates(tmp_path, runner):
    from dynenv_ros.agent.export import OnnxPolicy
    from dynenv_ros.evaluation.soccer import evaluate
    from dynenv_ros.learning.run.checkpoints import read_checkpoint_meta
    from dynenv_ros.learning.train_cli import main
    from dynenv_ros.learning.trainer import Trainer
    extra = {"runner": "async", "workers": 1} if runner == "async" else {}
    cfg = TrainConfig(**SMALL, **extra, total_env_steps=16)
    run = tmp_path / "run"
    summary = Trainer(cfg, run, progress=False).run()
    assert summary["env_steps"] >= 16 and summary["updates"] >= 2
    policy, _ = load_policy(run / "policy.safetensors")
    assert policy.uses_pose is True
    assert OnnxPolicy(run / "policy.onnx").uses_pose is True
    meta = read_checkpoint_meta(run)              # the latest training checkpoint's
    assert meta["config"]["localization"] == "estimate"
    assert meta["observation_layout"]["pose_estimate"] == [7]
    # resume: the agent is rebuilt from the checkpoint's config (with the pose) and trains on
    assert main(["--resume", str(run), "--no-progress", "--set", "total_env_steps=32"]) == 0
    resumed = json.loads((run / "summary.json").read_text())
    assert resumed["env_steps"] >= 32 and resumed["updates"] > summary["updates"]
    # evaluation: the env's observations carry the pose because the checkpoint uses it (file and run folder)
    for evaluated in (run / "policy.safetensors", run):
        result = evaluate(str(evaluated), "random", episodes=1, seeds=[0], players_per_team=1,
                          env_config={"episode_seconds": 2.0})
        assert result["evaluated"]["uses_pose"] is True and result["counts"]["episodes"] == 1
        assert np.isfinite(result["summary"]["total"]["mean"])
