"""The driving agent (issue 14): the padded driving layout read through its spec (class tables, side inputs), the
network's driving heads (discrete MultiDiscrete [3, 3], continuous clipped Gaussian) without temporal attention,
their log-probabilities, and soccer's tables left as they were."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from dynenv_ros.driving import agent_actions as driving_actions
from dynenv_ros.driving.agent_actions import ClippedNormal
from dynenv_ros.agent.inputs import (CLASS_INDEX, NUM_CLASSES, StreamBatch, agent_inputs, side_inputs,
                                     streams_from_padded)
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.core.object_classes import ObjectClass as C
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.envs.driving_observations import driving_layout_spec
from dynenv_ros.envs.driving_v0 import parallel_env


def driving_batch(seed: int = 0, n_cars: int = 2, steps: int = 3):
    """Padded observations of every car after a few random periods, stacked (cars leading), and the spec."""
    env = parallel_env(n_cars=n_cars, observation="padded", perception="realistic")
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        obs, *_ = env.step({a: rng.integers(0, 3, 2) for a in env.agents})
    cars = sorted(obs)
    spec = driving_layout_spec(env.config)
    return {k: np.stack([obs[a][k] for a in cars]) for k in obs[cars[0]]}, spec


def test_soccer_keeps_its_class_table_and_driving_has_its_own():
    assert CLASS_INDEX == {int(C.BALL): 1, int(C.ROBOT): 2, int(C.GOALPOST): 3, int(C.PENALTY_CROSS): 4,
                           int(C.LINE_CROSSING): 5, int(C.FIELD_LINE): 6, int(C.CENTER_CIRCLE): 7}
    assert NUM_CLASSES == 8 and agent_inputs("soccer").num_classes == 8
    driving = agent_inputs("driving")
    assert driving.class_index == {int(C.CAR): 1, int(C.PEDESTRIAN): 2, int(C.OBSTACLE): 3, int(C.UNKNOWN): 4,
                                   int(C.SELF): 5, int(C.LANE): 6}
    assert driving.num_classes == 7 and driving.action_encoding == 3 and driving.self_state == 9
    with pytest.raises(ValueError, match="scenario"):
        agent_inputs("chess")


def test_the_driving_layout_is_read_through_its_spec():
    batch, spec = driving_batch()
    lanes, objects = streams_from_padded(batch, spec)
    assert lanes.features.shape == batch["lanes"].shape and objects.mask.shape == batch["object_mask"].shape
    table = agent_inputs("driving").class_index
    assert (lanes.kind[:, :, 0] == table[int(C.SELF)]).all()            # the SELF row leads the static stream
    real = ~objects.mask
    expected = torch.tensor([table[int(c)] for c in batch["objects"][..., 0][real.numpy()].astype(int)])
    assert torch.equal(objects.kind[real], expected) and (objects.kind[objects.mask] == 0).all()
    previous, state = side_inputs(batch, spec=spec)
    w = DrivingConfig().cars.max_yaw_rate
    np.testing.assert_allclose(previous.numpy(), batch["previous_action"] / [1.0, 1.0, w], rtol=1e-6)
    assert previous.abs().max() <= 1.0 + 1e-6
    ego, seconds = batch["proprioception"][:, -1], batch["game"]
    np.testing.assert_allclose(state[:, :8].numpy(), ego * driving_actions_scale(), rtol=1e-6)
    np.testing.assert_allclose(state[:, 8].numpy(), seconds[:, 0] / 60.0, rtol=1e-6)


def driving_actions_scale():
    from dynenv_ros.agent.inputs import DRIVING_EGO_SCALE
    return DRIVING_EGO_SCALE.numpy()


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_the_driving_network_has_driving_heads_and_no_temporal_attention(action_mode):
    batch, spec = driving_batch()
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=32, scenario="driving", action_mode=action_mode)
    names = [n for n, _ in model.named_parameters()]
    assert not any("temporal_attention" in n or ".rta.norm" in n for n in names)
    assert not any(n.startswith(("pose_head", "reconstruction", "walk_head", "head_head")) for n in names)
    assert len(model.localization.embed.blocks) == 7
    lanes, objects = streams_from_padded(batch, spec)
    previous, state = side_inputs(batch, spec=spec)
    step = model(lanes, objects, previous, state, model.initial_state(2))
    assert step.walk is None and step.pose is None and step.ball is None and step.value.shape == (2,)
    if action_mode == "discrete":
        assert step.acceleration.shape == (2, 3) and step.steering.shape == (2, 3) and step.command is None
    else:
        assert step.command.shape == (2, 6) and step.acceleration is None
        mean = step.command[:, :3]
        assert (mean >= torch.tensor([-1.0, 0.0, -1.0])).all() and (mean <= 1.0).all()
    actions = model.act(step, torch.Generator().manual_seed(0))
    assert actions.shape == (2, 2 if action_mode == "discrete" else 3)
    dists = model.distributions(step)
    log_prob = sum(d.log_prob(a) for d, a in zip(dists, actions.unbind(-1)))
    assert log_prob.shape == (2,) and torch.isfinite(log_prob).all()
    log_prob.sum().backward()                         # gradients reach the heads
    head = model.acceleration_head if action_mode == "discrete" else model.command_head
    assert head.weight.grad is not None and head.weight.grad.abs().sum() > 0


def test_a_driving_network_refuses_more_than_one_frame_per_period():
    model = DynEnvAgent(feature_size=16, scenario="driving")
    two = StreamBatch(torch.zeros(1, 2, 3, 19), torch.ones(1, 2, 3, dtype=torch.int64),
                      torch.zeros(1, 2, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="no temporal attention"):
        model(two, two, torch.zeros(1, 3), torch.zeros(1, 9), model.initial_state(1))


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_a_driving_sequence_is_its_periods_one_by_one(action_mode):
    torch.manual_seed(1)
    model = DynEnvAgent(feature_size=16, scenario="driving", action_mode=action_mode)
    T, B, N = 3, 2, 5
    g = torch.Generator().manual_seed(2)

    def stream():
        return StreamBatch(torch.randn(T, B, 1, N, 19, generator=g), torch.randint(1, 7, (T, B, 1, N), generator=g),
                           torch.rand(T, B, 1, N, generator=g) < 0.4)

    static, dynamic = stream(), stream()
    previous, state = torch.randn(T, B, 3, generator=g), torch.randn(T, B, 9, generator=g)
    resets = torch.tensor([[False, False], [True, False], [False, False]])
    with torch.no_grad():
        sequence = model.forward_sequence(static, dynamic, previous, state, model.initial_state(B), resets)
        carried = model.initial_state(B)
        for t in range(T):
            if resets[t].any():
                carried = tuple(s.masked_fill(resets[t].unsqueeze(-1), 0.0) for s in carried)
            pick = lambda s: StreamBatch(s.features[t], s.kind[t], s.mask[t])      # noqa: E731
            step = model(pick(static), pick(dynamic), previous[t], state[t], carried)
            carried = step.state
            name = "acceleration" if action_mode == "discrete" else "command"
            torch.testing.assert_close(getattr(sequence, name)[t], getattr(step, name), rtol=1e-5, atol=1e-5)
            torch.testing.assert_close(sequence.value[t], step.value, rtol=1e-5, atol=1e-5)
    assert sequence.pose is None and sequence.walk is None


def test_the_clipped_gaussian_scores_the_executed_action():
    loc, scale = torch.tensor([0.3, 0.9, -0.5], dtype=torch.float64), torch.tensor([0.5, 0.2, 1.0],
                                                                                   dtype=torch.float64)
    for d, (low, high) in enumerate(zip(driving_actions.CONTINUOUS_LOW, driving_actions.CONTINUOUS_HIGH)):
        dist = ClippedNormal(loc[d], scale[d], low, high)
        normal = torch.distributions.Normal(loc[d], scale[d])
        inside = torch.tensor(0.5 * (low + high), dtype=torch.float64)
        torch.testing.assert_close(dist.log_prob(inside), normal.log_prob(inside))
        p_low, p_high = dist.log_prob(torch.tensor(low)).exp(), dist.log_prob(torch.tensor(high)).exp()
        torch.testing.assert_close(p_low, normal.cdf(torch.tensor(low, dtype=torch.float64)))
        torch.testing.assert_close(p_high, 1 - normal.cdf(torch.tensor(high, dtype=torch.float64)))
        # the mass on the bounds plus the density inside them make one
        grid = torch.linspace(low, high, 20001, dtype=torch.float64)[1:-1]
        density = dist.log_prob(grid).exp()
        inside_mass = torch.trapezoid(density, grid)
        assert abs(float(p_low + p_high + inside_mass) - 1.0) < 1e-4
    far = ClippedNormal(torch.tensor(0.0), torch.tensor(0.01), -1.0, 1.0)
    assert torch.isfinite(far.log_prob(torch.tensor(1.0))) and far.log_prob(torch.tensor(1.0)) < -1000


@pytest.mark.parametrize("action_mode", ["discrete", "continuous"])
def test_sampled_driving_actions_become_commands_the_simulator_accepts(action_mode):
    torch.manual_seed(3)
    model = DynEnvAgent(feature_size=16, scenario="driving", action_mode=action_mode)
    batch, spec = driving_batch(n_cars=4)
    with torch.no_grad():
        step = model(*streams_from_padded(batch, spec), *side_inputs(batch, spec=spec), model.initial_state(4))
    w = DrivingConfig().cars.max_yaw_rate
    for greedy in (True, False):
        actions, finite = driving_actions.sample_actions(step, action_mode, torch.Generator().manual_seed(0), greedy)
        assert finite.all()
        commands = driving_actions.commands(actions, action_mode, w)
        assert all(driving_actions.command_problem(c, action_mode, w) == "" for c in commands)
        log_probs = driving_actions.log_probs(step, actions, action_mode)
        expected = sum(d.log_prob(torch.as_tensor(a)) for d, a in zip(model.distributions(step), actions.T))
        np.testing.assert_allclose(log_probs, expected.double().numpy(), rtol=1e-5, atol=1e-5)
    assert driving_actions.command_problem((0.5, 0.0, 0.0), "discrete", w)          # not one of the nine
    assert driving_actions.command_problem((0.0, 1.0, 2 * w), "continuous", w).startswith("steering")
    assert math.isclose(w, spec.action_high[2], rel_tol=1e-6)


def test_an_untrained_continuous_head_starts_with_the_brake_released():
    """Its mean brake starts near 0.02 and the brake's spread at 0.2 (``driving_actions.INITIAL_COMMAND``,
    ``INITIAL_STD``): a head starting at the bounds' centre pressed the brake half down, which stops any throttle
    (full brake = 2 x full traction), and PPO learnt nothing in the tiny driving task from there."""
    torch.manual_seed(5)
    model = DynEnvAgent(feature_size=64, scenario="driving", action_mode="continuous")
    batch, spec = driving_batch(n_cars=8)
    with torch.no_grad():
        step = model(*streams_from_padded(batch, spec), *side_inputs(batch, spec=spec), model.initial_state(8))
    mean, std = step.command[:, :3], step.command[:, 3:].exp()
    assert float(mean[:, 1].max()) < 0.1                        # brake released wherever the car looks
    np.testing.assert_allclose(std[0].numpy(), [0.5, 0.2, 0.5], rtol=1e-6)
