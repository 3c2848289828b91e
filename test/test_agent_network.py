"""The agent network: invariant to detection order and padding, fine with empty frames, deterministic, and every
part wired (gradients reach every parameter; a tiny localization task is learned)."""
import math

import numpy as np
import pytest
import torch

from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.agent.inputs import (ACTION_ENCODING, FEATURES, NUM_CLASSES, PROPRIOCEPTION, collate,
                                   encode_previous_action)
from dynenv_ros.agent.network import AgentStep, DynEnvAgent, parameter_count


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


def _step_by_step(model, landmarks, objects, previous, proprio, start, resets):
    """``forward`` period by period with the state carried and zeroed where ``resets`` says: (steps, last state)."""
    steps, state = [], start
    for t in range(previous.shape[0]):
        keep = (~resets[t]).float().unsqueeze(-1)
        step = model(_at(landmarks, t), _at(objects, t), previous[t], proprio[t], tuple(s * keep for s in state))
        steps.append(step)
        state = step.state
    return steps, state


# ---- Training passes: forward_sequence, and the sparse/bucketed computation against a dense reference

def _rollout(periods=4, max_landmarks=48, max_objects=12, seed=0):
    """``periods`` consecutive motion periods of a 2v2 game with sampled actions, as forward_sequence's inputs:
    streams (T, 4, F, N, ...) collated at fixed maxima (lots of trailing padding), previous actions, self-state."""
    from dynenv_ros.agent.inputs import StreamBatch, self_state
    env = parallel_env(players_per_team=2, perception={"preset": "realistic", "noise_magnitude": 2.0})
    env.reset(seed=seed)
    for i, agent in enumerate(env.possible_agents):
        env.action_space(agent).seed(seed + i)
    steps = []
    for _ in range(periods):
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, *_ = env.step(actions)
        a = torch.tensor(np.stack([actions[agent] for agent in env.possible_agents]))
        previous = encode_previous_action(a[:, 0], a[:, 1], a[:, 2], (a[:, 3] - 3) * 0.2, 0.6)
        proprio = self_state(np.stack([obs[agent]["proprioception"][-1] for agent in env.possible_agents]),
                             np.stack([obs[agent]["game"] for agent in env.possible_agents]))
        landmarks, objects = collate([obs[agent]["detections"] for agent in env.possible_agents],
                                     max_landmarks=max_landmarks, max_objects=max_objects)
        steps.append((landmarks, objects, previous, proprio))

    def stack(index):
        if isinstance(steps[0][index], StreamBatch):
            return StreamBatch(*(torch.stack([getattr(s[index], name) for s in steps])
                                 for name in ("features", "kind", "mask")))
        return torch.stack([s[index] for s in steps])

    return tuple(stack(i) for i in range(4))


_OUTPUTS = ("walk", "turn", "kick", "head", "value", "pose", "phi", "object_features", "landmark_confidence",
            "object_confidence", "ball", "ball_confidence", "robots", "robot_confidence")


def _scalar(outputs, weights):
    """A fixed random linear function of every output (so every output's gradient path is checked)."""
    return sum((getattr(outputs, name) * weights[name]).sum() for name in _OUTPUTS)


def _weights(outputs):
    generator = torch.Generator().manual_seed(5)
    return {name: torch.randn(getattr(outputs, name).shape, generator=generator) for name in _OUTPUTS}


def _gradients(model, loss):
    model.zero_grad(set_to_none=True)
    loss.backward()
    return {name: p.grad.clone() for name, p in model.named_parameters() if p.grad is not None}


def _same_gradients(a, b, tol=1e-4):
    """Per parameter, max |a − b| ≤ tol · max |b|; a parameter without a gradient on one side (a class block no
    row of that class reached) must have an all-zero one on the other."""
    for name in a.keys() | b.keys():
        if name not in a or name not in b:
            assert (a.get(name, b.get(name)) == 0).all(), name
            continue
        scale = b[name].abs().max().clamp(min=1e-6)
        assert (a[name] - b[name]).abs().max() <= tol * scale, (name, ((a[name] - b[name]).abs().max() / scale).item())


def _at(batch, t):
    return type(batch)(batch.features[t], batch.kind[t], batch.mask[t])


@pytest.mark.parametrize("head_mode", ["discrete", "continuous"])
def test_forward_sequence_equals_stepping_forward_with_the_state_carried_and_reset(head_mode):
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=32, head_mode=head_mode)
    landmarks, objects, previous, proprio = _rollout(periods=4)
    T, B = previous.shape[:2]
    generator = torch.Generator().manual_seed(1)
    start = tuple(torch.randn(B, 32, generator=generator) for _ in range(4))      # mid-episode state
    resets = torch.zeros(T, B, dtype=torch.bool)
    resets[2, 1] = resets[2, 3] = True                     # two robots' episodes restart at period 2
    resets[0, 2] = True                                    # and one at the very first period
    sequence = model.forward_sequence(landmarks, objects, previous, proprio, start, resets)
    steps, state = _step_by_step(model, landmarks, objects, previous, proprio, start, resets)
    for name in _OUTPUTS:
        stepped = torch.stack([getattr(step, name) for step in steps])
        assert getattr(sequence, name).shape == stepped.shape, name
        assert torch.allclose(getattr(sequence, name), stepped, atol=1e-5, rtol=0), name
    for a, b in zip(sequence.state, state):
        assert torch.allclose(a, b, atol=1e-5, rtol=0)
    weights = _weights(sequence)
    by_sequence = _gradients(model, _scalar(sequence, weights) + sum(s.sum() for s in sequence.state))
    steps, state = _step_by_step(model, landmarks, objects, previous, proprio, start, resets)
    stepped = type(sequence)(**{name: torch.stack([getattr(s, name) for s in steps]) for name in _OUTPUTS},
                             state=state)
    by_steps = _gradients(model, _scalar(stepped, weights) + sum(s.sum() for s in stepped.state))
    _same_gradients(by_sequence, by_steps)
    # a reset really cuts the state: the restarted robots' later outputs do not depend on the state before
    other = model.forward_sequence(landmarks, objects, previous, proprio, tuple(s + 1.0 for s in start), resets)
    assert torch.allclose(other.phi[2:, [1, 3]], sequence.phi[2:, [1, 3]], atol=1e-6)
    assert (other.phi[2:, 0] - sequence.phi[2:, 0]).abs().max() > 1e-3


def test_forward_is_forward_sequence_of_one_period(model):
    landmarks, objects, previous, proprio = _rollout(periods=1)
    state = model.initial_state(4)
    one = model.forward_sequence(landmarks, objects, previous, proprio, state)
    step = model(_at(landmarks, 0), _at(objects, 0), previous[0], proprio[0], state)
    for name in _OUTPUTS:
        assert torch.allclose(getattr(one, name)[0], getattr(step, name), atol=1e-6, rtol=0), name
    with pytest.raises(ValueError, match="resets"):
        model.forward_sequence(landmarks, objects, previous, proprio, state, torch.zeros(2, 4, dtype=torch.bool))


def _dense_reference(model, landmarks, objects, previous, proprio, state):
    """The agent as first written, slow and literal: every class's block on every slot (padding included) and the
    right one gathered, no slot cut, ``nn.MultiheadAttention``'s own function on the attention parameters,
    ``nn.LSTMCell`` called as a module — on the model's parameters, so outputs and gradients compare."""
    import torch.nn.functional as F

    def embed(stream, batch):
        every = torch.stack([block(batch.features) for block in stream.embed.blocks], dim=-2)
        index = batch.kind.unsqueeze(-1).unsqueeze(-1).expand(*batch.kind.shape, 1, every.shape[-1])
        return every.gather(-2, index).squeeze(-2)

    def attention(module, query, key, padding):
        out, _ = F.multi_head_attention_forward(
            query.transpose(0, 1), key.transpose(0, 1), key.transpose(0, 1), module.embed_dim, 1,
            module.in_proj_weight, module.in_proj_bias, module.bias_k, module.bias_v, False, 0.0,
            module.out_proj.weight, module.out_proj.bias, training=False, key_padding_mask=padding,
            need_weights=False)
        return out.transpose(0, 1)

    def rta(stream, batch):
        module, x, mask = stream.rta, embed(stream, batch), batch.mask
        B, frames, N, D = x.shape
        attended = attention(module.object_attention, x.reshape(B * frames, N, D), x.reshape(B * frames, N, D),
                             mask.reshape(B * frames, N))
        attended = attended.reshape(B, frames, N, D).masked_fill(mask.unsqueeze(-1), 0.0)
        summary, padded_so_far = attended[:, 0], mask[:, 0]
        for t in range(1, frames):
            fed_back = attention(module.temporal_attention, attended[:, t], summary, padded_so_far)
            padded_so_far = padded_so_far & mask[:, t]
            summary = module.norm(attended[:, t] + fed_back).masked_fill(padded_so_far.unsqueeze(-1), 0.0)
        confidence = torch.sigmoid(module.confidence(summary)).squeeze(-1).masked_fill(padded_so_far, 0.0)
        pooled = (confidence.unsqueeze(-1) * summary).sum(1) / (1.0 + confidence.sum(1, keepdim=True))
        return pooled, confidence

    def stream_step(stream, batch, side, stream_state):
        pooled, confidence = rta(stream, batch)
        h, c = stream.lstm(stream.transform(torch.cat([pooled, side], dim=-1)), stream_state)
        return stream.norm(h), (h, c), confidence

    loc, loc_state, landmark_confidence = stream_step(model.localization, landmarks,
                                                      torch.cat([previous, proprio], dim=-1), state[:2])
    pose = model.pose_head(loc)
    obj, obj_state, object_confidence = stream_step(model.objects, objects,
                                                    torch.cat([pose.detach(), proprio], dim=-1), state[2:])
    phi = torch.cat([loc, obj], dim=-1)
    if model.head_mode == "discrete":
        head = model.head_head(phi)
    else:
        mean = model.head_max * torch.tanh(model.head_head(phi))
        head = torch.cat([mean, model.head_log_std.expand_as(mean)], dim=-1)
    ball, ball_conf, robots, robot_conf = model.reconstruction(obj)
    return AgentStep(walk=model.walk_head(phi), turn=model.turn_head(phi), kick=model.kick_head(phi), head=head,
                     value=model.critic(phi).squeeze(-1), pose=pose, phi=phi, object_features=obj,
                     state=loc_state + obj_state, landmark_confidence=landmark_confidence,
                     object_confidence=object_confidence, ball=ball, ball_confidence=ball_conf, robots=robots,
                     robot_confidence=robot_conf)


def _flat(batch, order=None):
    """(T, B, F, N, ...) → (T·B, F, N, ...), slots permuted by ``order`` (padding scattered through the frame)."""
    from dynenv_ros.agent.inputs import StreamBatch
    out = StreamBatch(batch.features.flatten(0, 1), batch.kind.flatten(0, 1), batch.mask.flatten(0, 1))
    if order is not None:
        out = StreamBatch(out.features[:, :, order], out.kind[:, :, order], out.mask[:, :, order])
    return out


@pytest.mark.parametrize("max_buckets,head_mode,scattered", [(1, "discrete", False), (3, "discrete", False),
                                                              (3, "continuous", True), (8, "continuous", False)])
def test_sparse_embedding_slot_cuts_and_buckets_equal_the_dense_computation(monkeypatch, max_buckets, head_mode,
                                                                            scattered):
    """Outputs and gradients of the network (each row through its own class's block only, padded rows skipped,
    slots cut per bucket of periods, folded attention, its own LSTM step) against the dense literal reference,
    on 12 robot-periods of real detections collated at fixed maxima — with the padding left trailing or
    scattered through each frame, in one bucket or several."""
    from dynenv_ros.agent import network
    plan = network.plan_buckets
    plans = []

    def recording_plan(used, limit=3):
        plans.append(plan(used, max_buckets))
        return plans[-1]

    monkeypatch.setattr(network, "plan_buckets", recording_plan)
    monkeypatch.setattr(network, "_BUCKET_WORK", 0.0)        # split wherever lengths differ (few periods here)
    torch.manual_seed(0)
    model = DynEnvAgent(feature_size=32, head_mode=head_mode)
    landmarks, objects, previous, proprio = _rollout(periods=3)
    order = torch.randperm(48, generator=torch.Generator().manual_seed(3)) if scattered else None
    object_order = torch.randperm(12, generator=torch.Generator().manual_seed(4)) if scattered else None
    landmarks, objects = _flat(landmarks, order), _flat(objects, object_order)
    previous, proprio = previous.flatten(0, 1), proprio.flatten(0, 1)
    gaps = landmarks.mask[..., :-1] & ~landmarks.mask[..., 1:]     # a padded slot before a filled one
    assert gaps.any() == scattered and landmarks.mask[:, :, -8:].all()  # trailing padding, or scattered too
    generator = torch.Generator().manual_seed(2)
    state = tuple(torch.randn(12, 32, generator=generator) for _ in range(4))
    fast = model(landmarks, objects, previous, proprio, state)
    if max_buckets > 1 and not scattered:
        assert max(len(p) for p in plans) > 1, plans          # the several-bucket path ran
    slow = _dense_reference(model, landmarks, objects, previous, proprio, state)
    for name in _OUTPUTS:
        assert torch.allclose(getattr(fast, name), getattr(slow, name), atol=1e-5, rtol=0), name
    weights = _weights(fast)
    _same_gradients(_gradients(model, _scalar(fast, weights)), _gradients(model, _scalar(slow, weights)))


def test_single_head_attention_is_multihead_attention_with_the_same_state_dict():
    """Parameter names, shapes and initialisation of nn.MultiheadAttention(D, 1, add_bias_kv=True); loaded into
    one, it computes the same function."""
    from dynenv_ros.agent.network import SingleHeadAttention
    torch.manual_seed(0)
    ours = SingleHeadAttention(16)
    torch.manual_seed(0)
    theirs = torch.nn.MultiheadAttention(16, 1, add_bias_kv=True, batch_first=True)
    assert {k: v.shape for k, v in ours.state_dict().items()} == {k: v.shape for k, v in theirs.state_dict().items()}
    assert all(torch.equal(v, theirs.state_dict()[k]) for k, v in ours.state_dict().items())
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for parameter in ours.parameters():
            parameter.add_(0.3 * torch.randn(parameter.shape, generator=generator))   # biases nonzero too
    theirs.load_state_dict(ours.state_dict())
    query, key = torch.randn(3, 5, 16, generator=generator), torch.randn(3, 7, 16, generator=generator)
    padding = torch.zeros(3, 7, dtype=torch.bool)
    padding[0, 3:] = True
    padding[2, :] = True                                     # every key padded: only the bias key remains
    expected = theirs(query, key, key, key_padding_mask=padding, need_weights=False)[0]
    assert torch.allclose(ours(query, key, padding), expected, atol=1e-5)
    assert torch.allclose(ours(query), theirs(query, query, query, need_weights=False)[0], atol=1e-5)


def test_plan_buckets_keeps_every_period_and_its_slots():
    from dynenv_ros.agent.network import plan_buckets
    for used in ([1] * 30 + [19] * 3, list(range(1, 41)), [5], [3, 3, 3, 12, 12, 40]):
        plan = plan_buckets(torch.tensor(used))
        assert sum(count for count, _ in plan) == len(used) and 1 <= len(plan) <= 3
        edges = np.cumsum([count for count, _ in plan])
        assert [slots for _, slots in plan] == [used[e - 1] for e in edges]   # each bucket cut to its longest
    assert len(plan_buckets(torch.tensor([2] * 200 + [30] * 200))) == 2
    assert plan_buckets(torch.tensor([4, 4, 5])) == [(3, 5)]                  # not worth a second bucket


def test_embedding_refuses_an_unknown_class_on_a_real_row():
    from dynenv_ros.agent.network import ClassEmbedding
    embedding = ClassEmbedding(8)
    features, kind = torch.randn(2, 3, FEATURES), torch.tensor([[1, 2, 99], [0, 1, 2]])
    with pytest.raises(ValueError, match="class index"):
        embedding(features, kind, torch.zeros(2, 3, dtype=torch.bool))
    padded = torch.tensor([[False, False, True], [False, False, False]])
    out = embedding(features, kind, padded)                  # the same index on a padded row is ignored
    assert out.shape == (2, 3, 8) and (out[0, 2] == 0).all() and (out[1].abs().sum(-1) > 0).all()


def test_the_short_row_softmax_is_torchs_softmax_forward_and_backward():
    from dynenv_ros.agent.network import short_row_softmax
    generator = torch.Generator().manual_seed(5)
    scores = torch.randn(300, 6, 9, generator=generator, dtype=torch.float64)
    scores[:, :, 3] = float("-inf")                                   # a masked key: weight exactly 0
    scores[:7, :, :8] = float("-inf")                                 # rows with only the bias slot left
    ours = short_row_softmax(scores)
    assert torch.allclose(ours, torch.softmax(scores, dim=-1), rtol=0, atol=1e-12)
    assert bool((ours[:, :, 3] == 0).all()) and torch.allclose(ours[:7, :, 8], torch.ones(7, 6, dtype=torch.float64))
    finite = torch.randn(40, 3, 5, generator=generator, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(short_row_softmax, (finite,))
    upstream = torch.randn(300, 6, 9, generator=generator, dtype=torch.float64)
    a, b = scores.clone().requires_grad_(), scores.clone().requires_grad_()
    (short_row_softmax(a) * upstream).sum().backward()
    (torch.softmax(b, dim=-1) * upstream).sum().backward()
    assert torch.allclose(a.grad, b.grad, rtol=0, atol=1e-12)
    with torch.inference_mode():                                      # acting: no graph, the same weights
        assert torch.allclose(short_row_softmax(scores.float()), torch.softmax(scores.float(), dim=-1), atol=1e-6)
