"""A driving policy as a file (issue 14): safetensors round trip, ONNX export with the scenario, layout and action
spec in its metadata, torch = ONNX over consecutive periods (both action modes), and a policy of the other scenario
refused with the reason."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("onnxruntime")

from dynenv_ros.driving import agent_actions as driving_actions  # noqa: E402
from dynenv_ros.agent.checkpoint import agent_config, load_policy, save_policy  # noqa: E402
from dynenv_ros.agent.export import (METADATA_KEY, OnnxPolicy, TorchPolicy, check_driving_policy,  # noqa: E402
                                     check_policy, check_scenario, export_onnx)
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded  # noqa: E402
from dynenv_ros.agent.network import DynEnvAgent  # noqa: E402
from dynenv_ros.driving.config import DrivingConfig  # noqa: E402
from dynenv_ros.envs.driving_observations import driving_layout_spec  # noqa: E402
from dynenv_ros.envs.driving_v0 import parallel_env  # noqa: E402

W = DrivingConfig().cars.max_yaw_rate


def periods(n_cars: int = 2, count: int = 4, seed: int = 1):
    """``count`` consecutive periods of padded driving observations (cars leading) under random discrete play."""
    env = parallel_env(n_cars=n_cars, observation="padded", perception="realistic")
    obs, _ = env.reset(seed=seed)
    spec = driving_layout_spec(env.config)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        cars = sorted(obs)
        out.append({k: np.stack([obs[a][k] for a in cars]) for k in obs[cars[0]]})
        obs, *_ = env.step({a: rng.integers(0, 3, 2) for a in env.agents})
    return out, spec


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_a_driving_policy_file_round_trips(tmp_path, action_mode):
    torch.manual_seed(2)
    model = DynEnvAgent(feature_size=24, scenario="driving", action_mode=action_mode)
    assert agent_config(model) == {"feature_size": 24, "scenario": "driving", "action_mode": action_mode}
    save_policy(model, tmp_path / "drive.safetensors", {"updates": 3})
    loaded, meta = load_policy(tmp_path / "drive.safetensors")
    assert meta == {"updates": 3} and loaded.scenario == "driving" and loaded.action_mode == action_mode
    for key, value in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value), key
    (batch,), spec = periods(count=1)
    inputs = (*streams_from_padded(batch, spec), *side_inputs(batch, spec=spec))
    with torch.no_grad():
        a, b = model.eval()(*inputs, model.initial_state(2)), loaded(*inputs, loaded.initial_state(2))
    torch.testing.assert_close(a.value, b.value, rtol=0, atol=0)


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_the_onnx_driving_policy_equals_torch_over_consecutive_periods(tmp_path, action_mode):
    torch.manual_seed(3)
    model = DynEnvAgent(feature_size=32, scenario="driving", action_mode=action_mode)
    path = tmp_path / "drive.onnx"
    export_onnx(model, path)
    onnx_policy, torch_policy = OnnxPolicy(path), TorchPolicy(model)
    assert (onnx_policy.scenario, onnx_policy.action_mode, onnx_policy.frames) == ("driving", action_mode, 1)
    assert (onnx_policy.max_landmarks, onnx_policy.max_objects) == (11, 52)
    config = onnx_policy.config
    assert config["layout"]["streams"][0]["key"] == "lanes" and config["layout"]["previous_action"] == [
        "throttle", "brake", "steering"]
    assert config["actions"]["mode"] == action_mode
    batches, spec = periods(count=4)
    state_t, state_o = torch_policy.initial_state(2), onnx_policy.initial_state(2)
    names = ("acceleration", "steering") if action_mode == "discrete" else ("command",)
    for batch in batches:
        inputs = (*streams_from_padded(batch, spec), *side_inputs(batch, spec=spec))
        a, b = torch_policy(*inputs, state_t), onnx_policy(*inputs, state_o)
        for name in names + ("value",):
            torch.testing.assert_close(getattr(b, name), getattr(a, name), rtol=1e-5, atol=1e-5)
        for x, y in zip(a.state, b.state):
            torch.testing.assert_close(y, x, rtol=1e-5, atol=1e-5)
        state_t, state_o = a.state, b.state
        check_driving_policy(onnx_policy, inputs, W)
        for greedy in (True, False):
            acts_t, _ = driving_actions.sample_actions(a, action_mode, torch.Generator().manual_seed(5), greedy)
            acts_o, _ = driving_actions.sample_actions(b, action_mode, torch.Generator().manual_seed(5), greedy)
            np.testing.assert_allclose(acts_o, acts_t, rtol=0, atol=1e-5)


def test_a_driving_export_has_one_frame():
    with pytest.raises(ValueError, match="one vision frame"):
        export_onnx(DynEnvAgent(feature_size=8, scenario="driving"), "/tmp/never.onnx", frames=5)


def test_a_policy_of_the_other_scenario_is_refused_with_the_reason(tmp_path):
    torch.manual_seed(4)
    soccer, driving = TorchPolicy(DynEnvAgent(feature_size=16)), TorchPolicy(
        DynEnvAgent(feature_size=16, scenario="driving", action_mode="continuous"))
    with pytest.raises(ValueError, match="it is a soccer policy and this node plays driving"):
        check_scenario(soccer, "driving", "discrete")
    with pytest.raises(ValueError, match="it is a driving policy and this node plays soccer"):
        check_scenario(driving, "robocup")
    with pytest.raises(ValueError, match="continuous driving policy and the simulator's action_mode is discrete"):
        check_scenario(driving, "driving", "discrete")
    check_scenario(driving, "driving", "continuous")
    with pytest.raises(ValueError, match="driving policy"):       # soccer's check refuses it too
        check_policy(driving, None, 1.0)
    export_onnx(driving.model, tmp_path / "drive.onnx")
    export_onnx(soccer.model, tmp_path / "soccer.onnx")
    assert OnnxPolicy(tmp_path / "soccer.onnx").scenario == "soccer"
    with pytest.raises(ValueError, match="it is a driving policy"):
        check_scenario(OnnxPolicy(tmp_path / "drive.onnx"), "robocup")


def test_a_driving_onnx_file_whose_metadata_lies_is_refused(tmp_path):
    import onnx

    export_onnx(DynEnvAgent(feature_size=8, scenario="driving"), tmp_path / "drive.onnx")
    proto = onnx.load(str(tmp_path / "drive.onnx"))
    entry = next(p for p in proto.metadata_props if p.key == METADATA_KEY)
    config = json.loads(entry.value)
    entry.value = json.dumps({**config, "action_mode": "continuous"})
    onnx.save(proto, str(tmp_path / "lies.onnx"))
    with pytest.raises(ValueError, match="does not match its own metadata"):
        OnnxPolicy(tmp_path / "lies.onnx")
    entry.value = json.dumps({**config, "frames": 3})
    onnx.save(proto, str(tmp_path / "frames.onnx"))
    with pytest.raises(ValueError, match="1 frame"):
        OnnxPolicy(tmp_path / "frames.onnx")
