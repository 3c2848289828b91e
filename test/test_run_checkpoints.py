"""Training checkpoints (safetensors + JSON) restore model and optimizer exactly, are pruned to the newest k,
survive a broken ``latest`` pointer, and refuse damaged or ill-fitting files by name; policy files round-trip."""
import json
import os
import random
import warnings

import numpy as np
import pytest
import torch
from safetensors.torch import save_file
from torch import nn

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.run.checkpoints import (FORMAT, CheckpointWarning, capture_rng_state, list_checkpoints,
                                                 load_policy, load_training_checkpoint, read_checkpoint_meta,
                                                 resolve_checkpoint, restore_rng_state, save_policy,
                                                 save_training_checkpoint, sha256)
from dynenv_ros.learning.config import TrainConfig


class Small(nn.Module):
    def __init__(self, hidden=8):
        super().__init__()
        self.a = nn.Linear(3, hidden)
        self.b = nn.Linear(hidden, 2)
        self.register_buffer("count", torch.zeros((), dtype=torch.int64))

    def forward(self, x):
        return self.b(torch.tanh(self.a(x)))


def _train_step(model, optimizer, seed):
    generator = torch.Generator().manual_seed(seed)
    x = torch.randn(16, 3, generator=generator)
    optimizer.zero_grad()
    model(x).pow(2).mean().backward()
    optimizer.step()


def _params(model):
    return [p.detach().clone() for p in model.state_dict().values()]


def test_round_trip_restores_model_and_adam_exactly(tmp_path):
    torch.manual_seed(0)
    model = Small()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2, eps=1e-5, betas=(0.8, 0.95))
    for seed in range(3):
        _train_step(model, optimizer, seed)
    model.count += 7
    meta = {"config": TrainConfig().to_dict(), "updates": 3, "env_steps": 144, "layout": {"a": [1, 2]}}
    extra = {"running.mean": torch.arange(5.0), **capture_rng_state()}
    path = save_training_checkpoint(tmp_path / "run", 144, model, optimizer, meta, extra_tensors=extra)
    assert path == tmp_path / "run" / "checkpoints" / "step_000000000144"
    assert sorted(p.name for p in path.iterdir()) == ["extra.safetensors", "meta.json", "model.safetensors",
                                                      "optimizer.safetensors"]
    assert (tmp_path / "run" / "checkpoints" / "latest").read_text().strip() == "step_000000000144"
    record = json.loads((path / "meta.json").read_text())
    assert record["format"] == FORMAT and record["step"] == 144
    assert record["files"]["model.safetensors"] == sha256(path / "model.safetensors")
    assert "code_revision" in record and record["optimizer"]["param_groups"][0]["betas"] == [0.8, 0.95]

    fresh = Small(); fresh_optimizer = torch.optim.Adam(fresh.parameters(), lr=0.5)     # noqa: E702
    loaded_meta, loaded_extra = load_training_checkpoint(tmp_path / "run", fresh, fresh_optimizer)
    assert TrainConfig.from_dict(loaded_meta["config"]) == TrainConfig()
    assert loaded_meta["updates"] == 3 and loaded_meta["layout"] == {"a": [1, 2]}
    assert loaded_meta["checkpoint"]["step"] == 144 and loaded_meta["checkpoint"]["path"] == str(path)
    assert torch.equal(loaded_extra["running.mean"], torch.arange(5.0))
    assert all(torch.equal(a, b) for a, b in zip(_params(model), _params(fresh))) and fresh.count.item() == 7
    assert fresh_optimizer.param_groups[0]["lr"] == 1e-2 and fresh_optimizer.param_groups[0]["betas"] == (0.8, 0.95)
    assert torch.equal(fresh_optimizer.state[fresh_optimizer.param_groups[0]["params"][0]]["step"],
                       optimizer.state[optimizer.param_groups[0]["params"][0]]["step"])
    for seed in range(10, 14):                       # both continue identically, bit for bit
        _train_step(model, optimizer, seed)
        _train_step(fresh, fresh_optimizer, seed)
    assert all(torch.equal(a, b) for a, b in zip(_params(model), _params(fresh)))
    assert read_checkpoint_meta(path)["env_steps"] == 144


def test_rng_states_round_trip_through_extra_tensors(tmp_path):
    torch.manual_seed(3); random.seed(3); np.random.seed(3)                          # noqa: E702
    state = capture_rng_state()
    expected = (torch.rand(3), random.random(), np.random.rand())
    save_training_checkpoint(tmp_path, 1, Small(), None, {}, extra_tensors=state)
    torch.manual_seed(99); random.seed(99); np.random.seed(99)                       # noqa: E702
    _, extra = load_training_checkpoint(tmp_path, Small())
    restore_rng_state(extra)
    assert torch.equal(torch.rand(3), expected[0]) and random.random() == expected[1] \
        and np.random.rand() == expected[2]


def test_only_the_newest_k_are_kept_and_the_same_step_can_be_rewritten(tmp_path):
    model = Small()
    for step in (10, 20, 30, 40, 50):
        save_training_checkpoint(tmp_path, step, model, None, {"step": step}, keep=3)
    assert [p.name for p in list_checkpoints(tmp_path)] == ["step_000000000050", "step_000000000040",
                                                           "step_000000000030"]
    save_training_checkpoint(tmp_path, 5, model, None, {"step": 5}, keep=3)          # an older step: still kept
    assert (tmp_path / "checkpoints" / "step_000000000005").is_dir()
    assert read_checkpoint_meta(tmp_path)["step"] == 5                               # latest = the one just written
    save_training_checkpoint(tmp_path, 50, model, None, {"step": 50, "again": True}, keep=3)
    assert read_checkpoint_meta(tmp_path)["again"] is True
    assert not [p for p in (tmp_path / "checkpoints").iterdir() if p.name.startswith(".")]
    with pytest.raises(ValueError, match="keep"):
        save_training_checkpoint(tmp_path, 60, model, None, {}, keep=0)
    with pytest.raises(ValueError, match="reserved"):
        save_training_checkpoint(tmp_path, 60, model, None, {"checkpoint": 1})
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        save_training_checkpoint(tmp_path, 60, model, None, {"bad": object()})
    assert not (tmp_path / "checkpoints" / "step_000000000060").exists()


def test_a_broken_latest_pointer_falls_back_to_the_newest_valid_checkpoint(tmp_path):
    model = Small()
    for step in (1, 2, 3):
        save_training_checkpoint(tmp_path, step, model, None, {"step": step})
    folder = tmp_path / "checkpoints"
    (folder / "step_000000000003" / "model.safetensors").write_bytes(b"damaged")      # newest is corrupt
    with pytest.warns(CheckpointWarning, match="SHA-256 mismatch.*newest valid checkpoint .*step_000000000002"):
        meta, _ = load_training_checkpoint(tmp_path, Small())
    assert meta["step"] == 2
    (folder / "latest").write_text("step_000000000099\n")                                 # names a missing one
    with pytest.warns(CheckpointWarning, match="does not exist"):
        assert read_checkpoint_meta(tmp_path)["step"] == 2
    (folder / "latest").unlink()                                                        # no pointer at all
    with pytest.warns(CheckpointWarning, match="latest does not exist"):
        assert resolve_checkpoint(folder) == folder / "step_000000000002"
    (folder / "latest").write_text("../../etc\n")                                       # garbage
    with pytest.warns(CheckpointWarning, match="damaged"):
        assert read_checkpoint_meta(tmp_path)["step"] == 2
    # a leftover temp folder of a killed writer is never a checkpoint
    (folder / ".tmp-step_000000000004-x").mkdir()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CheckpointWarning)
        assert read_checkpoint_meta(tmp_path)["step"] == 2
    for step in (1, 2):
        (folder / f"step_{step:012d}" / "meta.json").unlink()
    with pytest.raises(ValueError, match="no valid checkpoint in"):
        load_training_checkpoint(tmp_path, Small())
    with pytest.raises(ValueError, match="does not exist"):
        load_training_checkpoint(tmp_path / "nowhere", Small())
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no checkpoint in"):
        load_training_checkpoint(tmp_path / "empty", Small())


def test_damaged_files_are_refused(tmp_path):
    model = Small()
    path = save_training_checkpoint(tmp_path, 7, model, torch.optim.Adam(model.parameters()), {})
    weights = path / "model.safetensors"
    original = weights.read_bytes()
    weights.write_bytes(original[:-10])                                                    # truncated
    with pytest.raises(ValueError, match="model.safetensors is damaged"):
        load_training_checkpoint(path, Small())
    flipped = bytearray(original)
    flipped[-3] ^= 0x01                                                                    # one flipped bit
    weights.write_bytes(bytes(flipped))
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        load_training_checkpoint(path, Small())
    weights.write_bytes(original)
    (path / "optimizer.safetensors").unlink()
    with pytest.raises(ValueError, match="missing optimizer.safetensors"):
        load_training_checkpoint(path, Small())
    (path / "meta.json").write_text("{not json")
    with pytest.raises(ValueError, match="meta.json is damaged"):
        load_training_checkpoint(path, Small())
    (path / "meta.json").write_text(json.dumps({"format": "something/else"}))
    with pytest.raises(ValueError, match="not a dynenv_training/1 checkpoint"):
        load_training_checkpoint(path, Small())


def test_a_model_that_does_not_fit_is_refused_naming_the_key_and_left_untouched(tmp_path):
    path = save_training_checkpoint(tmp_path, 1, Small(hidden=8), None, {})
    other = Small(hidden=4)
    before = _params(other)
    with pytest.raises(ValueError, match=r"key 'a.weight' has shape \(8, 3\), the model expects \(4, 3\)"):
        load_training_checkpoint(path, other)
    assert all(torch.equal(a, b) for a, b in zip(before, _params(other)))
    extended = Small()
    extended.c = nn.Linear(2, 2)
    with pytest.raises(ValueError, match="missing key 'c.weight'"):
        load_training_checkpoint(path, extended)
    smaller = nn.Sequential()
    smaller.a = nn.Linear(3, 8)
    with pytest.raises(ValueError, match="unexpected key 'b.bias'"):
        load_training_checkpoint(path, smaller)
    model = Small()
    with pytest.raises(ValueError, match="holds no optimizer state"):
        load_training_checkpoint(path, model, torch.optim.Adam(model.parameters()))
    path = save_training_checkpoint(tmp_path, 2, model, torch.optim.Adam(model.parameters()), {})
    with pytest.raises(ValueError, match="Adam state, not one of torch.optim.sgd.SGD"):
        load_training_checkpoint(path, model, torch.optim.SGD(model.parameters(), lr=0.1))


def test_policy_files_round_trip_and_foreign_or_damaged_ones_are_refused(tmp_path):
    torch.manual_seed(1)
    model = DynEnvAgent(feature_size=16, head_mode="continuous").eval()
    path = tmp_path / "policy.safetensors"
    digest = save_policy(model, path, {"variant": "pred", "env_steps": 12})
    assert digest == sha256(path) and [p.name for p in tmp_path.iterdir()] == ["policy.safetensors"]
    loaded, meta = load_policy(path)
    assert meta == {"variant": "pred", "env_steps": 12} and not loaded.training
    assert (loaded.feature_size, loaded.head_mode, loaded.head_max) == (16, "continuous", model.head_max)
    for (name, a), (_, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    with torch.no_grad():
        h = torch.randn(4, 32)
        assert torch.equal(model.critic(h), loaded.critic(h)) and torch.equal(model.walk_head(h), loaded.walk_head(h))

    with pytest.raises(ValueError, match=r"must end in \.safetensors"):
        save_policy(model, tmp_path / "policy.pt", {})
    foreign = tmp_path / "foreign.safetensors"
    save_file({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match="not a dynenv_policy/1 file"):
        load_policy(foreign)
    flipped = bytearray(path.read_bytes())
    flipped[-5] ^= 0x10
    damaged = tmp_path / "damaged.safetensors"
    damaged.write_bytes(bytes(flipped))
    with pytest.raises(ValueError, match="cannot be read safely: tensor data checksum mismatch"):
        load_policy(damaged)
    damaged.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(ValueError, match="cannot be read safely"):
        load_policy(damaged)
    with pytest.raises(ValueError, match="does not exist"):
        load_policy(tmp_path / "missing.safetensors")


def test_a_policy_whose_weights_do_not_fit_its_config_is_refused(tmp_path):
    from safetensors.torch import save
    from dynenv_ros.agent.checkpoint import agent_config, safetensors_header, FORMAT as POLICY_FORMAT
    import hashlib
    small = DynEnvAgent(feature_size=16)
    tensors = {k: v.contiguous() for k, v in small.state_dict().items()}
    tensors.pop("critic.0.weight")
    metadata = {"format": POLICY_FORMAT, "config": json.dumps(agent_config(small)), "meta": "{}"}
    _, start = safetensors_header(save(tensors, metadata=metadata))
    metadata["data_sha256"] = hashlib.sha256(save(tensors, metadata=metadata)[start:]).hexdigest()
    path = tmp_path / "unfit.safetensors"
    path.write_bytes(save(tensors, metadata=metadata))
    with pytest.raises(ValueError, match="does not fit the model: missing key 'critic.0.weight'"):
        load_policy(path)


def test_a_kill_before_the_rename_leaves_the_previous_checkpoint_latest(tmp_path, monkeypatch):
    model = Small()
    save_training_checkpoint(tmp_path, 1, model, None, {"step": 1})
    real_rename = os.rename

    def killed(src, dst):
        if "step_000000000002" in str(dst):
            raise KeyboardInterrupt("killed")
        return real_rename(src, dst)

    monkeypatch.setattr(os, "rename", killed)
    with pytest.raises(KeyboardInterrupt):
        save_training_checkpoint(tmp_path, 2, model, None, {"step": 2})
    monkeypatch.undo()
    assert read_checkpoint_meta(tmp_path)["step"] == 1
    assert [p.name for p in list_checkpoints(tmp_path)] == ["step_000000000001"]
