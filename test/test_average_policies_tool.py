"""tools/average_policies.py: the uniform mean of several policies' weights, refused across different networks."""
from __future__ import annotations

import pytest
import torch
from tool_scripts import load_tool

from dynenv_ros.agent.checkpoint import load_policy, save_policy, sha256
from dynenv_ros.agent.network import DynEnvAgent


@pytest.fixture(scope="module")
def tool():
    return load_tool("average_policies")


def _policy(path, seed, **config):
    torch.manual_seed(seed)
    model = DynEnvAgent(feature_size=16, **config).eval()
    save_policy(model, path)
    return model


def test_the_average_of_two_policies_is_their_weights_mean(tool, tmp_path) -> None:
    a, b = _policy(tmp_path / "a.safetensors", 1), _policy(tmp_path / "b.safetensors", 2)
    out = tmp_path / "mean.safetensors"
    assert tool.main([str(out), str(tmp_path / "a.safetensors"), str(tmp_path / "b.safetensors")]) == 0
    mean, meta = load_policy(out)
    for name, tensor in mean.state_dict().items():
        expected = (a.state_dict()[name].double() + b.state_dict()[name].double()) / 2
        assert torch.allclose(tensor.double(), expected, rtol=0, atol=1e-7), name
    assert meta["averaged_from"] == [sha256(tmp_path / "a.safetensors"), sha256(tmp_path / "b.safetensors")]
    # the mean of one policy with itself is that policy, to the bit
    assert tool.main([str(out), str(tmp_path / "a.safetensors"), str(tmp_path / "a.safetensors")]) == 0
    again, _ = load_policy(out)
    assert all(torch.equal(again.state_dict()[k], v) for k, v in a.state_dict().items())


def test_policies_of_different_networks_are_refused_and_nothing_is_written(tool, tmp_path, capsys) -> None:
    _policy(tmp_path / "plain.safetensors", 1)
    _policy(tmp_path / "pose.safetensors", 1, uses_pose=True)
    out = tmp_path / "mean.safetensors"
    assert tool.main([str(out), str(tmp_path / "plain.safetensors"), str(tmp_path / "pose.safetensors")]) == 2
    assert "another network" in capsys.readouterr().err
    assert not out.exists()
