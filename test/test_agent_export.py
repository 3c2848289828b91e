"""The ONNX export of the agent: onnxruntime gives what torch gives (to 1e-5) on real detections across periods with
the recurrent state fed back, for any number of robots from one file, in both head modes and with empty frames;
a damaged file is refused clearly."""
import math

import numpy as np
import pytest
import torch

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from dynenv_ros.envs.robocup_v0 import parallel_env  # noqa: E402
from dynenv_ros.agent.export import OnnxPolicy, TorchPolicy, export_onnx  # noqa: E402
from dynenv_ros.agent.inputs import (FEATURES, PROPRIOCEPTION, collate, encode_previous_action,  # noqa: E402
                                      self_state)
from dynenv_ros.agent.network import DynEnvAgent  # noqa: E402

FRAMES, MAX_LANDMARKS, MAX_OBJECTS = 5, 48, 12
PERIODS = 3
HEAD_STEP, HEAD_UNITS = math.radians(12.5), 3
FIELDS = ("walk", "turn", "kick", "head", "value", "pose")


@pytest.fixture(scope="module")
def periods():
    """PERIODS consecutive env steps of a 2v2 game with sampled actions: per period, the 4 robots' (detections,
    encoded previous action — the one that led to these observations —, last frame's proprioception)."""
    env = parallel_env(players_per_team=2, perception={"preset": "realistic", "noise_magnitude": 2.0})
    obs, _ = env.reset(seed=0)
    for agent in env.possible_agents:
        env.action_space(agent).seed(0)
    out = []
    for _ in range(PERIODS):
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, *_ = env.step(actions)
        a = torch.tensor(np.stack([actions[agent] for agent in env.possible_agents]))
        previous = encode_previous_action(a[:, 0], a[:, 1], a[:, 2], (a[:, 3] - HEAD_UNITS) * HEAD_STEP,
                                          HEAD_STEP * HEAD_UNITS)
        proprio = self_state(np.stack([obs[agent]["proprioception"][-1] for agent in env.possible_agents]),
                             np.stack([obs[agent]["game"] for agent in env.possible_agents]))
        out.append(([obs[agent]["detections"] for agent in env.possible_agents], previous, proprio))
    return out


def _model(head_mode="discrete"):
    torch.manual_seed(0)
    return DynEnvAgent(feature_size=32, head_mode=head_mode).eval()


def _batch(periods, size):
    """Each period's inputs for ``size`` robots, cycling the 4 real ones (different order per slot so the batch
    entries are not aligned copies)."""
    out = []
    for detections, previous, proprio in periods:
        index = [(i * 3 + i // 4) % 4 for i in range(size)]
        out.append(([detections[i] for i in index], previous[index], proprio[index]))
    return out


def _assert_same_over_periods(torch_policy, onnx_policy, inputs):
    B = len(inputs[0][0])
    state_t, state_o = torch_policy.initial_state(B), onnx_policy.initial_state(B)
    for detections, previous, proprio in inputs:
        landmarks, objects = collate(detections, max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS)
        assert landmarks.features.shape[1:3] == (FRAMES, MAX_LANDMARKS)
        a = torch_policy(landmarks, objects, previous, proprio, state_t)
        b = onnx_policy(landmarks, objects, previous, proprio, state_o)
        for field in FIELDS:
            x, y = getattr(a, field), getattr(b, field)
            assert x.shape == y.shape, field
            assert torch.allclose(x, y, atol=1e-5, rtol=0), (field, (x - y).abs().max().item())
        for x, y in zip(a.state, b.state):
            assert torch.allclose(x, y, atol=1e-5, rtol=0), (x - y).abs().max().item()
        state_t, state_o = a.state, b.state      # each runtime carries its own state, as a node would


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    path = tmp_path_factory.mktemp("onnx") / "policy.onnx"
    model = _model()
    export_onnx(model, path, frames=FRAMES, max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS)
    return model, path


@pytest.mark.parametrize("robots", [1, 10])
def test_onnxruntime_matches_torch_across_periods(exported, periods, robots):
    model, path = exported
    policy = OnnxPolicy(path)
    assert (policy.frames, policy.max_landmarks, policy.max_objects) == (FRAMES, MAX_LANDMARKS, MAX_OBJECTS)
    assert policy.head_mode == "discrete" and policy.feature_size == 32
    _assert_same_over_periods(TorchPolicy(model), policy, _batch(periods, robots))


def test_one_file_serves_changing_batch_sizes(exported, periods):
    model, path = exported
    policy = OnnxPolicy(path)
    for robots in (4, 1, 10, 4):
        _assert_same_over_periods(TorchPolicy(model), policy, _batch(periods[:1], robots))


def test_continuous_head(tmp_path, periods):
    model = _model("continuous")
    export_onnx(model, tmp_path / "continuous.onnx", frames=FRAMES, max_landmarks=MAX_LANDMARKS,
                max_objects=MAX_OBJECTS)
    policy = OnnxPolicy(tmp_path / "continuous.onnx")
    assert policy.head_mode == "continuous"
    _assert_same_over_periods(TorchPolicy(model), policy, _batch(periods, 4))
    landmarks, objects = collate(periods[0][0], max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS)
    step = policy(landmarks, objects, periods[0][1], periods[0][2], policy.initial_state(4))
    assert step.head.shape == (4, 2)
    assert model.act(step, greedy=True).shape == (4, 4)      # a PolicyStep goes wherever an AgentStep went


def test_empty_frames(exported, periods):
    model, path = exported
    empty = [np.zeros((0, FEATURES), np.float32)] * FRAMES
    only_ball = [np.zeros((0, FEATURES), np.float32)] * (FRAMES - 1) + [periods[0][0][0][-1][:1]]
    detections = [empty, periods[0][0][1], only_ball, empty]
    inputs = [(detections, previous, proprio) for _, previous, proprio in periods]
    _assert_same_over_periods(TorchPolicy(model), OnnxPolicy(path), inputs)
    _assert_same_over_periods(TorchPolicy(model), OnnxPolicy(path),
                              [([empty], previous[:1], torch.zeros(1, PROPRIOCEPTION)) for _, previous, _ in periods])


def test_export_leaves_no_temporary_file_and_keeps_the_model_mode(tmp_path):
    model = _model().train()
    export_onnx(model, tmp_path / "p.onnx", max_landmarks=8, max_objects=4)
    assert model.training
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.onnx"]


def test_other_slot_counts_are_fitted_and_other_frame_counts_refused(exported, periods):
    """Collated without maxima (fewer slots) or with larger ones, the ONNX policy gives what torch gives on the
    batch collated with the file's maxima; a different number of frames is refused clearly."""
    model, path = exported
    detections, previous, proprio = periods[0]
    # more than MAX_OBJECTS balls and robots in some frames, landmarks as seen
    crowded = [np.concatenate([rows] + [rows[rows[:, 0] <= 2]] * 6) for rows in detections[1]]
    batch = [detections[0], crowded, detections[2], detections[3]]
    reference = TorchPolicy(model)(*collate(batch, max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS),
                                   previous, proprio, model.initial_state(4))
    policy = OnnxPolicy(path)
    for maxima in ({}, {"max_landmarks": 96, "max_objects": 40}):
        landmarks, objects = collate(batch, **maxima)
        assert objects.features.shape[2] > MAX_OBJECTS and landmarks.features.shape[2] != MAX_LANDMARKS
        step = policy(landmarks, objects, previous, proprio, policy.initial_state(4))
        for field in FIELDS:
            assert torch.allclose(getattr(reference, field), getattr(step, field), atol=1e-5, rtol=0), field
    landmarks, objects = collate([frames[:3] for frames in batch], max_landmarks=MAX_LANDMARKS,
                                 max_objects=MAX_OBJECTS)
    with pytest.raises(ValueError, match="5 vision frames per period"):
        policy(landmarks, objects, previous, proprio, policy.initial_state(4))


def test_a_corrupt_or_missing_file_is_refused_clearly(exported, tmp_path):
    _, path = exported
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(path.read_bytes()[:1000])
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"this is not a protobuf \x00\xff" * 50)
    for bad in (truncated, garbage):
        with pytest.raises(ValueError, match="cannot be loaded"):
            OnnxPolicy(bad)
    with pytest.raises(ValueError, match="does not exist"):
        OnnxPolicy(tmp_path / "missing.onnx")


def test_a_foreign_onnx_file_is_refused(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "foreign",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    onnx.save(model, tmp_path / "foreign.onnx")
    with pytest.raises(ValueError, match="not a dynenv_policy_onnx"):
        OnnxPolicy(tmp_path / "foreign.onnx")


def test_full_frames_and_scattered_padding(exported, periods):
    """Slots filled to the maximum in one robot, few in another, and padding in the middle of a frame (the graph
    cuts only slots padded everywhere, wherever the real ones sit)."""
    model, path = exported
    detections = periods[0][0]
    crowded = [np.concatenate([rows] * 8)[: 3 * MAX_LANDMARKS] for rows in detections[1]]
    batch = [crowded, detections[0], detections[2], detections[3]]
    landmarks, objects = collate(batch, max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS)
    assert not landmarks.mask[0, :, -1].any()
    order = torch.randperm(MAX_LANDMARKS, generator=torch.Generator().manual_seed(3))
    scattered = type(landmarks)(landmarks.features[:, :, order], landmarks.kind[:, :, order],
                                landmarks.mask[:, :, order])
    for lm in (landmarks, scattered):
        state = model.initial_state(4)
        a = TorchPolicy(model)(lm, objects, periods[0][1], periods[0][2], state)
        b = OnnxPolicy(path)(lm, objects, periods[0][1], periods[0][2], state)
        for field in FIELDS:
            assert torch.allclose(getattr(a, field), getattr(b, field), atol=1e-5, rtol=0), field
    small = [detections[0]] + [[rows[:2] for rows in frames] for frames in detections[1:]]
    _assert_same_over_periods(TorchPolicy(model), OnnxPolicy(path), [(small, periods[0][1], periods[0][2])])


def test_carried_mask_matches_torch(exported, periods):
    """The RTA's mask rule (a slot stays valid once any frame of the period filled it) in the exported graph:
    periods whose last frame is empty, and slots filled only in the first frame, give what torch gives — and the
    empty last frame does not blank out what the earlier frames saw."""
    model, path = exported
    empty = np.zeros((0, FEATURES), np.float32)
    detections = periods[0][0]
    last_empty = list(detections[0][:-1]) + [empty]
    first_only = [detections[1][0]] + [empty] * (FRAMES - 1)
    shrinking = [detections[2][0]] + [rows[:1] for rows in detections[2][1:]]    # slots 1.. filled in frame 0 only
    batch = [last_empty, first_only, shrinking, detections[3]]
    inputs = [(batch, previous, proprio) for _, previous, proprio in periods]
    _assert_same_over_periods(TorchPolicy(model), OnnxPolicy(path), inputs)
    _, previous, proprio = periods[0]
    moved = [rows.copy() for rows in last_empty]
    for rows in moved[:-1]:
        rows[:, 1] += 0.5                                    # every earlier detection 0.5 m further ahead
    policy = OnnxPolicy(path)
    a = policy(*collate([last_empty], max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS), previous[:1],
               proprio[:1], policy.initial_state(1))
    b = policy(*collate([moved], max_landmarks=MAX_LANDMARKS, max_objects=MAX_OBJECTS), previous[:1],
               proprio[:1], policy.initial_state(1))
    assert (a.pose - b.pose).abs().max() > 1e-4 and (a.state[2] - b.state[2]).abs().max() > 1e-4


def _with_metadata(source, target, change):
    import onnx

    proto = onnx.load(str(source))
    entry = next(p for p in proto.metadata_props if p.key == "dynenv.policy")
    entry.value = change(entry.value)
    onnx.save(proto, str(target))
    return target


@pytest.mark.parametrize("overrides,message", [
    ({"frames": 3}, "does not match its own metadata: landmark_features"),
    ({"max_landmarks": 40}, "does not match its own metadata: landmark_features"),
    ({"max_objects": 5}, "does not match its own metadata: object_features"),
    ({"feature_size": 16}, "does not match its own metadata: h_loc"),
    ({"head_units": 2}, "does not match its own metadata: head"),
    ({"head_mode": "continuous", "head_units": None}, "does not match its own metadata: head"),
    ({"frames": 0}, "frames must be an integer in 1..64"),
    ({"max_objects": 10**6}, "max_objects must be an integer in 1..256"),
    ({"feature_size": True}, "feature_size must be an integer"),
    ({"head_units": 0}, "head_units must be an integer in 1..64"),
    ({"head_max": float("nan")}, "head_max must be a finite angle"),
    ({"head_max": 1e6}, "head_max must be a finite angle"),
])
def test_metadata_that_disagrees_with_the_graph_or_its_bounds_is_refused_on_load(exported, tmp_path, overrides,
                                                                                 message):
    import json

    _, path = exported
    bad = _with_metadata(path, tmp_path / "bad.onnx", lambda raw: json.dumps({**json.loads(raw), **overrides}))
    with pytest.raises(ValueError, match=message):
        OnnxPolicy(bad)


def test_unreadable_metadata_external_weights_and_nan_weights(exported, tmp_path):
    import onnx
    from onnx import numpy_helper

    _, path = exported
    with pytest.raises(ValueError, match="unreadable dynenv.policy metadata"):
        OnnxPolicy(_with_metadata(path, tmp_path / "junk.onnx", lambda raw: raw[:-5]))
    proto = onnx.load(str(path))
    onnx.save_model(proto, str(tmp_path / "external.onnx"), save_as_external_data=True, location="weights.bin",
                    size_threshold=0)
    with pytest.raises(ValueError, match="keeps weights in external files"):
        OnnxPolicy(tmp_path / "external.onnx")
    proto = onnx.load(str(path))
    tensor = next(t for t in proto.graph.initializer if numpy_helper.to_array(t).dtype == np.float32)
    array = numpy_helper.to_array(tensor).copy()
    array.flat[0] = np.nan
    tensor.CopyFrom(numpy_helper.from_array(array, tensor.name))
    onnx.save(proto, str(tmp_path / "nan.onnx"))
    assert OnnxPolicy(tmp_path / "nan.onnx").non_finite_weights() == [tensor.name]
    assert OnnxPolicy(path).non_finite_weights() == []       # the graph's own −inf mask constants are no fault
    model = _model()
    with torch.no_grad():
        model.kick_head.weight[1, 2] = float("inf")
    assert TorchPolicy(model).non_finite_weights() == ["kick_head.weight"]
