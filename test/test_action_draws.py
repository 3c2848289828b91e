"""The one action-drawing primitive (core/action_draws.py, issue 40): a categorical head is drawn as
``torch.multinomial`` draws it, or its most probable choice when greedy (no draw); a Gaussian as mean + std · a
standard normal of the generator, clipped, its noise drawn even when greedy; the heads in the order given."""
from __future__ import annotations

import torch

from dynenv_ros.core.action_draws import Gaussian, draw_actions

PROBS = torch.tensor([[0.1, 0.6, 0.3], [0.5, 0.2, 0.3], [0.25, 0.25, 0.5], [0.0, 0.0, 1.0]])


def test_greedy_takes_the_most_probable_choice_and_draws_nothing():
    generator = torch.Generator().manual_seed(4)
    before = generator.get_state()
    ties = torch.tensor([[0.4, 0.4, 0.2], [0.2, 0.4, 0.4]])       # equals: the first of them
    walk, turn = draw_actions([PROBS, ties], generator, greedy=True)
    assert walk.tolist() == [1, 0, 2, 2] and turn.tolist() == [0, 1]
    assert walk.dtype == torch.int64
    assert torch.equal(generator.get_state(), before)


def test_a_sampled_categorical_is_torch_multinomial_with_the_same_seed():
    (drawn,) = draw_actions([PROBS], torch.Generator().manual_seed(9), greedy=False)
    expected = torch.multinomial(PROBS, 1, generator=torch.Generator().manual_seed(9)).squeeze(-1)
    assert torch.equal(drawn, expected)
    assert drawn[3] == 2                                            # probability 1: always drawn


def test_a_gaussian_is_its_mean_plus_std_times_the_generators_normal_clipped():
    mean = torch.tensor([0.0, 0.5, -0.9, 2.0])
    std = torch.tensor([1.0, 0.1, 0.5, 0.2])
    head = Gaussian(mean, std, -1.0, 1.0)
    (drawn,) = draw_actions([head], torch.Generator().manual_seed(2), greedy=False)
    noise = torch.randn(4, generator=torch.Generator().manual_seed(2))
    assert torch.equal(drawn, (mean + std * noise).clamp(-1.0, 1.0))
    assert drawn[3] == 1.0                                          # mean 2 ± 0.2·noise is clipped to the bound
    assert drawn.dtype == torch.float32


def test_a_greedy_gaussian_is_its_clipped_mean_and_still_draws_its_noise():
    head = Gaussian(torch.tensor([0.3, -2.0]), torch.tensor([1.0, 1.0]), -1.0, 1.0)
    generator = torch.Generator().manual_seed(6)
    (drawn,) = draw_actions([head], generator, greedy=True)
    assert drawn.tolist() == [torch.tensor(0.3).item(), -1.0]
    reference = torch.Generator().manual_seed(6)
    torch.randn(2, generator=reference)                             # the two normals the noise took
    assert torch.equal(generator.get_state(), reference.get_state())


def test_per_dimension_bounds_and_a_float64_noise():
    mean = torch.tensor([[0.9, 0.1, -0.2], [-3.0, 4.0, 0.0]], dtype=torch.float64)
    std = torch.full((2, 3), 0.5, dtype=torch.float64)
    low = torch.tensor([-1.0, 0.0, -1.0], dtype=torch.float64)
    high = torch.tensor([1.0, 1.0, 1.0], dtype=torch.float64)
    (drawn,) = draw_actions([Gaussian(mean, std, low, high, noise_dtype=torch.float64)],
                            torch.Generator().manual_seed(8), greedy=False)
    noise = torch.randn((2, 3), generator=torch.Generator().manual_seed(8), dtype=torch.float64)
    assert torch.equal(drawn, torch.maximum(torch.minimum(mean + std * noise, high), low))
    assert drawn[1, 0] == -1.0 and drawn[1, 1] == 1.0                # each dimension clipped to its own bounds
    assert drawn.dtype == torch.float64


def test_the_heads_draw_in_the_order_given():
    head = Gaussian(torch.zeros(4), torch.ones(4), -10.0, 10.0)
    walk, turn, normal = draw_actions([PROBS, PROBS.flip(-1), head], torch.Generator().manual_seed(1), greedy=False)
    reference = torch.Generator().manual_seed(1)
    assert torch.equal(walk, torch.multinomial(PROBS, 1, generator=reference).squeeze(-1))
    assert torch.equal(turn, torch.multinomial(PROBS.flip(-1), 1, generator=reference).squeeze(-1))
    assert torch.equal(normal, torch.randn(4, generator=reference))
