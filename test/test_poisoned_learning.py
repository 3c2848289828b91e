"""Issue 27 item 3, as the attacker: poisoned experience (forged early actions, extreme log-probabilities and
values, NaN rewards), NaN gradients and NaN policy files never reach the weights, and every refusal is counted."""
import copy
import logging

import numpy as np
import pytest
import torch

from dynenv_ros.agent.checkpoint import load_policy, policy_bytes, save_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.algo.ppo import UpdateSettings, update
from dynenv_ros.learning.run.checkpoints import load_training_checkpoint, save_training_checkpoint
from dynenv_ros.learning.messages.assembly import ExperienceAssembler
from dynenv_ros.learning.messages.scenarios import SoccerExperience
from dynenv_ros.learning.algo.networks import TrainingNetworks
from dynenv_ros.learning.sampling.collector import RolloutCollector
from experience_game import HEAD_MAX, HEAD_UNITS, play

T = 4
ROBOT = "team_a_0"


# -- experience ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def game():
    return play(episodes=3, players=1, seed=0, episode_seconds=3.0)


def _feed(messages):
    assembler = ExperienceAssembler(T, SoccerExperience(1, _frames(messages), HEAD_MAX, HEAD_UNITS))
    for kind, robot, msg in messages:
        {"frame": assembler.add_frame, "action": assembler.add_action,
         "feedback": assembler.add_feedback}.get(kind, lambda *a: None)("game", robot, msg)
    return assembler, [s for s in assembler.take() if s.stream == ("game", ROBOT)]


def _frames(messages):
    return next(m.frames_per_period for k, _, m in messages if k == "frame")


def _forge_early(game, **fields):
    """The real messages, with a forged Action for every answer of ROBOT sent before the frames it answers (the
    attacker knows the next period's number before it runs): policy_version current, other learning fields
    ``fields``."""
    out, forged = [], 0
    for kind, robot, msg in game.messages:
        if kind == "frame" and robot == ROBOT and msg.frame_index == 0:
            real = next((m for k, r, m in game.messages if k == "action" and r == ROBOT
                         and m.episode_id == msg.episode_id and m.motion_period == msg.motion_period + 1), None)
            if real is not None:
                evil = copy.deepcopy(real)
                evil.walk = (real.walk + 1) % 5
                for key, value in fields.items():
                    setattr(evil, key, value)
                out.append(("action", ROBOT, evil))
                forged += 1
        out.append((kind, robot, msg))
    return out, forged


def _real_log_probs(game):
    return {(m.episode_id, m.motion_period - 1): m.log_prob for k, r, m in game.messages
            if k == "action" and r == ROBOT}


def _assert_learnt_from_real(sequences, game):
    real = _real_log_probs(game)
    assert sequences
    for sequence in sequences:
        for t, key in enumerate(sequence.keys[:-1]):
            assert sequence.log_probs[t] == np.float32(real[key])
        assert np.isfinite(sequence.values).all() and np.isfinite(sequence.rewards).all()


def test_a_forged_early_action_in_bounds_gives_way_to_the_accepted_one(game):
    messages, forged = _forge_early(game, log_prob=-0.5, value=1.0)
    assembler, sequences = _feed(messages)
    _, clean = _feed(game.messages)
    assert assembler.counts["early_replaced"] == forged > 0
    assert len(sequences) == len(clean)
    _assert_learnt_from_real(sequences, game)


def test_forged_early_actions_with_extreme_fields_are_refused_as_out_of_range(game):
    messages, forged = _forge_early(game, log_prob=-1e30, value=3e38)
    assembler, sequences = _feed(messages)
    assert assembler.counts["out_of_range"] == forged and "log_prob" in assembler.last_refused
    _assert_learnt_from_real(sequences, game)
    for fields in ({"log_prob": -0.1, "value": 3e38}, {"log_prob": -51.0}):
        messages, forged = _forge_early(game, **fields)
        assembler, sequences = _feed(messages)
        assert assembler.counts["out_of_range"] == forged
        _assert_learnt_from_real(sequences, game)


def test_two_rival_answers_after_the_frames_are_no_step(game):
    messages = []
    for kind, robot, msg in game.messages:
        messages.append((kind, robot, msg))
        if kind == "action" and robot == ROBOT:       # a forged twin right after the real one
            evil = copy.deepcopy(msg)
            evil.log_prob, evil.walk = -0.25, (msg.walk + 1) % 5
            messages.append((kind, robot, evil))
    assembler, sequences = _feed(messages)
    assert assembler.counts["contested"] > 0 and assembler.counts["contested_cuts"] > 0
    assert not sequences                              # nothing learnt from a guess
    for sequence in sequences:
        assert -0.25 not in sequence.log_probs


def test_nan_and_huge_rewards_are_refused_and_counted(game):
    messages = []
    for kind, robot, msg in game.messages:
        if kind == "feedback" and robot == ROBOT and msg.motion_period == 2:
            for value in (float("nan"), 1e6):
                evil = copy.deepcopy(msg)
                evil.reward_primary = value
                messages.append((kind, robot, evil))     # sent before the real feedback
        messages.append((kind, robot, msg))
    assembler, sequences = _feed(messages)
    assert assembler.counts["malformed"] == 3 and assembler.counts["out_of_range"] == 3
    _assert_learnt_from_real(sequences, game)


# -- the update --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def rollout_setup():
    torch.manual_seed(3)
    env = SoccerVectorEnv(2, backend="inprocess", config={"players_per_team": 1, "episode_seconds": 2.0},
                          targets=True)
    agent = DynEnvAgent()
    networks = TrainingNetworks(agent, horizon=3)
    collector = RolloutCollector(env, agent, np.arange(2), None, torch.Generator().manual_seed(3), seed=3)
    rollout = collector.collect(6)
    yield networks, rollout
    env.close()


def _weights(networks):
    return [p.detach().clone() for p in networks.parameters()]


@pytest.mark.parametrize("poison", ["log_prob", "value", "reward"])
@pytest.mark.parametrize("ppo", [True, False])
def test_a_poisoned_rollout_skips_the_update_and_leaves_the_weights(rollout_setup, poison, ppo, caplog):
    networks, rollout = rollout_setup
    tensors = {k: (v.clone() if torch.is_tensor(v) else v) for k, v in rollout.as_tensors().items()}
    if poison == "log_prob":
        tensors["log_probs"][0, 0] = -1e30
    elif poison == "value":
        tensors["values"][0, 0] = 3e38
    else:
        tensors["rewards"][0, 0] = float("nan")
    optimizer = torch.optim.Adam(networks.parameters(), lr=1e-3)
    before = _weights(networks)
    with caplog.at_level(logging.ERROR, logger="dynenv_ros.learning.algo.ppo"):
        stats = update(networks, optimizer, tensors, UpdateSettings(algorithm="ppo" if ppo else "a2c", minibatches=1,
                                                                   epochs=2))
    after = _weights(networks)
    assert all(bool(torch.isfinite(a).all()) for a in after)
    if poison == "log_prob" and not ppo:        # A2C never reads the behaviour's log-probability: harmless
        return
    skipped = stats["nonfinite_loss_skipped"] + stats["nonfinite_gradient_skipped"]
    assert skipped >= 1
    assert any("non-finite" in r.getMessage() for r in caplog.records if r.levelno == logging.ERROR)
    assert all(torch.equal(b, a) for b, a in zip(before, after))


def test_a_nan_gradient_skips_the_step_and_is_counted(rollout_setup):
    networks, rollout = rollout_setup
    param = networks.agent.kick_head.weight             # the policy loss reaches it
    handle = param.register_hook(lambda grad: torch.full_like(grad, float("nan")))
    try:
        optimizer = torch.optim.Adam(networks.parameters(), lr=1e-3)
        before = _weights(networks)
        stats = update(networks, optimizer, rollout.as_tensors(), UpdateSettings(minibatches=1, epochs=1))
    finally:
        handle.remove()
    assert stats["nonfinite_gradient_skipped"] == 1 and stats["nonfinite_loss_skipped"] == 0
    assert all(torch.equal(b, a) for b, a in zip(before, _weights(networks)))
    stats = update(networks, optimizer, rollout.as_tensors(), UpdateSettings(minibatches=1, epochs=1))
    assert stats["nonfinite_gradient_skipped"] == 0          # and a clean update still steps
    assert any(not torch.equal(b, a) for b, a in zip(before, _weights(networks)))


# -- files ------------------------------------------------------------------------------------------------------
def _poisoned_policy_file(tmp_path):
    """A policy file whose one tensor holds a NaN, written past the saver's own refusal (as an attacker would)."""
    model = DynEnvAgent()
    path = tmp_path / "policy.safetensors"
    save_policy(model, path)
    with torch.no_grad():
        model.kick_head.weight[0, 0] = float("nan")
    import dynenv_ros.agent.checkpoint as checkpoint
    original = checkpoint.refuse_non_finite
    checkpoint.refuse_non_finite = lambda *a: None
    try:
        path.write_bytes(policy_bytes(model))
    finally:
        checkpoint.refuse_non_finite = original
    return model, path


def test_a_policy_file_with_one_nan_tensor_is_refused_naming_it(tmp_path):
    model, path = _poisoned_policy_file(tmp_path)
    with pytest.raises(ValueError, match="NaN or infinite values in tensor 'kick_head.weight'"):
        load_policy(path)


def test_non_finite_weights_are_never_saved_or_published(tmp_path):
    model = DynEnvAgent()
    with torch.no_grad():
        model.kick_head.bias[0] = float("inf")
    with pytest.raises(ValueError, match="kick_head.bias"):
        policy_bytes(model)
    with pytest.raises(ValueError, match="kick_head.bias"):
        save_policy(model, tmp_path / "p.safetensors")
    with pytest.raises(ValueError, match="kick_head.bias"):
        save_training_checkpoint(tmp_path / "run", 1, model, None, {})
    assert not list(tmp_path.iterdir())


def test_a_training_checkpoint_with_a_nan_is_refused_on_load(tmp_path):
    model = DynEnvAgent()
    save_training_checkpoint(tmp_path / "run", 1, model, None, {})
    import dynenv_ros.learning.run.checkpoints as checkpoints
    with torch.no_grad():
        model.kick_head.weight[0, 0] = float("nan")
    original = checkpoints.refuse_non_finite
    checkpoints.refuse_non_finite = lambda *a: None
    try:
        save_training_checkpoint(tmp_path / "run", 2, model, None, {})
    finally:
        checkpoints.refuse_non_finite = original
    with pytest.raises(ValueError, match="kick_head.weight"):
        load_training_checkpoint(tmp_path / "run", DynEnvAgent())
