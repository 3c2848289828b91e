"""The agent's losses (dynenv_ros/agent/losses.py): LTP against a hand-computed example, gradients reaching every
parameter, masking, the slot assignment against brute force, reconstruction and its ignore rule, empty inputs."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from dynenv_ros.agent.losses import (ANCHORS, ROBOCUP_HEADS, ForwardModel, InverseModel, LongTermPredictor,
                                      RCMAttention, assign_slots, assignment_cost, brute_force_assignment,
                                      icm_losses, localization_loss, ltp_loss, one_hot_actions, pose_features,
                                      reconstruction_loss)

D = 8
A = sum(ROBOCUP_HEADS)


def random_actions(gen: torch.Generator, steps: int, agents: int) -> tuple[torch.Tensor, torch.Tensor]:
    index = torch.stack([torch.randint(0, n, (steps, agents), generator=gen) for n in ROBOCUP_HEADS], dim=-1)
    return one_hot_actions(index), index


def set_linear(layer: torch.nn.Linear, weight: list[list[float]]) -> None:
    with torch.no_grad():
        layer.weight.copy_(torch.tensor(weight))
        layer.bias.zero_()


def nonzero_grads(*modules: torch.nn.Module) -> dict[str, bool]:
    return {f"{i}.{name}": p.grad is not None and bool(p.grad.abs().sum() > 0)
            for i, module in enumerate(modules) for name, p in module.named_parameters()}


# --- Long-Term Prediction ---------------------------------------------------------------------------------------

def hand_ltp() -> tuple[LongTermPredictor, RCMAttention, torch.Tensor, torch.Tensor]:
    """D = 2, A = 2, horizon 2. Hidden layer = [φ + M_k a] (LeakyReLU is the identity on these positive values),
    output layer = identity, so f_1(φ, a) = φ + [[.5, 0], [0, 0]] a and f_2(φ, a) = φ + [[0, 1], [0, 0]] a."""
    predictor = LongTermPredictor(2, 2, horizon=2, hidden=2)
    set_linear(predictor.nets[0].net[0], [[1, 0, 0.5, 0], [0, 1, 0, 0]])
    set_linear(predictor.nets[1].net[0], [[1, 0, 0, 1], [0, 1, 0, 0]])
    for net in predictor.nets:
        set_linear(net.net[2], [[1, 0], [0, 1]])
    attention = RCMAttention(2)
    set_linear(attention.linear, [[4, 0], [0, 0]])
    phi = torch.tensor([[[1.0, 2.0]], [[2.0, 2.0]], [[3.0, 1.0]]])     # (T+1 = 3, N = 1, D = 2)
    actions = torch.tensor([[[1.0, 0.0]], [[0.0, 1.0]]])                # (T = 2, N = 1, A = 2)
    return predictor, attention, phi, actions


def test_ltp_matches_hand_computed_example():
    predictor, attention, phi, actions = hand_ltp()
    # φ̂_1 = [1, 2] + [.5, 0] = [1.5, 2];        e_1 = ([2, 2] − φ̂_1)² = [.25, 0];  J_1 = mean(1 ⊙ e_1) = .125
    # φ̂_2 = [1.5, 2] + [1, 0] = [2.5, 2];      e_2 = ([3, 1] − φ̂_2)² = [.25, 1]
    # w_2 = softmax([[4, 0], [0, 0]] e_1) = softmax([1, 0]) = [e, 1] / (e + 1);  J_2 = mean(w_2 ⊙ e_2)
    w2 = (math.e / (math.e + 1), 1 / (math.e + 1))
    j1, j2 = 0.125, (w2[0] * 0.25 + w2[1] * 1.0) / 2
    result = ltp_loss(phi, actions, predictor, attention, torch.ones(2, 1, dtype=torch.bool))
    assert result.loss.item() == pytest.approx((j1 + j2) / 2, rel=1e-6)          # the paper's 1/N, N = 2
    assert result.weighted.tolist() == pytest.approx([j1, j2], rel=1e-6)
    assert result.mse.tolist() == pytest.approx([0.125, 0.625], rel=1e-6)
    assert result.loss.requires_grad

    attention_unit = RCMAttention(2, unit_mean=True)
    attention_unit.load_state_dict(attention.state_dict())
    scaled = ltp_loss(phi, actions, predictor, attention_unit, None)
    assert scaled.loss.item() == pytest.approx((j1 + 2 * j2) / 2, rel=1e-6)       # weights × D


def test_ltp_horizon_longer_than_rollout_uses_the_rollout():
    predictor, attention, phi, actions = hand_ltp()
    longer = LongTermPredictor(2, 2, horizon=4, hidden=2)
    for k in range(2):
        longer.nets[k].load_state_dict(predictor.nets[k].state_dict())
    assert ltp_loss(phi, actions, longer, attention, None).loss.item() == pytest.approx(
        ltp_loss(phi, actions, predictor, attention, None).loss.item())
    shorter = ltp_loss(phi[:2], actions[:1], predictor, attention, None)
    assert shorter.loss.item() == pytest.approx(0.125) and shorter.weighted.shape == (1,)


# --- gradients --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("use_rcm", [False, True])
def test_icm_gradients_reach_every_parameter_and_the_features(use_rcm):
    gen = torch.Generator().manual_seed(1)
    steps, agents = 4, 3
    phi = torch.randn(steps + 1, agents, D, generator=gen, requires_grad=True)
    onehot, index = random_actions(gen, steps, agents)
    forward, inverse = ForwardModel(D, A, hidden=16), InverseModel(D)
    attention = RCMAttention(D) if use_rcm else None
    losses = icm_losses(phi, onehot, index, forward, inverse, torch.ones(steps, agents, dtype=torch.bool), attention)
    (losses["forward"] + losses["inverse"]).backward()
    grads = nonzero_grads(forward, inverse, *([attention] if attention else []))
    assert all(grads.values()), grads
    assert (phi.grad.abs().sum(dim=(1, 2)) > 0).all()          # every step: forward input and/or inverse input


def test_icm_detaches_only_the_forward_target_by_default():
    gen = torch.Generator().manual_seed(2)
    phi = torch.randn(3, 2, D, generator=gen, requires_grad=True)
    onehot, index = random_actions(gen, 2, 2)
    forward, inverse = ForwardModel(D, A), InverseModel(D)
    icm_losses(phi, onehot, index, forward, inverse, None)["forward"].backward()
    assert phi.grad[-1].abs().sum() == 0 and phi.grad[:-1].abs().sum() > 0
    phi.grad = None
    icm_losses(phi, onehot, index, forward, inverse, None, detach_target=False)["forward"].backward()
    assert phi.grad[-1].abs().sum() > 0


@pytest.mark.parametrize("detach_target", [True, False])
def test_ltp_gradients_reach_every_parameter_and_the_features(detach_target):
    gen = torch.Generator().manual_seed(3)
    steps, agents, horizon = 5, 3, 3
    phi = torch.randn(steps + 1, agents, D, generator=gen, requires_grad=True)
    onehot, _ = random_actions(gen, steps, agents)
    predictor, attention = LongTermPredictor(D, A, horizon, hidden=16), RCMAttention(D)
    result = ltp_loss(phi, onehot, predictor, attention, torch.ones(steps, agents, dtype=torch.bool),
                      detach_target=detach_target)
    assert result.loss.dim() == 0 and result.weighted.shape == result.mse.shape == (horizon,)
    result.loss.backward()
    grads = nonzero_grads(predictor, attention)
    assert all(grads.values()), grads
    assert phi.grad[0].abs().sum() > 0
    reached = phi.grad[1:horizon + 1].abs().sum() > 0
    assert reached != detach_target
    assert phi.grad[horizon + 1:].abs().sum() == 0                 # beyond the horizon: not used


def test_ltp_weight_input_detach_option():
    gen = torch.Generator().manual_seed(4)
    phi = torch.randn(3, 2, D, generator=gen)
    onehot, _ = random_actions(gen, 2, 2)
    predictor, attention = LongTermPredictor(D, A, 2), RCMAttention(D)
    full = ltp_loss(phi, onehot, predictor, attention, None)
    stopped = ltp_loss(phi, onehot, predictor, attention, None, detach_weight_input=True)
    assert full.loss.item() == pytest.approx(stopped.loss.item())
    # only J_2 depends on f_1 through w_2; with the stop, f_1's gradient comes from J_1 and the chain φ̂_1 → φ̂_2
    g_full = torch.autograd.grad(full.loss, predictor.nets[0].net[0].weight)[0]
    g_stop = torch.autograd.grad(stopped.loss, predictor.nets[0].net[0].weight)[0]
    assert not torch.allclose(g_full, g_stop)


def test_localization_and_reconstruction_gradients():
    gen = torch.Generator().manual_seed(5)
    pose = torch.randn(4, 6, generator=gen, requires_grad=True)
    localization_loss(pose, torch.randn(4, 6, generator=gen)).backward()
    assert (pose.grad.abs().sum(-1) > 0).all()
    slots = torch.randn(3, 4, 5, generator=gen, requires_grad=True)
    conf = torch.randn(3, 4, generator=gen, requires_grad=True)
    targets = torch.randn(3, 3, 5, generator=gen) * 2
    losses = reconstruction_loss(slots, conf, targets, torch.ones(3, 3, dtype=torch.bool), ignore_radius=0.0)
    sum(losses.values()).backward()
    assert slots.grad.abs().sum() > 0 and (conf.grad.abs() > 0).all()


# --- masking ----------------------------------------------------------------------------------------------------

def test_masked_agents_contribute_nothing():
    gen = torch.Generator().manual_seed(6)
    steps, agents = 4, 3
    phi = torch.randn(steps + 1, agents, D, generator=gen)
    onehot, index = random_actions(gen, steps, agents)
    mask = torch.ones(steps, agents, dtype=torch.bool)
    mask[:, 1] = False          # agent 1 never trainable
    mask[1, 2] = False          # agent 2 untrainable at step 1: its LTP chain is cut from horizon 2 on
    forward, inverse, attention = ForwardModel(D, A), InverseModel(D), RCMAttention(D)
    predictor = LongTermPredictor(D, A, 3)

    def losses(phi_in: torch.Tensor, onehot_in: torch.Tensor, index_in: torch.Tensor) -> list[torch.Tensor]:
        icm = icm_losses(phi_in, onehot_in, index_in, forward, inverse, mask, attention)
        return [icm["forward"], icm["inverse"], ltp_loss(phi_in, onehot_in, predictor, attention, mask).loss]

    base = losses(phi, onehot, index)
    phi2, onehot2, index2 = phi.clone(), onehot.clone(), index.clone()
    phi2[:, 1] = 100 * torch.randn(steps + 1, D, generator=gen)
    new_onehot, new_index = random_actions(gen, steps, 1)
    onehot2[:, 1], index2[:, 1] = new_onehot[:, 0], -1        # padding indices for the untrainable agent
    changed = losses(phi2, onehot2, index2)
    for a, b in zip(base, changed):
        assert a.item() == pytest.approx(b.item(), rel=1e-6)

    # the same numbers as with agent 1 removed
    keep = [0, 2]
    icm_kept = icm_losses(phi[:, keep], onehot[:, keep], index[:, keep], forward, inverse, mask[:, keep], attention)
    assert icm_kept["forward"].item() == pytest.approx(base[0].item(), rel=1e-6)
    assert icm_kept["inverse"].item() == pytest.approx(base[1].item(), rel=1e-6)

    # LTP: agent 2 counts at horizon 1 only; changing its later features changes nothing
    phi3 = phi.clone()
    phi3[2:, 2] += 5.0
    assert ltp_loss(phi3, onehot, predictor, attention, mask).loss.item() == pytest.approx(base[2].item(), rel=1e-6)
    phi3[1, 2] += 5.0
    assert ltp_loss(phi3, onehot, predictor, attention, mask).loss.item() != pytest.approx(base[2].item(), rel=1e-6)

    # and the masked agent's features get exactly zero gradient
    leaf = phi2.clone().requires_grad_(True)
    sum(losses(leaf, onehot2, index2)).backward()
    assert leaf.grad[:, 1].abs().sum() == 0 and leaf.grad[:, 0].abs().sum() > 0

    pose, truth = torch.randn(3, 6, generator=gen), torch.randn(3, 6, generator=gen)
    agent_mask = torch.tensor([True, False, True])
    before = localization_loss(pose, truth, agent_mask)
    pose[1] += 50
    assert localization_loss(pose, truth, agent_mask).item() == pytest.approx(before.item())

    slots, conf = torch.randn(3, 4, 5, generator=gen), torch.randn(3, 4, generator=gen)
    targets, seen = torch.randn(3, 3, 5, generator=gen), torch.rand(3, 3, generator=gen) < 0.7
    before_r = reconstruction_loss(slots, conf, targets, seen, mask=agent_mask)
    slots[1] += 7
    conf[1] -= 3
    after_r = reconstruction_loss(slots, conf, targets, seen, mask=agent_mask)
    for key in before_r:
        assert after_r[key].item() == pytest.approx(before_r[key].item()), key


# --- slot assignment --------------------------------------------------------------------------------------------

def test_assignment_equals_brute_force():
    gen = torch.Generator().manual_seed(7)
    for case in range(200):
        slots = int(torch.randint(1, 6, (1,), generator=gen))
        count = int(torch.randint(0, slots + 1, (1,), generator=gen))
        anchors = (torch.rand(slots, 2, generator=gen) - 0.5) * torch.tensor([9.0, 6.0])
        targets = (torch.rand(count, 4, generator=gen) - 0.5) * torch.tensor([9.0, 6.0, 1.0, 1.0])
        seen = (torch.rand(count, generator=gen) < 0.6) if case % 2 else torch.ones(count, dtype=torch.bool)
        perm, reference = assign_slots(anchors, targets, seen), brute_force_assignment(anchors, targets, seen)
        assert perm.shape == (count,) and len(set(perm.tolist())) == count
        assert all(0 <= s < slots for s in perm.tolist())
        assert assignment_cost(anchors, targets, seen, perm) == pytest.approx(
            assignment_cost(anchors, targets, seen, reference), abs=1e-9)
        assert perm[seen].tolist() == reference[seen].tolist()       # unique for the seen ones (continuous data)


def test_assignment_to_default_anchors_and_errors():
    targets = torch.tensor([[2.0, 1.4], [-2.0, -1.0], [0.0, 0.0]])
    perm = assign_slots(torch.tensor(ANCHORS), targets, torch.tensor([True, True, False]))
    assert perm[:2].tolist() == [3, 0]
    with pytest.raises(ValueError):
        assign_slots(torch.tensor(ANCHORS[:2]), targets, torch.ones(3, dtype=torch.bool))


# --- reconstruction ---------------------------------------------------------------------------------------------

def perfect_predictions(targets: torch.Tensor, seen: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    agents, count, fields = targets.shape
    slots = torch.full((agents, len(ANCHORS), fields), 100.0)          # unassigned slots far from everything
    conf = torch.full((agents, len(ANCHORS)), -40.0)
    for b in range(agents):
        perm = assign_slots(torch.tensor(ANCHORS), targets[b], seen[b])
        for m in range(count):
            if seen[b, m]:
                slots[b, perm[m]] = targets[b, m]
                conf[b, perm[m]] = 40.0
    return slots, conf


def test_reconstruction_is_zero_for_perfect_confident_predictions():
    gen = torch.Generator().manual_seed(8)
    targets = (torch.rand(5, 3, 5, generator=gen) - 0.5) * torch.tensor([9.0, 6.0, 2.0, 2.0, 1.0])
    seen = torch.rand(5, 3, generator=gen) < 0.7
    seen[0] = True
    seen[1] = False
    slots, conf = perfect_predictions(targets, seen)
    losses = reconstruction_loss(slots, conf, targets, seen)
    for key, value in losses.items():
        assert value.item() == pytest.approx(0.0, abs=1e-8), key
    # one regression field off by .5 at every matched slot: fields MSE = .25 over the 3 extra fields
    shifted = targets.clone()
    shifted[..., 3] += 0.5
    assert reconstruction_loss(slots, conf, shifted, seen)["fields"].item() == pytest.approx(0.25 / 3)
    # a binary field scored by BCE instead: target 1 with logit = target value 1 → softplus(−1)
    binary = targets.clone()
    binary[..., 4] = 1.0
    slots_b, conf_b = perfect_predictions(binary, seen)
    got = reconstruction_loss(slots_b, conf_b, binary, seen, binary_fields=[4])["fields"].item()
    assert got == pytest.approx(math.log1p(math.exp(-1.0)))


def test_confidence_targets_ignored_near_unseen_objects_only():
    target = torch.tensor([[[2.0, 1.4]]])                # seen, assigned to anchor (2.25, 1.5): slot 3
    seen = torch.tensor([[True]])
    slots = torch.full((1, 4, 2), 100.0)
    slots[0, 3] = target[0, 0]
    conf = torch.tensor([[5.0, -40.0, -40.0, 40.0]])    # slot 0: a confident extra detection
    expected = math.log1p(math.exp(5.0)) / 4                          # BCE(5, target 0) over 4 scored slots
    # a second slot on an object already answered for is a duplicate: pushed down, however close it is
    slots[0, 0] = target[0, 0] + torch.tensor([0.1, 0.0])
    assert reconstruction_loss(slots, conf, target, seen)["confidence"].item() == pytest.approx(expected, rel=1e-5)
    slots[0, 0] = target[0, 0] + torch.tensor([0.5, 0.0])
    assert reconstruction_loss(slots, conf, target, seen, ignore_radius=0.6)["confidence"].item() == pytest.approx(
        expected, rel=1e-5)

    # an unseen but present object also protects a slot predicted next to it; padding rows do not
    targets = torch.tensor([[[2.0, 1.4], [-3.0, 2.0]]])
    seen2 = torch.tensor([[True, False]])
    slots[0, 0] = torch.tensor([-3.1, 2.0])
    assert reconstruction_loss(slots, conf, targets, seen2)["confidence"].item() == pytest.approx(0.0, abs=1e-8)
    padded = reconstruction_loss(slots, conf, targets, seen2, present=torch.tensor([[True, False]]))
    assert padded["confidence"].item() == pytest.approx(expected, rel=1e-5)


# --- empty inputs -----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("agents", [0, 3])
def test_zero_agents_or_all_masked_give_zero_without_nan(agents):
    gen = torch.Generator().manual_seed(9)
    steps = 3
    phi = torch.randn(steps + 1, agents, D, generator=gen, requires_grad=True)
    onehot, index = random_actions(gen, steps, agents)
    mask = torch.zeros(steps, agents, dtype=torch.bool)
    forward, inverse, attention = ForwardModel(D, A), InverseModel(D), RCMAttention(D)
    predictor = LongTermPredictor(D, A, 2)
    icm = icm_losses(phi, onehot, index, forward, inverse, mask, attention)
    ltp = ltp_loss(phi, onehot, predictor, attention, mask)
    pose = torch.randn(agents, 6, generator=gen, requires_grad=True)
    loc = localization_loss(pose, torch.randn(agents, 6, generator=gen), torch.zeros(agents, dtype=torch.bool))
    slots = torch.randn(agents, 4, 5, generator=gen, requires_grad=True)
    conf = torch.randn(agents, 4, generator=gen, requires_grad=True)
    recon = reconstruction_loss(slots, conf, torch.randn(agents, 3, 5, generator=gen),
                                torch.ones(agents, 3, dtype=torch.bool), mask=torch.zeros(agents, dtype=torch.bool))
    values = [icm["forward"], icm["inverse"], ltp.loss, loc, *recon.values()]
    assert all(v.item() == 0.0 for v in values)
    assert torch.isfinite(ltp.weighted).all() and torch.isfinite(ltp.mse).all()
    sum(values).backward()
    for tensor in (phi, pose, slots, conf):
        assert tensor.grad is not None and torch.isfinite(tensor.grad).all() and tensor.grad.abs().sum() == 0
    for p in [*forward.parameters(), *inverse.parameters(), *attention.parameters(), *predictor.parameters()]:
        assert p.grad is None or (torch.isfinite(p.grad).all() and p.grad.abs().sum() == 0)


def test_no_targets_and_empty_rollout():
    slots, conf = torch.zeros(2, 4, 3), torch.zeros(2, 4)
    losses = reconstruction_loss(slots, conf, torch.zeros(2, 0, 3), torch.zeros(2, 0, dtype=torch.bool))
    assert losses["position"].item() == 0.0 and losses["confidence"].item() == pytest.approx(math.log(2.0))
    predictor, attention = LongTermPredictor(D, A, 2), RCMAttention(D)
    empty = ltp_loss(torch.zeros(1, 2, D), torch.zeros(0, 2, A), predictor, attention,
                     torch.zeros(0, 2, dtype=torch.bool))
    assert empty.loss.item() == 0.0 and empty.weighted.shape == (0,)


def test_helpers():
    index = torch.tensor([[4, 0, 2, 6], [-1, 1, 0, 3]])
    onehot = one_hot_actions(index)
    assert onehot.shape == (2, A) and onehot.sum(-1).tolist() == [4, 3]
    assert onehot[0, 4] == 1 and onehot[0, 5] == 1 and onehot[0, 10] == 1 and onehot[0, 17] == 1
    features = pose_features(torch.tensor(1.0), torch.tensor(-2.0), torch.tensor(math.pi / 2),
                             torch.tensor(-math.pi / 2))
    assert features.tolist() == pytest.approx([1.0, -2.0, 1.0, 0.0, 0.0, -1.0], abs=1e-7)
    assert localization_loss(features, features).item() == 0.0


def test_the_long_term_prediction_loss_is_actually_optimised():
    """DynEnv computed LTP but never optimised it (docs/original.md §12.12): an optimiser on it learns the dynamics."""
    from dynenv_ros.agent.losses import LongTermPredictor, RCMAttention, ltp_loss
    g = torch.Generator().manual_seed(0)
    T, N, D, A = 6, 8, 8, 4
    actions = torch.nn.functional.one_hot(torch.randint(0, A, (T, N), generator=g), A).float()
    drift = torch.randn(A, D, generator=g) * 0.3
    phi = [torch.randn(N, D, generator=g)]
    for t in range(T):                                   # a simple action-driven dynamics to predict
        phi.append(0.9 * phi[-1] + actions[t] @ drift)
    phi = torch.stack(phi)
    predictor, attention = LongTermPredictor(D, A, horizon=T), RCMAttention(D)
    optimiser = torch.optim.Adam(list(predictor.parameters()) + list(attention.parameters()), lr=1e-2)
    mask = torch.ones(T, N, dtype=torch.bool)
    first = ltp_loss(phi, actions, predictor, attention, mask).loss.item()
    for _ in range(300):
        optimiser.zero_grad()
        loss = ltp_loss(phi, actions, predictor, attention, mask).loss
        loss.backward()
        optimiser.step()
    assert loss.item() < 0.1 * first


def test_batched_assignment_is_optimal_like_brute_force():
    from dynenv_ros.agent.losses import ANCHORS, assign_slots_batch, assignment_cost, brute_force_assignment
    rng = np.random.default_rng(4)
    anchors = np.array(ANCHORS)
    targets = rng.uniform(-4.5, 4.5, size=(200, 3, 2))
    seen = rng.random((200, 3)) < 0.7
    got = assign_slots_batch(anchors, targets, seen)
    for b in range(200):
        best = brute_force_assignment(anchors, targets[b], seen[b])
        assert len(set(got[b].tolist())) == 3                       # distinct slots
        assert assignment_cost(anchors, targets[b], seen[b], got[b]) == pytest.approx(
            assignment_cost(anchors, targets[b], seen[b], best), abs=1e-12)
