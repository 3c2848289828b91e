"""The agent network: invariant to detection order and padding, fine with empty frames, deterministic, and every
part wired (gradients reach every parameter; a tiny localization task is learned)."""
import math

import numpy as np
import pytest
import torch

from dynenv_ros.envs.robocup_v0 import parallel_env
from policy_node.model.inputs import ACTION_ENCODING, FEATURES, PROPRIOCEPTION, collate, encode_previous_action
from policy_node.model.network import DynEnvAgent, parameter_count


def _observations(seed=0, robots=2):
    env = parallel_env(players_per_team=1, perception={"preset": "realistic", "noise_magnitude": 2.0})
    obs, _ = env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + i)              # the same frames every run
    for _ in range(3):
        obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    frames = [obs[a]["detections"] for a in env.possible_agents][:robots]
    classes = {int(c) for rows in frames[0] for c in rows[:, 0]}
    assert {1, 2} & classes and {3, 4, 5, 6} & classes, "the test scene must show objects and landmarks"
    return frames


def _run(model, observations, max_objects=None, state=None):
    landmarks, objects = collate(observations, max_landmarks=max_objects, max_objects=max_objects)
    B = len(observations)
    prev = torch.zeros(B, ACTION_ENCODING)
    proprio = torch.zeros(B, PROPRIOCEPTION)
    return model(landmarks, objects, prev, proprio, state or model.initial_state(B))


@pytest.fixture
def model():
    torch.manual_seed(0)
    return DynEnvAgent(feature_size=32).eval()


def _close(a, b, tol=1e-5):
    return torch.allclose(a, b, atol=tol, rtol=1e-4)


def test_outputs_do_not_depend_on_the_order_of_detections(model):
    observations = _observations()
    rng = np.random.default_rng(1)
    shuffled = [[rows[rng.permutation(len(rows))] for rows in frames] for frames in observations]
    a, b = _run(model, observations), _run(model, shuffled)
    for field in ("walk", "turn", "kick", "head", "value", "pose", "phi"):
        assert _close(getattr(a, field), getattr(b, field)), field


def test_padding_does_not_change_outputs(model):
    observations = _observations()
    a, b = _run(model, observations), _run(model, observations, max_objects=64)
    for field in ("walk", "value", "pose", "phi"):
        assert _close(getattr(a, field), getattr(b, field)), field


def test_a_batch_entry_does_not_depend_on_the_others(model):
    observations = _observations(robots=2)
    together = _run(model, observations)
    alone = _run(model, observations[:1])
    assert _close(together.phi[:1], alone.phi)


def test_empty_frames_and_no_detections_give_finite_outputs(model):
    empty = [[np.zeros((0, FEATURES), np.float32)] * 5, [np.zeros((0, FEATURES), np.float32)] * 5]
    out = _run(model, empty)
    for field in ("walk", "turn", "kick", "head", "value", "pose", "phi"):
        assert torch.isfinite(getattr(out, field)).all(), field
    mixed = _observations()[:1] + [[np.zeros((0, FEATURES), np.float32)] * 5]
    assert torch.isfinite(_run(model, mixed).phi).all()


def test_forward_is_deterministic_and_the_recurrent_state_matters(model):
    observations = _observations()
    a, b = _run(model, observations), _run(model, observations)
    assert torch.equal(a.phi, b.phi)
    c = _run(model, observations, state=a.state)
    assert not torch.allclose(a.phi, c.phi)


def test_every_parameter_gets_gradient_from_the_actor_critic_and_localization_losses():
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=16, head_mode="continuous")
    observations = _observations()
    first = _run(model, observations)
    out = _run(model, observations, state=first.state)      # a second period: the recurrent weights act too
    actions = model.act(out, generator=torch.Generator().manual_seed(0))
    log_prob = sum(d.log_prob(actions[:, i]) for i, d in enumerate(model.distributions(out)))
    loss = -log_prob.mean() + out.value.pow(2).mean() + out.pose.pow(2).mean()
    loss = loss + out.ball.pow(2).mean() + out.ball_confidence.mean() + out.robots.pow(2).mean() \
        + out.robot_confidence.mean()
    loss.backward()
    unused = [name for name, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    # class blocks of classes absent from these frames cannot get gradient; everything else must
    assert all(".embed.blocks." in name for name in unused), unused


def test_continuous_head_turn_samples_within_limits_and_discrete_gives_indices():
    torch.manual_seed(0)
    continuous = DynEnvAgent(feature_size=16, head_mode="continuous")
    out = _run(continuous, _observations())
    head = continuous.act(out, generator=torch.Generator().manual_seed(1))[:, 3]
    assert (head.abs() <= continuous.head_max + 1e-6).all()
    discrete = DynEnvAgent(feature_size=16)
    actions = discrete.act(_run(discrete, _observations()), greedy=True)
    assert actions.dtype == torch.float32 and set(actions[:, 3].tolist()) <= set(range(7))


def test_previous_action_encoding_keeps_every_dimension():
    enc = encode_previous_action(torch.tensor([3, 4]), torch.tensor([1, 2]), torch.tensor([2, 0]),
                                 torch.tensor([0.2, -0.4]), head_max=0.4)
    assert enc.shape == (2, ACTION_ENCODING)
    assert not torch.equal(enc[0, :5], enc[1, :5])           # left and right side steps differ (DynEnv merged them)
    assert enc[0, 8 + 2] == 1 and enc[1, 8] == 1             # the kick survives (DynEnv overwrote it)
    assert enc[:, -1].tolist() == pytest.approx([0.5, -1.0])


def test_parameter_count_is_small():
    assert 50_000 < parameter_count(DynEnvAgent()) < 400_000


def test_a_tiny_localization_task_is_learned():
    """Supervised: the pose head learns the robot's field position from its landmark detections."""
    torch.manual_seed(0)
    env = parallel_env(players_per_team=1, perception="none", falls={"enabled": False})
    rng = np.random.default_rng(0)
    samples = []
    for seed in range(24):
        obs, _ = env.reset(seed=seed)
        robot = env.world.robots[0]
        x, y = rng.uniform(-3.5, 3.5), rng.uniform(-2.5, 2.5)
        env.world.place_robot(0, x, y, rng.uniform(-math.pi, math.pi))
        obs, *_ = env.step({a: np.array([0, 0, 0, 3]) for a in env.agents})
        samples.append((obs["team_a_0"]["detections"], [robot.x, robot.y]))
    model = DynEnvAgent(feature_size=32)
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    landmarks, objects = collate([s[0] for s in samples])
    target = torch.tensor([s[1] for s in samples], dtype=torch.float32)
    B = len(samples)

    def loss_now():
        out = model(landmarks, objects, torch.zeros(B, ACTION_ENCODING), torch.zeros(B, PROPRIOCEPTION),
                    model.initial_state(B))
        return (out.pose[:, :2] - target).pow(2).mean()

    first = loss_now().item()
    for _ in range(150):
        optimiser.zero_grad()
        loss = loss_now()
        loss.backward()
        optimiser.step()
    assert loss.item() < 0.2 * first


def test_reconstruction_loss_trains_the_head_and_the_object_stream():
    from policy_node.model.losses import ANCHORS, reconstruction_loss
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=16)
    out = _run(model, _observations())
    targets = torch.tensor([[[1.0, 0.5, 1, 0, 1, 0], [-2.0, 1.0, 0, 1, -1, 0], [0, 0, 0, 0, 0, 0]]] * 2)
    seen = torch.tensor([[True, True, False]] * 2)
    losses = reconstruction_loss(out.robots, out.robot_confidence, targets, seen, anchors=ANCHORS)
    sum(losses.values()).backward()
    assert model.reconstruction.net[0].weight.grad.abs().sum() > 0
    assert model.objects.lstm.weight_ih.grad.abs().sum() > 0
