"""Policy checkpoints (safetensors, no pickle) round-trip, are written atomically, and anything else is refused with
a clear error — including a pickle that would run code."""
import pickle

import pytest
import torch
from safetensors.torch import save_file

from dynenv_ros.agent.checkpoint import load_checkpoint, load_policy, save_checkpoint, sha256
from dynenv_ros.agent.network import DynEnvAgent


class _Payload:
    def __reduce__(self):                       # what a malicious checkpoint would carry
        return (print, ("this must never run",))


def test_round_trip_keeps_every_weight_and_setting(tmp_path):
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=16, head_mode="continuous")
    path = tmp_path / "agent.safetensors"
    digest = save_checkpoint(model, path, extra={"updates": 12})
    assert digest == sha256(path) and [p.name for p in tmp_path.iterdir()] == ["agent.safetensors"]   # no temp left
    loaded = load_checkpoint(path)
    assert loaded.head_mode == "continuous" and loaded.feature_size == 16 and not loaded.training
    for (name, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    assert load_policy(path)[1] == {"updates": 12}
    discrete = DynEnvAgent(feature_size=16, head_units=5)
    save_checkpoint(discrete, path)                                         # replaces the file atomically
    assert load_checkpoint(path).head_head.out_features == 11


def test_bad_checkpoints_are_refused_with_a_reason(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_checkpoint(tmp_path / "missing.safetensors")
    truncated = tmp_path / "truncated.safetensors"
    save_checkpoint(DynEnvAgent(feature_size=16), truncated)
    truncated.write_bytes(truncated.read_bytes()[:500])
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_checkpoint(truncated)
    code = tmp_path / "code.pt"                 # an old-style pickle checkpoint, carrying code: never unpickled
    code.write_bytes(pickle.dumps({"format": "dynenv_agent/1", "state_dict": _Payload()}, protocol=2))
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_checkpoint(code)
    old = tmp_path / "old.pt"
    torch.save({"weights": torch.zeros(3)}, old)
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_checkpoint(old)
    foreign = tmp_path / "foreign.safetensors"
    save_file({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match="not a dynenv_policy/1 file"):
        load_checkpoint(foreign)
    with pytest.raises(ValueError, match="folder .* does not exist"):
        save_checkpoint(DynEnvAgent(feature_size=16), tmp_path / "nowhere" / "agent.safetensors")
