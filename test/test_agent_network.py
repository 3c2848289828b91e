"""The agent network: invariant to detection order and padding, fine with empty frames, deterministic, and every
part wired (gradients reach every parameter; a tiny localization task is learned)."""
import math

import numpy as np
import pytest
import torch

from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.agent.inputs import (ACTION_ENCODING, FEATURES, NUM_CLASSES, PROPRIOCEPTION, collate,
                                   encode_previous_action)
from dynenv_ros.agent.network import DynEnvAgent, parameter_count


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


def _linear(n_in, n_out, bias=True):
    return n_in * n_out + (n_out if bias else 0)


def _layer_norm(d):
    return 2 * d                                             # weight and bias


def _lstm_cell(n_in, h):
    return 4 * (n_in * h + h * h + 2 * h)                    # weight_ih, weight_hh, bias_ih, bias_hh of 4 gates


def _attention_with_bias_kv(d):
    # nn.MultiheadAttention(d, 1, add_bias_kv=True): in_proj weight (3d·d) and bias (3d), out_proj Linear(d, d),
    # bias_k (d) and bias_v (d)
    return 3 * d * d + 3 * d + _linear(d, d) + d + d


def _expected_parameters(d, head_mode="discrete", head_units=3, robot_slots=4, pose=6, embed_hidden=32):
    """The architecture as network.py documents it, counted by hand (no call into the model code)."""
    embed_block = (_linear(FEATURES, embed_hidden, bias=False) + _layer_norm(embed_hidden)
                   + _linear(embed_hidden, d, bias=False) + _layer_norm(d))          # EmbedBlock: 2 × (Linear, LN)
    rta = 2 * _attention_with_bias_kv(d) + _layer_norm(d) + _linear(d, 1)            # object + temporal attention

    def stream(side):                                       # embed → RTA → transform → LSTMCell → LayerNorm
        return (NUM_CLASSES * embed_block + rta + _linear(d + side, d) + _layer_norm(d) + _lstm_cell(d, d)
                + _layer_norm(d))

    total = stream(ACTION_ENCODING + PROPRIOCEPTION)         # localization: previous action + proprioception
    total += _linear(d, pose)                                # pose head
    total += stream(pose + PROPRIOCEPTION)                   # objects: pose estimate + proprioception
    total += _linear(2 * d, 5) + _linear(2 * d, 3) + _linear(2 * d, 3)                   # walk, turn, kick
    total += _linear(2 * d, 2 * head_units + 1) if head_mode == "discrete" else _linear(2 * d, 1) + 1  # + log std
    total += _linear(2 * d, d) + _layer_norm(d) + _linear(d, 1)                          # critic
    total += _linear(d, 2 * d) + _layer_norm(2 * d) + _linear(2 * d, 4 + robot_slots * 7)  # reconstruction
    return total


@pytest.mark.parametrize("feature_size,head_mode", [(64, "discrete"), (16, "continuous"), (32, "discrete")])
def test_parameter_count_is_exactly_the_documented_architecture(feature_size, head_mode):
    expected = _expected_parameters(feature_size, head_mode)
    assert parameter_count(DynEnvAgent(feature_size=feature_size, head_mode=head_mode)) == expected


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
    from dynenv_ros.agent.losses import ANCHORS, reconstruction_loss
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=16)
    out = _run(model, _observations())
    targets = torch.tensor([[[1.0, 0.5, 1, 0, 1, 0], [-2.0, 1.0, 0, 1, -1, 0], [0, 0, 0, 0, 0, 0]]] * 2)
    seen = torch.tensor([[True, True, False]] * 2)
    losses = reconstruction_loss(out.robots, out.robot_confidence, targets, seen, anchors=ANCHORS)
    sum(losses.values()).backward()
    assert model.reconstruction.net[0].weight.grad.abs().sum() > 0
    assert model.objects.lstm.weight_ih.grad.abs().sum() > 0


# ---- Recurrent Temporal Attention: a slot stays valid once any frame of the period has filled it

def _rta(size=16):
    from dynenv_ros.agent.network import RecurrentTemporalAttention
    torch.manual_seed(0)
    return RecurrentTemporalAttention(size).eval()


def test_rta_remembers_earlier_frames_when_the_last_frame_is_empty():
    rta, frames, slots = _rta(), 5, 4
    x = torch.randn(2, frames, slots, 16, generator=torch.Generator().manual_seed(1))
    mask = torch.zeros(2, frames, slots, dtype=torch.bool)
    mask[:, :, 3] = True                                     # a slot no frame fills
    mask[:, -1] = True                                       # the last frame saw nothing
    with torch.no_grad():
        pooled, confidence = rta(x, mask)
        assert (pooled.norm(dim=-1) > 0.1).all()
        assert (confidence[:, :3] > 0).all() and (confidence[:, 3] == 0).all()
        changed = x.clone()
        changed[:, :-1] += torch.randn(2, frames - 1, slots, 16, generator=torch.Generator().manual_seed(2))
        assert ((rta(changed, mask)[0] - pooled).abs().amax(-1) > 1e-3).all()
        # what the empty last frame and the never-filled slot hold changes nothing
        ignored = x.clone()
        ignored[:, -1] = 7.0
        ignored[:, :, 3] = -7.0
        assert torch.allclose(rta(ignored, mask)[0], pooled, atol=1e-6)


def test_rta_slot_filled_only_in_the_first_frame_still_counts_at_the_end():
    rta, frames = _rta(), 5
    x = torch.randn(1, frames, 2, 16, generator=torch.Generator().manual_seed(3))
    mask = torch.ones(1, frames, 2, dtype=torch.bool)
    mask[:, :, 0] = False                                    # slot 0: every frame
    mask[:, 0, 1] = False                                    # slot 1: frame 0 only
    with torch.no_grad():
        pooled, confidence = rta(x, mask)
        assert confidence[0, 1] > 0                          # still pooled after four frames without it
        other = x.clone()
        other[:, 0, 1] = torch.randn(16, generator=torch.Generator().manual_seed(4))
        assert (rta(other, mask)[0] - pooled).abs().max() > 1e-3
        never = mask.clone()
        never[:, 0, 1] = True                                # the same period without that detection
        assert (rta(x, never)[0] - pooled).abs().max() > 1e-3
        assert rta(x, never)[1][0, 1] == 0
        # only frame 0 has anything: its detections carry through to the end
        first_only = torch.ones_like(mask)
        first_only[:, 0] = False
        alone, confidence = rta(x, first_only)
        assert (confidence > 0).all() and alone.norm() > 0.1
        assert (rta(other, first_only)[0] - alone).abs().max() > 1e-3


def _empty_last_frame(frames):
    return list(frames[:-1]) + [np.zeros((0, FEATURES), np.float32)]


def _shift(frames, classes, dx):
    """Frames 0..F-2 with the x of the given classes' detections moved by dx (metres); the last frame as is."""
    out = []
    for rows in frames[:-1]:
        rows = rows.copy()
        rows[np.isin(rows[:, 0].astype(int), classes), 1] += dx
        out.append(rows)
    return out + [frames[-1]]


def test_agent_features_keep_the_period_when_its_last_frame_is_empty(model):
    """Both streams: with nothing in the last frame, the pooled RTA output is not zero and the agent's features
    still follow what the earlier frames saw."""
    robot = _empty_last_frame(_observations()[0])
    earlier = np.concatenate(robot[:-1])
    assert np.isin(earlier[:, 0], [1, 2]).any() and np.isin(earlier[:, 0], [3, 4, 5, 6, 7]).any()
    landmarks, objects = collate([robot])
    assert landmarks.mask[:, -1].all() and objects.mask[:, -1].all()
    with torch.no_grad():
        for stream, batch in ((model.localization, landmarks), (model.objects, objects)):
            pooled, _ = stream.rta(stream.embed(batch.features, batch.kind), batch.mask)
            assert pooled.norm() > 0.1
        base = _run(model, [robot])
        moved_objects = _run(model, [_shift(robot, [1, 2], 0.5)])
        moved_landmarks = _run(model, [_shift(robot, [3, 4, 5, 6, 7], 0.5)])
    # the same landmarks give the same pose; the objects seen earlier in the period still reach the object stream
    assert torch.allclose(moved_objects.pose, base.pose)
    assert (moved_objects.object_features - base.object_features).abs().max() > 1e-3
    assert (moved_landmarks.pose - base.pose).abs().max() > 1e-4
