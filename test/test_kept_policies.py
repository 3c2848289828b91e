"""Policies kept at env-step marks (``keep_policy_every_env_steps``, ``learning/run/kept_policies.py``): one file per
mark passed, named by the env steps at which it was written, never more than one per update; a resumed run goes on
to the marks it had not passed; the files load as policies and say their mark."""
from __future__ import annotations

import pytest

from dynenv_ros.agent.checkpoint import load_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.run.kept_policies import KeptPolicies, kept_policy_path


def _agent() -> DynEnvAgent:
    return DynEnvAgent(feature_size=16)


def test_a_policy_is_kept_once_per_mark_passed_at_the_update_that_passes_it(tmp_path):
    kept = KeptPolicies(100, 0)
    agent, written = _agent(), []
    for env_steps in (32, 64, 96, 128, 160, 192, 224, 512, 544):      # 512 passes 300, 400 and 500 at once
        path = kept.after_update(tmp_path, env_steps, agent, {"note": "test"})
        written.append(None if path is None else path.name)
    assert [w for w in written if w] == ["step_000000000128.safetensors", "step_000000000224.safetensors",
                                         "step_000000000512.safetensors"]
    _, meta = load_policy(kept_policy_path(tmp_path, 512))
    assert meta["kept_at_mark"] == 500 and meta["note"] == "test"


def test_a_resumed_run_goes_on_to_the_marks_it_had_not_passed(tmp_path):
    kept = KeptPolicies(250, 600)                    # resumed at 600: 250 and 500 were passed before
    assert kept.after_update(tmp_path, 700, _agent(), {}) is None
    assert kept.after_update(tmp_path, 760, _agent(), {}).name == "step_000000000760.safetensors"
    assert KeptPolicies(250, 500).next_mark == 750   # a checkpoint exactly at a mark: that mark was passed


@pytest.mark.parametrize("every", [0, -5, True, 2.5])
def test_a_mark_spacing_that_is_not_a_positive_whole_number_is_refused(every):
    with pytest.raises(ValueError, match="positive number of env steps"):
        KeptPolicies(every, 0)


def test_the_training_setting_is_bounded_and_optional():
    assert TrainConfig().keep_policy_every_env_steps is None
    with pytest.raises(ConfigError) as error:
        TrainConfig(keep_policy_every_env_steps=0)
    assert error.value.key == "keep_policy_every_env_steps"
