"""GAE(λ) and n-step returns against hand-computed cases: episode ends cut the sum, a terminated end bootstraps
with 0, a truncated end with the value of the episode's final observation."""
import pytest
import torch

from dynenv_ros.learning.algo.advantages import generalized_advantages


def _col(values):
    return torch.tensor(values, dtype=torch.float64).reshape(-1, 1)


def test_gae_no_episode_end_matches_hand_computation():
    gamma, lam = 0.9, 0.8
    rewards = _col([1.0, 2.0, 3.0])
    values = _col([0.5, 0.4, 0.3, 0.2])
    none = torch.zeros(3, 1, dtype=torch.bool)
    adv, ret = generalized_advantages(rewards, values, none, none, torch.zeros(3, 1, dtype=torch.float64),
                                      gamma, lam)
    d2 = 3.0 + 0.9 * 0.2 - 0.3            # 2.88
    d1 = 2.0 + 0.9 * 0.3 - 0.4            # 1.87
    d0 = 1.0 + 0.9 * 0.4 - 0.5            # 0.86
    a2 = d2
    a1 = d1 + 0.9 * 0.8 * a2
    a0 = d0 + 0.9 * 0.8 * a1
    assert adv[:, 0].tolist() == pytest.approx([a0, a1, a2], abs=1e-12)
    assert ret[:, 0].tolist() == pytest.approx([a0 + 0.5, a1 + 0.4, a2 + 0.3], abs=1e-12)


def test_lambda_one_gives_n_step_returns():
    gamma = 0.99
    rewards = _col([1.0, 0.0, -1.0, 2.0])
    values = _col([0.1, 0.2, 0.3, 0.4, 10.0])
    none = torch.zeros(4, 1, dtype=torch.bool)
    _, ret = generalized_advantages(rewards, values, none, none, torch.zeros(4, 1, dtype=torch.float64), gamma, 1.0)
    expected0 = 1.0 + 0.99 * 0.0 + 0.99 ** 2 * -1.0 + 0.99 ** 3 * 2.0 + 0.99 ** 4 * 10.0
    expected3 = 2.0 + 0.99 * 10.0
    assert ret[0, 0].item() == pytest.approx(expected0, abs=1e-12)
    assert ret[3, 0].item() == pytest.approx(expected3, abs=1e-12)


def test_terminated_end_cuts_and_bootstraps_with_zero():
    gamma, lam = 0.5, 1.0
    rewards = _col([1.0, 1.0, 1.0])
    values = _col([0.0, 0.0, 100.0, 8.0])      # values[2] belongs to the next episode's first observation
    end = torch.tensor([[False], [True], [False]])
    adv, ret = generalized_advantages(rewards, values, end, torch.zeros_like(end),
                                      torch.zeros(3, 1, dtype=torch.float64), gamma, lam)
    # step 1 ends the episode: its return is its reward only; step 0 sees one more step of it.
    assert ret[1, 0].item() == pytest.approx(1.0)
    assert ret[0, 0].item() == pytest.approx(1.0 + 0.5 * 1.0)
    # step 2 starts a new episode and bootstraps from values[3]
    assert ret[2, 0].item() == pytest.approx(1.0 + 0.5 * 8.0)


def test_truncated_end_bootstraps_from_the_final_observation():
    gamma, lam = 0.5, 1.0
    rewards = _col([1.0, 1.0])
    values = _col([0.0, 0.0, 100.0])
    end = torch.tensor([[False], [True]])
    final = _col([0.0, 6.0])
    _, ret = generalized_advantages(rewards, values, end, end, final, gamma, lam)
    assert ret[1, 0].item() == pytest.approx(1.0 + 0.5 * 6.0)       # not 100 (next episode), not 0
    assert ret[0, 0].item() == pytest.approx(1.0 + 0.5 * (1.0 + 0.5 * 6.0))


def test_values_must_have_one_more_step():
    with pytest.raises(ValueError, match="T\\+1"):
        z = torch.zeros(3, 1)
        generalized_advantages(z, z, z.bool(), z.bool(), z, 0.9, 0.9)
