"""The shipped soccer policy's two files are one policy: onnxruntime on ``policy.onnx`` gives what torch gives on
``policy.safetensors`` (to 1e-4) on real observations of a 2v2 game, the recurrent state carried over periods; the
same for the policies shipped before it, each kept in its archive folder (docs/results_data/issue26/shipped_2fd24e79/,
docs/results_data/issue39/shipped_ca882145/). The shipped file is the kept copy that met the test split, byte for
byte (the digest its test-ledger rows record); the one shipped before it, written from a kept training checkpoint,
names that checkpoint and holds the weights of the policy file committed for it (docs/results.md, "Learning beyond
the teacher")."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from dynenv_ros.agent.checkpoint import load_policy, safetensors_header  # noqa: E402
from dynenv_ros.agent.export import OnnxPolicy, TorchPolicy  # noqa: E402
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded  # noqa: E402
from dynenv_ros.envs.robocup_v0 import parallel_env  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "policy_node" / "pretrained"
ARCHIVED = ROOT / "docs" / "results_data" / "issue26" / "shipped_2fd24e79"
LEAGUE_ARCHIVED = ROOT / "docs" / "results_data" / "issue39" / "shipped_ca882145"
POLICIES = ROOT / "docs" / "results_data" / "issue39" / "policies"
# league_privileged_5v5_s0's kept copy at its end (+400,128 env steps), the one that met both 2v2 bars on test
CHOSEN = POLICIES / "league_privileged_5v5_s0_400k.safetensors"
# the policy file committed for league_anchor_s0's checkpoint at +270,592 env steps, shipped 29-30 Nov 2026
LEAGUE_CHOSEN = POLICIES / "league_anchor_s0_271k.safetensors"
PERIODS = 4


def _observations(seed: int) -> list[dict[str, np.ndarray]]:
    """PERIODS consecutive padded observations of the 4 robots of a 2v2 game (realistic perception, the pose
    estimate on), sampled actions, stacked with the robots leading."""
    env = parallel_env(players_per_team=2, observation="padded", localization="estimate",
                       perception="realistic")
    obs, _ = env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed)
    out = []
    for _ in range(PERIODS):
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
        out.append({key: np.stack([obs[a][key] for a in env.possible_agents]) for key in obs[env.possible_agents[0]]})
    env.close()
    return out


@pytest.mark.parametrize("folder", [SHIPPED, LEAGUE_ARCHIVED, ARCHIVED], ids=["shipped", "archived", "archived_first"])
def test_the_onnx_file_acts_as_the_safetensors_file(folder):
    model, _ = load_policy(folder / "policy.safetensors")
    onnx_policy, torch_policy = OnnxPolicy(folder / "policy.onnx"), TorchPolicy(model.eval())
    assert onnx_policy.uses_pose == torch_policy.uses_pose
    assert onnx_policy.feature_size == model.feature_size and onnx_policy.head_mode == model.head_mode
    state_onnx, state_torch = onnx_policy.initial_state(4), torch_policy.initial_state(4)
    for batch in _observations(seed=3):
        inputs = (*streams_from_padded(batch), *side_inputs(batch, model.head_max, pose=model.uses_pose))
        a, b = onnx_policy(*inputs, state_onnx), torch_policy(*inputs, state_torch)
        for name in ("walk", "turn", "kick", "head", "value", "pose"):
            np.testing.assert_allclose(getattr(a, name).numpy(), getattr(b, name).numpy(), atol=1e-4, rtol=0,
                                       err_msg=name)
        for x, y in zip(a.state, b.state):
            np.testing.assert_allclose(x.numpy(), y.numpy(), atol=1e-4, rtol=0)
        state_onnx, state_torch = a.state, b.state


def test_the_shipped_file_is_the_chosen_kept_copy_byte_for_byte():
    assert (SHIPPED / "policy.safetensors").read_bytes() == CHOSEN.read_bytes()
    meta = json.loads(safetensors_header(CHOSEN.read_bytes())[0]["__metadata__"]["meta"])
    assert meta["env_steps"] == 400_128 and meta["config"]["players_per_team"] == 5
    assert "source_checkpoint" not in meta and "numpy_rng" not in meta


def test_the_archived_league_file_names_its_checkpoint_and_holds_the_chosen_policys_weights():
    shipped, chosen = (safetensors_header((path).read_bytes())[0]["__metadata__"]
                       for path in (LEAGUE_ARCHIVED / "policy.safetensors", LEAGUE_CHOSEN))
    assert shipped["data_sha256"] == chosen["data_sha256"]           # the tensor data, byte for byte
    assert json.loads(shipped["config"]) == json.loads(chosen["config"])
    meta = json.loads(shipped["meta"])
    source = meta["source_checkpoint"]
    assert source["step"] == meta["env_steps"] == 270_592
    assert source["model_sha256"].startswith("7798c7d5dc80")        # the digest the test ledger's rows record
    assert source["code_revision"] == meta["code_revision"]
    assert "numpy_rng" not in meta                                   # a policy file resumes nothing
