"""The training config: presets load, overrides apply with YAML value syntax, and anything unknown, mistyped or
impossible is refused with an error that names the key."""
import dataclasses
import json
from pathlib import Path

import pytest

from dynenv_ros.learning.config import (VARIANTS, ConfigError, TrainConfig, field_help, load_config, parse_value)

PRESETS = Path(__file__).resolve().parents[1] / "config" / "train"


def _refused(key, match=None, **values):
    with pytest.raises(ConfigError) as info:
        TrainConfig(**values)
    assert info.value.key == key and str(info.value).startswith(f"{key}:"), str(info.value)
    if match:
        assert match in str(info.value), str(info.value)
    return str(info.value)


def test_presets_load_with_the_documented_values():
    paper = load_config(PRESETS / "paper_a2c.yaml")
    assert (paper.algorithm, paper.variant, paper.num_envs, paper.rollout_length) == ("a2c", "pred", 8, 6)
    assert paper.total_env_steps == 60_000 * 8 * 6
    assert (paper.learning_rate, paper.max_grad_norm, paper.value_coef, paper.entropy_coef) == (1e-4, 0.5, 0.5, 0.1)
    assert (paper.forward_coef, paper.inverse_coef, paper.ltp_coef, paper.self_supervised_coef) == \
        (1e-2, 1e-2, 1e-3, 1e-2)
    assert paper.gamma == 0.99 and paper.gae_lambda == 1.0
    ppo = load_config(PRESETS / "ppo.yaml")
    assert (ppo.algorithm, ppo.ppo_epochs, ppo.ppo_minibatches, ppo.ppo_clip, ppo.gae_lambda) == \
        ("ppo", 4, 4, 0.2, 0.95)
    assert ppo.normalize_advantages and ppo.entropy_coef == 0.01 and ppo.learning_rate == 3e-4
    teacher = load_config(PRESETS / "ppo_teacher.yaml")     # the ppo preset + the chaser's imitation (docs)
    assert (teacher.teacher, teacher.imitation_coef, teacher.teacher_driven_worlds, teacher.teacher_driven_env_steps,
            teacher.ppo_epochs, teacher.learning_rate) == ("chaser", 1.0, 0, 0, 2, 1e-3)
    quick = load_config(PRESETS / "quick.yaml")
    assert quick.num_envs == 2 and quick.total_env_steps < 10_000
    assert load_config(None) == TrainConfig()


def test_every_field_is_documented():
    helps = field_help()
    assert list(helps) == [f.name for f in dataclasses.fields(TrainConfig)]
    assert all(len(text) > 10 for text in helps.values())


def test_variants_select_the_papers_losses_and_overrides_apply():
    rows = {v: TrainConfig(variant=v, pretrained_encoder="enc.safetensors" if v == "recon" else None).losses()
            for v in VARIANTS}
    assert not rows["baseline"].curiosity and not rows["baseline"].localization
    assert rows["icm"].icm_forward and rows["icm"].inverse and not rows["icm"].rcm_attention
    assert rows["rcm"].rcm_attention and rows["rcm"].inverse and not rows["rcm"].icm_forward and not rows["rcm"].ltp
    assert rows["pred"].ltp and rows["pred"].rcm_attention and not rows["pred"].reconstruction
    assert rows["recon"].ltp and rows["recon"].localization and rows["recon"].reconstruction
    scratch = TrainConfig(variant="pred", use_localization=True, use_reconstruction=True).losses()
    assert scratch.localization and scratch.reconstruction
    assert not TrainConfig(variant="recon", pretrained_encoder="e", use_reconstruction=False).losses().reconstruction


def test_yaml_and_overrides_round_trip(tmp_path):
    preset = tmp_path / "mine.yaml"
    preset.write_text("# comment\nalgorithm: ppo\nnum_envs: 4\nlearning_rate: 3e-4\ntarget_kl: 0.02\n")
    config = load_config(preset, ["learning_rate=1e-4", "normalize_advantages=true", "target_kl=null",
                                  "max_minutes=2", "variant=icm", "device=cuda:0", "pretrained_encoder='a b'"])
    assert config.algorithm == "ppo" and config.num_envs == 4
    assert config.learning_rate == 1e-4 and isinstance(config.learning_rate, float)
    assert config.normalize_advantages is True and config.target_kl is None and config.variant == "icm"
    assert config.max_minutes == 2.0 and isinstance(config.max_minutes, float)     # ints given for floats
    assert config.pretrained_encoder == "a b" and config.device == "cuda:0"
    assert parse_value("1e-4") == 1e-4 and parse_value("3E5") == 3e5 and parse_value("2_000") == 2000
    # to_dict/from_dict round trip, through JSON as checkpoint metadata does
    back = TrainConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert back == config and back.to_dict() == config.to_dict()
    assert all(type(getattr(back, k)) is type(getattr(config, k)) for k in config.to_dict())
    # writing the dict as YAML and reading it back gives the same config
    dumped = tmp_path / "dumped.yaml"
    import yaml
    dumped.write_text(yaml.safe_dump(config.to_dict()))
    assert load_config(dumped) == config
    assert TrainConfig.from_dict({"num_envs": 3}) == TrainConfig(num_envs=3)     # missing keys: defaults


def test_unknown_keys_are_refused_with_a_suggestion(tmp_path):
    preset = tmp_path / "typo.yaml"
    preset.write_text("num_env: 4\n")
    with pytest.raises(ConfigError, match=r"num_env: unknown setting; did you mean 'num_envs'\?.*typo.yaml") as info:
        load_config(preset)
    assert info.value.key == "num_env"
    with pytest.raises(ConfigError, match=r"learning_rte: unknown setting; did you mean 'learning_rate'"):
        load_config(None, ["learning_rte=1e-3"])
    with pytest.raises(ConfigError, match=r"entropy_cof: .*did you mean 'entropy_coef'"):
        TrainConfig.from_dict({"entropy_cof": 0.1})
    with pytest.raises(ConfigError, match=r"num_envs: override 'num_envs' must look like key=value"):
        load_config(None, ["num_envs"])
    not_a_mapping = tmp_path / "list.yaml"
    not_a_mapping.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        load_config(not_a_mapping)


def test_unknown_choices_are_refused_naming_the_key():
    assert "did you mean 'ppo'" in _refused("algorithm", "unknown value 'ppo2'", algorithm="ppo2")
    _refused("variant", "unknown value", variant="curious")
    _refused("opponent", "unknown value", opponent="human")
    _refused("backend", "unknown value", backend="threads")
    _refused("head_mode", "unknown value", head_mode="free")
    _refused("perception", "unknown value", perception="perfect")
    _refused("device", "expected", device="gpu")


def test_wrong_types_are_refused_naming_the_key():
    _refused("num_envs", "expected an integer, got str '8'", num_envs="8")
    _refused("num_envs", "expected an integer, got bool True", num_envs=True)          # bool is not an int here
    _refused("rollout_length", "expected an integer, got float 6.0", rollout_length=6.0)
    _refused("total_env_steps", "without a decimal point", total_env_steps=2e6)
    _refused("learning_rate", "expected a number, got str", learning_rate="fast")
    _refused("gamma", "expected a number, got bool", gamma=True)
    _refused("normalize_advantages", "expected true or false, got int 1", normalize_advantages=1)
    _refused("use_localization", "expected true or false", use_localization="yes please")
    _refused("variant", "expected a string, got int", variant=3)
    _refused("seed", "expected int, got null", seed=None)
    with pytest.raises(ConfigError, match=r"^num_envs: expected an integer, got float 2.5"):
        load_config(None, ["num_envs=2.5"])
    with pytest.raises(ConfigError, match=r"^ppo_epochs: expected an integer, got bool True"):
        load_config(None, ["ppo_epochs=true"])


def test_impossible_values_are_refused_naming_the_key():
    _refused("num_envs", "must be in 1..1024", num_envs=0)
    _refused("rollout_length", "must be in 1..1024", rollout_length=0)
    _refused("players_per_team", "1..5", players_per_team=6)
    _refused("gamma", "(0, 1]", gamma=0.0)
    _refused("gamma", "(0, 1]", gamma=1.01)
    assert TrainConfig(gamma=1).gamma == 1.0
    _refused("gae_lambda", "[0, 1]", gae_lambda=-0.1)
    _refused("gae_lambda", "[0, 1]", gae_lambda=1.5)
    _refused("learning_rate", "> 0", learning_rate=0.0)
    _refused("learning_rate", "finite", learning_rate=float("nan"))
    _refused("entropy_coef", ">= 0", entropy_coef=-0.01)
    _refused("ltp_coef", ">= 0", ltp_coef=-1e-3)
    _refused("max_minutes", "> 0", max_minutes=0)
    _refused("keep_checkpoints", "must be in 1..100", keep_checkpoints=0)
    # LTP must fit in the rollout, but only when LTP is trained
    _refused("ltp_horizon", "exceeds rollout_length 4", rollout_length=4, ltp_horizon=6)
    assert TrainConfig(variant="rcm", rollout_length=4, ltp_horizon=6).rollout_length == 4
    # PPO minibatches split robot sequences: 2 envs x 1 player x 2 teams = 4 in self-play, 2 against a fixed team
    _refused("ppo_minibatches", "only 4 learning robots", algorithm="ppo", num_envs=2, players_per_team=1,
             ppo_minibatches=5)
    assert TrainConfig(algorithm="ppo", num_envs=2, players_per_team=1, ppo_minibatches=4).ppo_minibatches == 4
    _refused("ppo_minibatches", "only 2 learning robots", algorithm="ppo", num_envs=2, players_per_team=1,
             ppo_minibatches=4, opponent="scripted")
    assert TrainConfig(algorithm="a2c", num_envs=1, ppo_minibatches=64).num_envs == 1    # a2c ignores it
    # recon is the pretrained row
    _refused("pretrained_encoder", "requires the pretrained", variant="recon")
    assert TrainConfig(variant="recon", pretrained_encoder="runs/pre/policy.safetensors").losses().reconstruction
    _refused("intrinsic_reward_coef", "forward model", variant="baseline", intrinsic_reward_coef=0.1)


def test_config_is_frozen_and_replace_revalidates():
    config = TrainConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.num_envs = 3
    assert config.replace(num_envs=3).num_envs == 3
    with pytest.raises(ConfigError, match="^num_envs:"):
        config.replace(num_envs=0)
    with pytest.raises(ConfigError, match="^num_env: unknown setting"):
        config.replace(num_env=3)


def test_continuous_head_is_refused_for_training_with_the_reason():
    from dynenv_ros.learning.config import ConfigError, load_config
    import pytest
    with pytest.raises(ConfigError, match="head_mode: only 'discrete'"):
        load_config(None, ["head_mode=continuous"])


@pytest.mark.parametrize("key, value, bounds", [
    ("num_envs", 100_000_000, "1..1024"), ("num_envs", 1025, "1..1024"), ("feature_size", 100_000, "1..1024"),
    ("feature_size", 0, "1..1024"), ("players_per_team", 6, "1..5"), ("rollout_length", 5000, "1..1024"),
    ("ppo_minibatches", 5000, "1..4096"), ("ppo_epochs", 101, "1..100"), ("rollouts_per_update", 65, "1..64"),
    ("workers", 300, "1..256"), ("torch_threads", 1000, "1..256"), ("snapshot_pool", 101, "1..100"),
    ("ltp_horizon", 2000, "1..1024")])
def test_size_settings_out_of_bounds_are_refused_in_one_line_naming_key_and_bounds(key, value, bounds):
    """Checked on construction, before a world or a network exists: the 120 GB network of feature_size=100000 and
    the unbounded worlds of num_envs=100000000 are never allocated."""
    message = _refused(key, f"must be in {bounds}, got {value}", **{key: value})
    assert "\n" not in message
    with pytest.raises(ConfigError, match=f"^{key}: must be in {bounds}"):
        load_config(None, [f"{key}={value}"])


def test_size_bounds_are_in_the_help():
    helps = field_help()
    assert "1..1024" in helps["num_envs"] and "1..1024" in helps["feature_size"] and "1..256" in helps["workers"]
