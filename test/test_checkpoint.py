"""Policy checkpoints (safetensors, no pickle) round-trip, are written atomically, and anything else is refused with
a clear error — including a pickle that would run code."""
import pickle

import pytest
import torch
from safetensors.torch import save_file

from dynenv_ros.agent.checkpoint import load_policy, save_policy, sha256
from dynenv_ros.agent.network import DynEnvAgent


class _Payload:
    def __reduce__(self):                       # what a malicious checkpoint would carry
        return (print, ("this must never run",))


def test_round_trip_keeps_every_weight_and_setting(tmp_path):
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=16, head_mode="continuous")
    path = tmp_path / "agent.safetensors"
    digest = save_policy(model, path, {"updates": 12})
    assert digest == sha256(path) and [p.name for p in tmp_path.iterdir()] == ["agent.safetensors"]   # no temp left
    loaded, _ = load_policy(path)
    assert loaded.head_mode == "continuous" and loaded.feature_size == 16 and not loaded.training
    for (name, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    assert load_policy(path)[1] == {"updates": 12}
    discrete = DynEnvAgent(feature_size=16, head_units=5)
    save_policy(discrete, path)                                         # replaces the file atomically
    assert load_policy(path)[0].head_head.out_features == 11


def test_bad_checkpoints_are_refused_with_a_reason(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_policy(tmp_path / "missing.safetensors")
    truncated = tmp_path / "truncated.safetensors"
    save_policy(DynEnvAgent(feature_size=16), truncated)
    truncated.write_bytes(truncated.read_bytes()[:500])
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_policy(truncated)
    code = tmp_path / "code.pt"                 # an old-style pickle checkpoint, carrying code: never unpickled
    code.write_bytes(pickle.dumps({"format": "dynenv_agent/1", "state_dict": _Payload()}, protocol=2))
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_policy(code)
    old = tmp_path / "old.pt"
    torch.save({"weights": torch.zeros(3)}, old)
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_policy(old)
    foreign = tmp_path / "foreign.safetensors"
    save_file({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match="not a dynenv_policy/1 file"):
        load_policy(foreign)
    with pytest.raises(ValueError, match="folder .* does not exist"):
        save_policy(DynEnvAgent(feature_size=16), tmp_path / "nowhere" / "agent.safetensors")


def _crafted(path, model, **config):
    """A well-formed policy file (checksum right) with ``model``'s weights under a config changed by ``config``."""
    import hashlib
    import json

    from safetensors.torch import save

    from dynenv_ros.agent.checkpoint import FORMAT, agent_config, safetensors_header, tensors_for_saving

    tensors = tensors_for_saving(model.state_dict())
    metadata = {"format": FORMAT, "config": json.dumps({**agent_config(model), **config}), "meta": "{}"}
    _, start = safetensors_header(first := save(tensors, metadata=metadata))
    metadata["data_sha256"] = hashlib.sha256(first[start:]).hexdigest()
    path.write_bytes(save(tensors, metadata=metadata))
    return path


def test_a_tiny_file_asking_for_a_huge_network_is_refused_before_it_is_allocated(tmp_path, monkeypatch):
    """The config's network is first built on the meta device (no memory) and the tensors checked against it."""
    import dynenv_ros.agent.checkpoint as checkpoint

    built = []

    class Recording(DynEnvAgent):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            built.append(next(self.parameters()).device.type)

    monkeypatch.setattr(checkpoint, "DynEnvAgent", Recording)
    small = DynEnvAgent(feature_size=16)
    path = _crafted(tmp_path / "huge.safetensors", small, feature_size=1024)     # 40 M weights asked, 0.2 M given
    with pytest.raises(ValueError, match="does not fit the model"):
        load_policy(path)
    assert built == ["meta"]
    assert load_policy(_crafted(tmp_path / "ok.safetensors", small))[0].feature_size == 16
    assert built == ["meta", "meta", "cpu"]


@pytest.mark.parametrize("config,message", [
    ({"feature_size": 10**7}, "feature_size must be an integer in 1..1024"),
    ({"feature_size": True}, "feature_size must be an integer"),
    ({"feature_size": "16"}, "feature_size must be an integer"),
    ({"head_units": 0}, "head_units must be an integer in 1..64"),
    ({"head_units": 1000}, "head_units must be an integer in 1..64"),
    ({"head_max": float("nan")}, "head_max must be a finite angle"),
    ({"head_max": float("inf")}, "head_max must be a finite angle"),
    ({"head_max": 1e6}, "head_max must be a finite angle"),
    ({"head_max": 0.0}, "head_max must be a finite angle"),
    ({"layers": 99}, "unknown config keys"),
])
def test_architecture_settings_read_from_a_file_are_bounded(tmp_path, config, message):
    path = _crafted(tmp_path / "p.safetensors", DynEnvAgent(feature_size=16), **config)
    with pytest.raises(ValueError, match=message):
        load_policy(path)


def test_a_file_beyond_the_size_limit_or_not_a_file_is_refused_unread(tmp_path):
    giant = tmp_path / "giant.safetensors"
    with open(giant, "wb") as handle:
        handle.truncate(300 << 20)                     # sparse: no disk, but 300 MiB to read
    with pytest.raises(ValueError, match="more than the 256 MiB"):
        load_policy(giant)
    with pytest.raises(ValueError, match="is not a regular file"):
        load_policy(tmp_path)
