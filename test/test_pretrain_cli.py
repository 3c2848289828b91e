"""dynenv-pretrain: data generation, the tiny end-to-end pretraining through the CLI, and its refusals."""
import json

import numpy as np
import pytest
import torch

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.learning.algo.networks import make_agent
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.pretrain import data, main, model, train


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("pretrain_data")
    assert main(["generate", "--out", str(folder), "--train", "16", "--test", "8", "--seed", "3",
                          "--worlds-per-batch", "8"]) == 0
    return folder


@pytest.fixture(scope="module")
def trained(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("pretrain_run")
    assert main(["train", "--data", str(data_dir), "--out", str(out), "--epochs", "3", "--seed", "0"]) == 0
    return out


def test_generation_is_deterministic_and_holds_the_documented_shapes():
    seed = np.random.SeedSequence(7)
    a = data.generate_split(3, seed, worlds_per_batch=2)
    b = data.generate_split(3, np.random.SeedSequence(7), worlds_per_batch=2)
    assert set(a) == set(data.ARRAY_KEYS)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    S, T, A, R = 3, data.OBSERVATIONS, 4, 3
    assert T == 7
    assert a["landmarks"].shape[:4] == (S, T, A, 5) and a["landmarks"].shape[-1] == 19
    assert a["landmark_mask"].shape == a["landmarks"].shape[:-1]
    assert a["objects"].shape[:4] == (S, T, A, 5) and a["object_mask"].shape == a["objects"].shape[:-1]
    assert a["proprioception"].shape == (S, T, A, 5, 4)
    assert a["game"].shape == (S, T, A, 3) and a["previous_action"].shape == (S, T, A, 4)
    assert a["pose"].shape == (S, T, A, 6) and a["ball"].shape == (S, T, A, 3)
    assert a["robots"].shape == (S, T, A, R, 6)
    assert a["ball_seen"].shape == a["ball_known"].shape == (S, T, A)
    assert a["robots_seen"].shape == a["robots_known"].shape == (S, T, A, R)
    assert a["actions"].shape == (S, T - 1, A, 4) and a["actions"].dtype == np.int64
    # two random discrete actions, each held for 3 periods; the observation after a step carries it
    acts = a["actions"]
    assert (acts[:, 0:3] == acts[:, [0]]).all() and (acts[:, 3:6] == acts[:, [3]]).all()
    assert (acts >= 0).all() and (acts < np.array([5, 3, 3, 7])).all()
    np.testing.assert_array_equal(a["previous_action"][:, 1:, :, :3], acts[..., :3].astype(np.float32))
    assert (a["previous_action"][:, 0] == 0).all()
    # known = seen at least once so far
    np.testing.assert_array_equal(a["ball_known"], np.maximum.accumulate(a["ball_seen"], axis=1))
    assert (np.diff(a["robots_known"], axis=1) >= 0).all()
    # another seed gives other sequences
    c = data.generate_split(3, np.random.SeedSequence(8), worlds_per_batch=2)
    assert not np.array_equal(a["pose"], c["pose"])


def test_data_files_load_without_pickle(data_dir):
    for split, count in (("train", 16), ("test", 8)):
        with np.load(data_dir / f"{split}.npz", allow_pickle=False) as archive:
            meta = json.loads(str(archive["meta"]))
            assert archive["pose"].shape == (count, 7, 4, 6)
        assert meta["format"] == data.DATA_FORMAT and meta["sequences"] == count
        assert meta["head_mode"] == "discrete" and meta["split"] == split
        loaded = data.load_split(data_dir / f"{split}.npz")
        assert loaded.sequences == count and loaded.robots == 4


def test_tiny_pretraining_end_to_end(trained, data_dir, capsys):
    metrics = json.loads((trained / "metrics.json").read_text())
    history = metrics["history"]
    assert len(history) == 3
    assert history[-1]["train"]["loss"] < history[0]["train"]["loss"]
    assert 1 <= metrics["best_epoch"] <= 3
    agent, meta = load_policy(trained / "pretrained.safetensors")
    assert meta["kind"] == train.POLICY_KIND and meta["privileged_seeding"] is False
    assert "pose_seeder" not in meta
    test = metrics["test"]
    for block in ("all", "last"):
        assert set(test[block]["localization"]) == {"25cm", "50cm", "1m"}
        assert set(test[block]["reconstruction_ap"]) == {"ball", "robots", "mean"}
        assert set(test[block]["reconstruction_ap_ignore_unknown"]) == {"ball", "robots", "mean"}
        assert set(test[block]["original_ap"]["mean"]) == {"52cm", "1.04m", "2.08m"}
    assert len(test["per_step"]) == 7
    assert test["last"]["robot_steps"] == 8 * 4 and test["all"]["robot_steps"] == 8 * 4 * 7
    # the trainer's encoder loading takes the file
    encoder = {k: v for k, v in agent.state_dict().items() if k.startswith(train.ENCODER_PREFIXES)}
    fresh = make_agent(TrainConfig())
    assert not fresh.load_state_dict(encoder, strict=False).unexpected_keys
    # evaluate reproduces the test figures of the file
    capsys.readouterr()
    assert main(["evaluate", "--data", str(data_dir), "--policy", str(trained / "pretrained.safetensors"),
                          "--json", str(trained / "eval.json")]) == 0
    printed = capsys.readouterr().out
    assert "reconstruction AP, mean" in printed and "paper Table 3" in printed
    again = json.loads((trained / "eval.json").read_text())["test"]
    assert again["all"]["localization"] == pytest.approx(test["all"]["localization"])
    assert again["all"]["reconstruction_ap"]["mean"] == pytest.approx(test["all"]["reconstruction_ap"]["mean"])


def test_privileged_seeding_round_trip(data_dir, tmp_path):
    out = tmp_path / "privileged"
    assert main(["train", "--data", str(data_dir), "--out", str(out), "--epochs", "1",
                          "--privileged-seeding", "--validation-fraction", "0"]) == 0
    agent, seeder, meta = train.load_pretrained(out / "pretrained.safetensors")
    assert meta["privileged_seeding"] is True and seeder is not None
    assert meta["validation"].startswith("the test set")
    pose = torch.zeros(5, 6)
    state = model.initial_state(agent, pose, seeder, None)
    assert torch.equal(state[0], torch.zeros(5, 64)) and torch.equal(state[2], torch.zeros(5, 64))
    assert torch.allclose(state[1], torch.tanh(seeder.linear.bias).expand(5, 64))


def _fails(capsys, argv, needle):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("dynenv-pretrain: error:") and needle in err, err


def test_bad_arguments_and_files_exit_2(capsys, data_dir, tmp_path):
    _fails(capsys, ["train", "--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")], "does not exist")
    _fails(capsys, ["generate", "--out", str(tmp_path / "g"), "--train", "0"], "at least 1")
    _fails(capsys, ["train", "--data", str(data_dir), "--out", str(tmp_path / "o"), "--epochs", "0"], "--epochs")
    _fails(capsys, ["train", "--data", str(data_dir), "--out", str(tmp_path / "o"), "--validation-fraction", "1"],
           "validation")
    _fails(capsys, ["evaluate", "--data", str(data_dir), "--policy", str(tmp_path / "none.safetensors")],
           "does not exist")
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "train.npz").write_bytes(b"not a zip file at all")
    (corrupt / "test.npz").write_bytes((data_dir / "test.npz").read_bytes()[:5000])
    _fails(capsys, ["train", "--data", str(corrupt), "--out", str(tmp_path / "o")], "corrupt")
    _fails(capsys, ["evaluate", "--data", str(corrupt), "--policy", str(tmp_path / "x.safetensors")], "corrupt")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    np.savez(foreign / "test.npz", pose=np.zeros(3))
    _fails(capsys, ["evaluate", "--data", str(foreign), "--policy", str(tmp_path / "x.safetensors")], "lacks")
    with pytest.raises(SystemExit) as exit_info:
        main(["generate", "--train", "4"])          # --out missing: argparse, one line
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err
    with pytest.raises(SystemExit) as exit_info:
        main(["fly"])
    assert exit_info.value.code == 2
