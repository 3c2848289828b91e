"""PPO's losses against numbers worked out by hand (issue 26): the clipped surrogate (inside the clip range, clipped
above 1 + ε and below 1 − ε, the min() keeping the unclipped term), advantage normalisation, the value loss plain
and clipped, the entropy bonus, and decoupled PPO's proximal clip centre and behaviour weight
(``learning.algo.ppo.ppo_loss`` alone and within ``minibatch_loss``, ``_proximal``, ``_fused_proximal``).

A stub network stands in for the agent: one two-way categorical head whose probability of the taken action (action 0)
is chosen per robot — so each ratio π/π_old is an exact fraction — and chosen critic values. One step (T = 1), 2–4
robots. Every expected number is written out below with its arithmetic; none comes from the project's functions.
ε = 0.2 throughout. H(p) = −p·ln p − (1 − p)·ln(1 − p) is a two-way head's entropy.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from dynenv_ros.learning.algo import ppo as algorithms
from dynenv_ros.learning.algo.ppo import UpdateSettings, _proximal, minibatch_loss, ppo_loss

TOL = 2e-6            # the literals are rounded to 6 decimals


class _Agent:
    head_max = None

    def distributions(self, step):
        return [torch.distributions.Categorical(logits=step.walk)]


LEARNER = SimpleNamespace(agent=_Agent())


def _out(p, values=None):
    """The stub network's output for robots whose taken action has probability ``p``: walk logits (T, B, 2) =
    (ln p, ln(1 − p)), critic values (T + 1, B) (zeros unless given), both leaves with gradients."""
    logits = torch.tensor([[[math.log(q), math.log(1 - q)] for q in p]], dtype=torch.float64, requires_grad=True)
    value = torch.tensor(values if values is not None else [[0.0] * len(p)] * 2, dtype=torch.float64,
                         requires_grad=True)
    return SimpleNamespace(walk=logits, value=value)


def _rollout(p_old, can_act=None, **fields):
    """A one-step rollout of robots that took action 0 with (behaviour) probability ``p_old``; ``fields``: more
    (T, B) or (T + 1, B) entries (values, rewards, episode_end …) as nested lists."""
    B = len(p_old)
    rollout = {"obs": {}, "initial_state": (), "starts": torch.zeros(2, B, dtype=torch.bool),
               "actions": torch.zeros(1, B, 1, dtype=torch.long),
               "can_act": torch.tensor([can_act or [True] * B, [True] * B]),
               "log_probs": torch.tensor([[math.log(q) for q in p_old]], dtype=torch.float64),
               "values": torch.zeros(2, B, dtype=torch.float64)}
    for name, value in fields.items():
        rollout[name] = torch.tensor(value, dtype=torch.bool if name in ("episode_end", "truncated")
                                     else torch.float64)
    return rollout


def _settings(**overrides):
    base = dict(algorithm="ppo", clip=0.2, policy_coef=1.0, value_coef=0.0, entropy_coef=0.0, use_forward=False,
                use_rcm=False, use_inverse=False, use_ltp=False)
    return UpdateSettings(**{**base, **overrides})


def _loss(monkeypatch, settings, out, rollout, adv=None, ret=None):
    """(loss, logged scalars) of ``minibatch_loss`` on every robot with the stub network's output ``out``;
    ``adv``/``ret`` per robot (None: decoupled PPO's fused pass computes them)."""
    monkeypatch.setattr(algorithms, "run_sequence", lambda agent, obs, state, starts: out)
    logged = {}

    def as_step(x):
        return None if x is None else torch.tensor([x], dtype=torch.float64)

    loss, _ = minibatch_loss(LEARNER, rollout, torch.arange(rollout["actions"].shape[1]), as_step(adv),
                              as_step(ret), settings, lambda name, value: logged.__setitem__(name, float(value)))
    return loss, logged


def _close(actual, expected):
    actual = float(actual.detach()) if torch.is_tensor(actual) else actual
    assert actual == pytest.approx(expected, abs=TOL), (actual, expected)


CLIP_CASES = {
    # r = 0.55 / 0.5 = 1.1 (inside [0.8, 1.2]), A = 2:   min(1.1·2, 1.1·2)        =  2.2, unclipped
    # r = 0.5 / 0.4 = 1.25 (above 1.2),       A = 1:   min(1.25·1, 1.2·1)       =  1.2, clipped (no gradient)
    # r = 0.3 / 0.6 = 0.5 (below 0.8),        A = −1:  min(0.5·−1, 0.8·−1)      = −0.8, clipped (no gradient)
    # policy loss = −(2.2 + 1.2 − 0.8) / 3 = −0.866667
    # (min → max would give −(2.2 + 1.25 − 0.5)/3 = −0.983333; ε = 0.3 −(2.2 + 1.25 − 0.7)/3 = −0.916667;
    #  the sign flipped +0.866667)
    # d loss / d logit₀ of an unclipped robot = −(1/N)·r·A·(1 − p): −(1/3)·1.1·2·0.45 = −0.33
    # clip fraction: |r − 1| > 0.2 for 2 of 3 = 0.666667 (|r − 1| > 0.3 for 1 of 3)
    # approx KL = mean((r − 1) − ln r) = (0.1 − 0.095310 + 0.25 − 0.223144 − 0.5 + 0.693147) / 3 = 0.074898
    "clipped": dict(p_old=[0.5, 0.4, 0.6], p=[0.55, 0.5, 0.3], adv=[2.0, 1.0, -1.0], loss=-0.866667,
                    grad=[-0.33, 0.0, 0.0], clip_fraction=0.666667, approx_kl=0.074898),
    # r = 1.5 (above 1.2), A = −2:  min(1.5·−2, 1.2·−2) = min(−3.0, −2.4) = −3.0, unclipped
    # r = 0.5 (below 0.8), A = 1:   min(0.5·1, 0.8·1)   = min(0.5, 0.8)   =  0.5, unclipped
    # policy loss = −(−3.0 + 0.5) / 2 = 1.25   (min → max: −(−2.4 + 0.8) / 2 = 0.8)
    # gradients −(1/2)·1.5·(−2)·(1 − 0.6) = 0.6 and −(1/2)·0.5·1·(1 − 0.3) = −0.175
    # clip fraction 2/2 = 1; approx KL (0.094535 + 0.193147) / 2 = 0.143841
    "min_keeps_unclipped": dict(p_old=[0.4, 0.6], p=[0.6, 0.3], adv=[-2.0, 1.0], loss=1.25, grad=[0.6, -0.175],
                                clip_fraction=1.0, approx_kl=0.143841),
}


@pytest.mark.parametrize("case", CLIP_CASES, ids=list(CLIP_CASES))
def test_the_clipped_surrogate_against_hand_computed_numbers(case, monkeypatch):
    c = CLIP_CASES[case]
    out = _out(c["p"])
    loss, logged = _loss(monkeypatch, _settings(), out, _rollout(c["p_old"]), c["adv"], [0.0] * len(c["p"]))
    _close(loss, c["loss"])
    _close(logged["policy_loss"], c["loss"])
    _close(logged["clip_fraction"], c["clip_fraction"])
    _close(logged["approx_kl"], c["approx_kl"])
    loss.backward()
    grad = out.walk.grad[0]
    for b, expected in enumerate(c["grad"]):
        _close(float(grad[b, 0]), expected)
        _close(float(grad[b, 1]), -expected)       # logits (ln p, ln(1 − p)): the two move oppositely


def test_advantages_are_normalised_over_the_steps_where_the_robot_could_act(monkeypatch):
    # acting robots' advantages 1, 2, 3, −2 (the fifth, 100, could not act and is left out of mean and std):
    # mean = 4/4 = 1; deviations 0, 1, 2, −3; variance (0 + 1 + 4 + 9)/4 = 3.5 (population); std = 1.870829
    # normalised: 0, 1/1.870829 = 0.534522, 2/1.870829 = 1.069045, −3/1.870829 = −1.603567
    # ratios 0.55/0.5 = 1.1, 0.45/0.5 = 0.9, 1.1, 0.9, all inside the clip range:
    # surrogates 0, 0.9·0.534522 = 0.481070, 1.1·1.069045 = 1.175950, 0.9·−1.603567 = −1.443211
    # policy loss = −(0 + 0.481070 + 1.175950 − 1.443211)/4 = −0.053452
    # (the fifth robot in the statistics: 0.497031; the unbiased std 2.160247: −0.046291; not normalised: −1.1)
    rollout = _rollout([0.5] * 5, can_act=[True, True, True, True, False])
    loss, _ = _loss(monkeypatch, _settings(normalize_advantages=True), _out([0.55, 0.45, 0.55, 0.45, 0.5]), rollout,
                    [1.0, 2.0, 3.0, -2.0, 100.0], [0.0] * 5)
    _close(loss, -0.053452)


def test_the_value_loss_is_the_squared_error_at_every_step_times_its_coefficient(monkeypatch):
    # V = 0.5, 2.0, −1.0 against returns 1.5, 0.5, 1.0: errors (−1)² = 1, 1.5² = 2.25, (−2)² = 4
    # the third robot could not act, but its value is still learnt: value loss = (1 + 2.25 + 4)/3 = 2.416667
    # loss = value_coef·2.416667 = 0.5·2.416667 = 1.208333
    # d loss / d V = 0.5·2·(V − R)/3 = (V − R)/3: −0.333333, 0.5, −0.666667; the bootstrap row V(s₁) gets none
    out = _out([0.5] * 3, values=[[0.5, 2.0, -1.0], [9.0, 9.0, 9.0]])
    loss, logged = _loss(monkeypatch, _settings(policy_coef=0.0, value_coef=0.5), out,
                         _rollout([0.5] * 3, can_act=[True, True, False]), [0.0] * 3, [1.5, 0.5, 1.0])
    _close(logged["value_loss"], 2.416667)
    _close(loss, 1.208333)
    loss.backward()
    for b, expected in enumerate([-0.333333, 0.5, -0.666667]):
        _close(float(out.value.grad[0, b]), expected)
    assert (out.value.grad[1] == 0).all()


def test_the_clipped_value_loss_takes_the_larger_error_of_the_clipped_value(monkeypatch):
    # old values 1.0 each; the clipped value is 1 + clamp(V − 1, −0.2, 0.2):
    # V 1.5, R 2.0: unclipped (−0.5)² = 0.25, clipped 1.2 → (−0.8)² = 0.64; max 0.64 (clipped: no gradient)
    # V 0.5, R 0.0: unclipped 0.5² = 0.25,    clipped 0.8 → 0.8² = 0.64;     max 0.64 (clipped: no gradient)
    # V 1.1, R 3.0: inside, (−1.9)² = 3.61 both
    # V 1.5, R 0.0: unclipped 1.5² = 2.25,    clipped 1.2 → 1.2² = 1.44;     max 2.25 (unclipped)
    # value loss = (0.64 + 0.64 + 3.61 + 2.25)/4 = 1.785 (min instead of max: 1.3875); loss = 0.5·1.785 = 0.8925
    # d loss / d V = 0.5·2·(V − R)/4: 0, 0, (1.1 − 3)/4 = −0.475, 1.5/4 = 0.375
    out = _out([0.5] * 4, values=[[1.5, 0.5, 1.1, 1.5], [0.0] * 4])
    rollout = _rollout([0.5] * 4, values=[[1.0] * 4, [0.0] * 4])
    loss, logged = _loss(monkeypatch, _settings(policy_coef=0.0, value_coef=0.5, clip_value_loss=True), out,
                         rollout, [0.0] * 4, [2.0, 0.0, 3.0, 0.0])
    _close(logged["value_loss"], 1.785)
    _close(loss, 0.8925)
    loss.backward()
    for b, expected in enumerate([0.0, 0.0, -0.475, 0.375]):
        _close(float(out.value.grad[0, b]), expected)


def test_the_loss_adds_the_value_term_and_subtracts_the_entropy_bonus(monkeypatch):
    # robots 1–2 act, robot 3 could not (out of the policy and entropy terms, in the value term):
    # policy: r = 0.55/0.5 = 1.1, A = 2 → 2.2; r = 0.6/0.4 = 1.5, A = 1 → 1.2 (clipped); loss −(2.2 + 1.2)/2 = −1.7
    # entropy: (H(0.55) + H(0.6))/2 = (0.688139 + 0.673012)/2 = 0.680576   (H(0.25) = 0.562335 left out)
    #   H(0.55) = −0.55·ln 0.55 − 0.45·ln 0.45 = 0.55·0.597837 + 0.45·0.798508
    #   H(0.6)  = −0.6·ln 0.6 − 0.4·ln 0.4   = 0.6·0.510826 + 0.4·0.916291
    # value: V 0, 1, 2 against R 1, 3, 2.5: (1 + 4 + 0.25)/3 = 1.75
    # loss = 1·(−1.7) + 0.25·1.75 − 0.05·0.680576 = −1.7 + 0.4375 − 0.034029 = −1.296529
    # (entropy added instead: −1.228471)
    out = _out([0.55, 0.6, 0.25], values=[[0.0, 1.0, 2.0], [0.0] * 3])
    loss, logged = _loss(monkeypatch, _settings(value_coef=0.25, entropy_coef=0.05), out,
                         _rollout([0.5, 0.4, 0.5], can_act=[True, True, False]), [2.0, 1.0, 5.0], [1.0, 3.0, 2.5])
    _close(logged["policy_loss"], -1.7)
    _close(logged["entropy"], 0.680576)
    _close(logged["value_loss"], 1.75)
    _close(loss, -1.296529)


def test_decoupled_ppo_clips_around_the_proximal_policy_and_weights_by_the_behaviour_ratio(monkeypatch):
    # behaviour π_b = 0.5, 0.2, 0.8; proximal (the weights when the update starts) π_prox = 0.25, 0.4, 0.4
    # weights min(1, π_prox/π_b) = min(1, 0.5) = 0.5, min(1, 2) = 1 (truncated), min(1, 0.5) = 0.5; mean 0.666667
    # proximal KL = mean((x − 1) − ln x), x = π_prox/π_b = 0.5, 2, 0.5:
    #   (−0.5 + 0.693147 + 1 − 0.693147 − 0.5 + 0.693147)/3 = 0.231049
    rollout = _rollout([0.5, 0.2, 0.8])
    monkeypatch.setattr(algorithms, "run_sequence", lambda agent, obs, state, starts: _out([0.25, 0.4, 0.4]))
    stats = {}
    proximal = _proximal(LEARNER, rollout, stats)
    assert stats["proximal_weight"][0] == pytest.approx(0.666667, abs=TOL)
    assert stats["proximal_kl"][0] == pytest.approx(0.231049, abs=TOL)
    for b, expected in enumerate([0.5, 1.0, 0.5]):
        _close(float(proximal["sample_weights"][0, b]), expected)
    # after some steps π = 0.275, 0.6, 0.2; advantages 2, 1, −2; r = π/π_prox = 1.1, 1.5, 0.5:
    #   0.5·2 = 1 → min(1.1·1, 1.1·1) = 1.1;  1·1 = 1 → min(1.5, 1.2) = 1.2;  0.5·−2 = −1 → min(−0.5, −0.8) = −0.8
    #   policy loss = −(1.1 + 1.2 − 0.8)/3 = −0.5
    # (around the behaviour policy, r = 0.55, 3, 0.25: −(0.55 + 1.2 − 0.8)/3 = −0.316667; without the weights −0.6;
    #  untruncated −0.9)
    loss, _ = _loss(monkeypatch, _settings(), _out([0.275, 0.6, 0.2]), proximal, [2.0, 1.0, -2.0], [0.0] * 3)
    _close(loss, -0.5)


def test_fused_decoupled_ppo_takes_advantages_from_the_current_critic(monkeypatch):
    # one epoch: the minibatch's own pass is the proximal one, so r = 1 and each sample's term is weight·A
    # current critic V(s₀), V(s₁) = (0.5, 1.0) and (2.0, 1.0); γ = 0.9; the stored behaviour values are 0
    # robot 1: reward 1, continues: A = 1 + 0.9·1.0 − 0.5 = 1.4; π/π_b = 0.25/0.5 → weight 0.5; term 0.7
    # robot 2: reward 0, terminated: A = 0 + 0 − 2.0 = −2.0;       π/π_b = 0.6/0.3 → weight min(1, 2) = 1; term −2
    # policy loss = −(0.7 − 2.0)/2 = 0.65; mean weight (0.5 + 1)/2 = 0.75
    # returns A + V(s₀) = 1.9, 0.0: value loss ((0.5 − 1.9)² + (2.0 − 0)²)/2 = (1.96 + 4)/2 = 2.98
    # loss = 0.65 + 0.5·2.98 = 2.14   (with the behaviour values: A = 1.0, 0.0 and loss −0.25 + 0.5·2.125)
    rollout = _rollout([0.5, 0.3], rewards=[[1.0, 0.0]], episode_end=[[False, True]], truncated=[[False, False]],
                       final_values=[[0.0, 0.0]])
    out = _out([0.25, 0.6], values=[[0.5, 2.0], [1.0, 1.0]])
    settings = _settings(value_coef=0.5, proximal=True, gamma=0.9, gae_lambda=0.95)
    loss, logged = _loss(monkeypatch, settings, out, rollout)
    _close(logged["policy_loss"], 0.65)
    _close(logged["proximal_weight"], 0.75)
    _close(logged["value_loss"], 2.98)
    _close(loss, 2.14)


# ``ppo_loss`` alone, on tensors written out: one step (T = 1) of four robots, the taken action's log-probability
# under the behaviour policy 0 (π_old = 1), so r = exp(log π) is chosen directly: r = 1.5, 0.5, 1.1, 0.9.
# Advantages 1, 1, −2, 0.5; entropies 1, 2, 3, 10; values 0.5, 1, −1, 2 against returns 1, 1, 0, 0.
# Robot 4 could not act (out of the policy, entropy, KL and clip-fraction means; in the value mean).
RATIOS = [1.5, 0.5, 1.1, 0.9]


def _terms(algorithm="ppo", clip_value_loss=False, alive=(True, True, True, True), old_value=None):
    as_row = lambda values, dtype=torch.float64: torch.tensor([values], dtype=dtype)   # noqa: E731
    settings = UpdateSettings(algorithm=algorithm, clip=0.2, value_coef=0.5, entropy_coef=0.01,
                              clip_value_loss=clip_value_loss)
    return ppo_loss(as_row([math.log(r) for r in RATIOS]), as_row([0.0] * 4), as_row([1.0, 1.0, -2.0, 0.5]),
                    as_row([1.0, 2.0, 3.0, 10.0]), as_row([0.5, 1.0, -1.0, 2.0]), as_row([1.0, 1.0, 0.0, 0.0]),
                    as_row([True, True, True, False], torch.bool), as_row(list(alive), torch.bool), settings,
                    None if old_value is None else as_row(old_value))


def test_ppo_loss_is_the_clipped_objective_the_value_loss_and_the_entropy_bonus():
    # clip(r, 0.8, 1.2) = 1.2, 0.8, 1.1, 0.9; min(r·A, clip(r)·A) = min(1.5, 1.2) = 1.2, min(0.5, 0.8) = 0.5,
    #   min(−2.2, −2.2) = −2.2 (robot 4: 0.45, not acting); policy = −(1.2 + 0.5 − 2.2)/3 = 0.5/3 = 0.166667
    # value = ((0.5 − 1)² + 0² + (−1 − 0)² + (2 − 0)²)/4 = (0.25 + 0 + 1 + 4)/4 = 1.3125
    # entropy = (1 + 2 + 3)/3 = 2
    # total = 0.166667 + 0.5·1.3125 − 0.01·2 = 0.166667 + 0.65625 − 0.02 = 0.802917
    # approx KL = mean((r − 1) − ln r) = ((0.5 − 0.405465) + (−0.5 + 0.693147) + (0.1 − 0.095310))/3
    #           = (0.094535 + 0.193147 + 0.004690)/3 = 0.097457
    # clip fraction: |r − 1| > 0.2 for r = 1.5 and 0.5, not 1.1: 2/3
    terms = _terms()
    _close(terms.policy, 0.166667)
    _close(terms.value, 1.3125)
    _close(terms.entropy, 2.0)
    _close(terms.total, 0.802917)
    _close(terms.approx_kl, 0.097457)
    _close(terms.clip_fraction, 0.666667)


def test_ppo_loss_without_the_clip_is_a2c_and_the_value_term_can_be_clipped_or_masked():
    # A2C: −mean(log π·A) = −(0.405465·1 + (−0.693147)·1 + 0.095310·(−2))/3 = −(−0.478302)/3 = 0.159434
    _close(_terms(algorithm="a2c").policy, 0.159434)
    # clipped value, V_old = 0, 1, 0, 1: V_clipped = V_old + clip(V − V_old, ±0.2) = 0.2, 1, −0.2, 1.2;
    #   (V_clipped − R)² = 0.64, 0, 0.04, 1.44; the larger of it and (V − R)² = 0.64, 0, 1, 4: mean 5.64/4 = 1.41
    _close(_terms(clip_value_loss=True, old_value=[0.0, 1.0, 0.0, 1.0]).value, 1.41)
    # robot 4 not alive: (0.25 + 0 + 1)/3 = 0.416667
    _close(_terms(alive=(True, True, True, False)).value, 0.416667)
    with pytest.raises(ValueError, match="old_value"):
        _terms(clip_value_loss=True)
