"""The agent as an ONNX file, and two interchangeable runtimes (torch, onnxruntime) so a policy node can switch by a
parameter.

Why ONNX: a robot's decision must fit in a few milliseconds on one core; onnxruntime runs the small recurrent
network with far less per-call overhead than eager torch, and the file carries no Python code.

The exported graph takes explicit tensors (a ``StreamBatch`` is not an ONNX type) with a dynamic batch axis (the
robots) and fixed frame and detection axes (``collate`` with the same ``max_landmarks`` / ``max_objects`` gives
exactly those shapes). Inputs, in order:

==================  ==================  ========  ==========================================
name                shape               dtype     meaning
==================  ==================  ========  ==========================================
landmark_features   (B, F, N_l, 19)     float32   ``StreamBatch.features`` of the landmarks
landmark_kind       (B, F, N_l)         int64     class embedding index (0 = padding)
landmark_mask       (B, F, N_l)         bool      True = padded slot
object_features     (B, F, N_o, 19)     float32   same for ball and robots
object_kind         (B, F, N_o)         int64
object_mask         (B, F, N_o)         bool
previous_action     (B, 12)             float32   ``encode_previous_action``
proprioception      (B, 4)              float32
pose_estimate       (B, 7)              float32   only when the agent ``uses_pose``: the raw ``pose_estimate`` row
h_loc, c_loc        (B, D)              float32   localization LSTM state
h_obj, c_obj        (B, D)              float32   object LSTM state
==================  ==================  ========  ==========================================

``pose_estimate`` (``envs.pose_features``: x, y, cos yaw, sin yaw, σx, σy, σyaw in the team frame) is an input
only of a policy that takes the self-localization estimate (``DynEnvAgent.uses_pose``, trained with
``localization: estimate``); its metadata then says ``"uses_pose": true``. Both runtimes are called with the self
state that ``side_inputs(batch, head_max, pose=policy.uses_pose)`` builds — (B, 14), the pose appended —; the ONNX
runtime feeds its first 7 columns as ``proprioception`` and the last 7 as ``pose_estimate``.

Outputs: walk_logits (B, 5), turn_logits (B, 3), kick_logits (B, 3), head (B, 2·units+1 logits, or B, 2
[mean, log_std]), value (B,), pose (B, 6), then the next state h_loc', c_loc', h_obj', c_obj' (B, D) each.
Masks are ONNX ``bool`` tensors (numpy ``bool_``), the same type ``collate`` produces, so nothing is converted.

The model's configuration and the fixed shapes are stored as JSON under the metadata key ``dynenv.policy``, so the
onnxruntime side needs no checkpoint to know its head mode or the shapes it accepts. ``OnnxPolicy`` believes none of
it blindly: the file must be at most ``checkpoint.MAX_POLICY_BYTES``, hold its weights inside (no external data: a
file must not make the runtime read other files), have bounded metadata (``frames`` 1..``MAX_FRAMES``, maxima
1..``MAX_SLOTS``, the agent bounds of ``checkpoint``) and declare inputs and outputs whose names, types and fixed
sizes agree with that metadata — a file whose metadata lies is refused when loaded, not at its first decision.

``check_policy`` is what a policy node runs before it lets a policy act: settings a robot can execute, finite
weights, and a trial decision whose outputs are finite, of the right shapes, and give actions in the simulator's
accepted ranges. ``sample_actions`` is the one way both runtimes' outputs become actions.

**Driving** (``DynEnvAgent(scenario='driving')``): the same file format, one frame per period (``frames`` 1). Inputs
``lane_features``, ``lane_kind``, ``lane_mask`` (the static stream: the SELF row and the lanes, ``max_landmarks``
slots), ``object_*`` (cars, pedestrians, obstacles, UNKNOWN: ``max_objects`` slots), ``previous_action`` (B, 3)
(``encode_driving_action``), ``proprioception`` (B, 9) (``driving_self_state``) and the four states; outputs
``acceleration_logits``, ``steering_logits`` (B, 3) each (discrete) or ``command`` (B, 6) [mean × 3, log_std × 3]
(continuous), then ``value`` and the four next states — no pose. Both scenarios' metadata name their
``scenario`` (a file without it is soccer's), the ``layout`` (stream keys and classes, the proprioception, game and
previous-action columns) and the ``actions`` (heads and sizes; driving's ``action_mode``), so a policy node can
refuse a file of the other scenario with the reason before it acts. What differs between the two is each
scenario's ``PolicyFormat`` (``SOCCER_FORMAT``, ``DRIVING_FORMAT``; ``policy_format(name)``), which the registry's
``Scenario.policy_format`` points to.

The graph is the network's own forward pass, traced: it skips work on padded slots (trailing all-padded slots are
cut, each detection is embedded by its own class's block only) and computes the RTA's single-head attention in its
folded form (``network.SingleHeadAttention``), so it is a few hundred plain nodes. Outputs agree with the torch
model to float rounding (the tests hold them to 1e-5 over consecutive periods); 10 robots take ~1.5 ms on one core.
"""
from __future__ import annotations

import copy
import io
import json
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from dynenv_ros.agent.checkpoint import (MAX_FEATURE_SIZE, MAX_POLICY_BYTES, _bounded_int, check_file_size,
                                         check_head, non_finite_tensors)
from dynenv_ros.driving import agent_actions as driving_actions
from dynenv_ros.agent.inputs import POSE_INPUT, StreamBatch, agent_inputs
from dynenv_ros.agent.network import DynEnvAgent, State
from dynenv_ros.envs.padded_layout import FEATURES, MAX_FRAMES, MAX_SLOTS
from dynenv_ros.soccer.agent_actions import (KICK_CHOICES, TURN_CHOICES, WALK_CHOICES, action_problem,
                                             sample_actions)

INPUT_NAMES = ("landmark_features", "landmark_kind", "landmark_mask", "object_features", "object_kind",
               "object_mask", "previous_action", "proprioception", "h_loc", "c_loc", "h_obj", "c_obj")
OUTPUT_NAMES = ("walk_logits", "turn_logits", "kick_logits", "head", "value", "pose",
                "h_loc_out", "c_loc_out", "h_obj_out", "c_obj_out")
METADATA_KEY = "dynenv.policy"
FORMAT = "dynenv_policy_onnx/1"
STATE_NAMES = ("h_loc", "c_loc", "h_obj", "c_obj")
DRIVING_INPUT_NAMES = ("lane_features", "lane_kind", "lane_mask", "object_features", "object_kind", "object_mask",
                       "previous_action", "proprioception", *STATE_NAMES)
DRIVING_DEFAULT_MAXIMA = (11, 52)       # envs.driving_observations.default_maxima of the default 2-car config


POSE_INPUT_NAME = "pose_estimate"            # after proprioception, when the policy uses_pose


def io_names(scenario: str, action_mode: str | None = None, uses_pose: bool = False
             ) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(input names, output names) of a scenario's exported graph (module docstring): 'soccer' or 'driving'."""
    return policy_format(scenario).io_names(action_mode, uses_pose)


@dataclass
class PolicyStep:
    """What a policy node needs from one decision; the field names are those of ``AgentStep`` so the code that
    reads a step (``DynEnvAgent.act``/``distributions`` included) does not care which runtime produced it."""
    walk: torch.Tensor | None     # (B, 5) logits (soccer; None in driving, as turn, kick, head, pose)
    turn: torch.Tensor | None     # (B, 3)
    kick: torch.Tensor | None     # (B, 3)
    head: torch.Tensor | None     # (B, 2·units+1) logits, or (B, 2) [mean, log_std]
    value: torch.Tensor           # (B,)
    pose: torch.Tensor | None     # (B, 6)
    state: State
    acceleration: torch.Tensor | None = None    # driving, discrete: (B, 3) logits
    steering: torch.Tensor | None = None        # driving, discrete: (B, 3) logits
    command: torch.Tensor | None = None         # driving, continuous: (B, 6) [mean × 3, log_std × 3]


def _driving_step(outputs: list[torch.Tensor], action_mode: str) -> PolicyStep:
    """A driving graph's outputs (``io_names``' order) as a ``PolicyStep``."""
    heads = ({"acceleration": outputs[0], "steering": outputs[1]} if action_mode == "discrete"
             else {"command": outputs[0]})
    rest = outputs[len(heads):]
    return PolicyStep(None, None, None, None, rest[0], None, cast(State, tuple(rest[1:5])), **heads)


# -- each scenario's format ----------------------------------------------------------------------------------------
class PolicyFormat:
    """One scenario's exported graph (module docstring) and what its policies are checked against: the graph's
    input and output names and sizes, its default and accepted shapes, its metadata, how its outputs become a
    ``PolicyStep``, the action settings a runtime reads from the metadata and the simulator's settings it must
    match. ``policy_format(name)`` finds one; the registry's ``Scenario.policy_format`` is its scenario's."""
    scenario: str            # DynEnvAgent's ``scenario`` and the metadata's
    node_scenario: str       # how the nodes' ``scenario`` parameter spells it (``Scenario.parameter_value``)

    def __repr__(self) -> str:
        return f"<policy format {self.scenario}>"

    def io_names(self, action_mode: str | None, uses_pose: bool) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(input names, output names) of the graph of a policy with ``action_mode`` (driving's) and ``uses_pose``
        (soccer's)."""
        raise NotImplementedError

    def shapes(self, frames: int | None, max_landmarks: int | None, max_objects: int | None
               ) -> tuple[int, int, int]:
        """(frames, static slots, dynamic slots) of an export: the defaults where None; ValueError for a frame
        count the network cannot take."""
        raise NotImplementedError

    def graph_outputs(self, model: DynEnvAgent, step: Any) -> tuple[torch.Tensor, ...]:
        """The graph's outputs of the model's step, in ``io_names`` order."""
        raise NotImplementedError

    def metadata(self, model: DynEnvAgent, frames: int, max_landmarks: int, max_objects: int) -> dict[str, Any]:
        """The ``dynenv.policy`` metadata of the model's graph."""
        raise NotImplementedError

    def check_metadata(self, config: dict[str, Any]) -> None:
        """ValueError unless the scenario's part of a file's metadata is within its bounds (``check_onnx_config``
        checked the shared part)."""
        raise NotImplementedError

    def output_sizes(self, policy: OnnxPolicy) -> dict[str, tuple[int, ...]]:
        """Each action output's size after the robot axis (every output the scenario's graphs may declare)."""
        raise NotImplementedError

    def runtime_heads(self, config: dict[str, Any]) -> tuple[str | None, str | None, int | None, float | None]:
        """(action_mode, head_mode, head_units, head_max) of an ``OnnxPolicy`` from checked metadata: None where
        the setting is the other scenario's."""
        raise NotImplementedError

    def step(self, outputs: list[torch.Tensor], policy: OnnxPolicy) -> PolicyStep:
        """The graph's outputs (``io_names`` order) as a ``PolicyStep``."""
        raise NotImplementedError

    def mode_problem(self, policy: Any, action_mode: str | None) -> str:
        """Why a policy of this scenario must not act under the simulator's ``action_mode`` ('' if it may;
        ``check_scenario``)."""
        return ""


class SoccerFormat(PolicyFormat):
    scenario = "soccer"
    node_scenario = "robocup"

    def io_names(self, action_mode: str | None, uses_pose: bool) -> tuple[tuple[str, ...], tuple[str, ...]]:
        if uses_pose:
            at = INPUT_NAMES.index("proprioception") + 1
            return INPUT_NAMES[:at] + (POSE_INPUT_NAME,) + INPUT_NAMES[at:], OUTPUT_NAMES
        return INPUT_NAMES, OUTPUT_NAMES

    def shapes(self, frames: int | None, max_landmarks: int | None, max_objects: int | None
               ) -> tuple[int, int, int]:
        frames = 5 if frames is None else frames
        max_landmarks = 48 if max_landmarks is None else max_landmarks
        max_objects = 12 if max_objects is None else max_objects
        return frames, max_landmarks, max_objects

    def graph_outputs(self, model: DynEnvAgent, step: Any) -> tuple[torch.Tensor, ...]:
        return (step.walk, step.turn, step.kick, step.head, step.value, step.pose, *step.state)

    def metadata(self, model: DynEnvAgent, frames: int, max_landmarks: int, max_objects: int) -> dict[str, Any]:
        head_units = (model.head_head.out_features - 1) // 2 if model.head_mode == "discrete" else None
        return {"format": FORMAT, "feature_size": model.feature_size, "head_mode": model.head_mode,
                "head_units": head_units, "head_max": float(cast(float, model.head_max)), "frames": frames,
                "max_landmarks": max_landmarks, "max_objects": max_objects, "scenario": "soccer",
                "uses_pose": bool(getattr(model, "uses_pose", False)), "layout": _layout_metadata("soccer"),
                "actions": {"heads": {"walk": WALK_CHOICES, "turn": TURN_CHOICES, "kick": KICK_CHOICES,
                                      "head": 2 * head_units + 1 if head_units else 2}}}

    def check_metadata(self, config: dict[str, Any]) -> None:
        check_head(config.get("head_mode"), config.get("head_units"), config.get("head_max"))
        if not isinstance(config.get("uses_pose", False), bool):
            raise ValueError(f"uses_pose must be true or false, got {config['uses_pose']!r}")

    def output_sizes(self, policy: OnnxPolicy) -> dict[str, tuple[int, ...]]:
        head = 2 * cast(int, policy.head_units) + 1 if policy.head_mode == "discrete" else 2
        return {"walk_logits": (WALK_CHOICES,), "turn_logits": (TURN_CHOICES,), "kick_logits": (KICK_CHOICES,),
                "head": (head,), "pose": (6,)}

    def runtime_heads(self, config: dict[str, Any]) -> tuple[str | None, str | None, int | None, float | None]:
        head_mode = config["head_mode"]
        return None, head_mode, config["head_units"] if head_mode == "discrete" else None, float(config["head_max"])

    def step(self, outputs: list[torch.Tensor], policy: OnnxPolicy) -> PolicyStep:
        walk, turn, kick, head, value, pose = outputs[:6]
        return PolicyStep(walk, turn, kick, head, value, pose, (outputs[6], outputs[7], outputs[8], outputs[9]))


class DrivingFormat(PolicyFormat):
    scenario = "driving"
    node_scenario = "driving"

    def io_names(self, action_mode: str | None, uses_pose: bool) -> tuple[tuple[str, ...], tuple[str, ...]]:
        heads = (("acceleration_logits", "steering_logits") if action_mode == "discrete" else ("command",))
        return DRIVING_INPUT_NAMES, (*heads, "value", *(name + "_out" for name in STATE_NAMES))

    def shapes(self, frames: int | None, max_landmarks: int | None, max_objects: int | None
               ) -> tuple[int, int, int]:
        frames = 1 if frames is None else frames
        if frames != 1:
            raise ValueError(f"a driving policy takes one vision frame per period (no temporal attention), not {frames}")
        max_landmarks = DRIVING_DEFAULT_MAXIMA[0] if max_landmarks is None else max_landmarks
        max_objects = DRIVING_DEFAULT_MAXIMA[1] if max_objects is None else max_objects
        return frames, max_landmarks, max_objects

    def graph_outputs(self, model: DynEnvAgent, step: Any) -> tuple[torch.Tensor, ...]:
        heads = ((step.acceleration, step.steering) if model.action_mode == "discrete" else (step.command,))
        return (*heads, step.value, *step.state)

    def metadata(self, model: DynEnvAgent, frames: int, max_landmarks: int, max_objects: int) -> dict[str, Any]:
        heads = ({"acceleration": driving_actions.ACCELERATION_CHOICES, "steering": driving_actions.STEERING_CHOICES}
                 if model.action_mode == "discrete" else {"command": 2 * driving_actions.CONTINUOUS_SIZE})
        return {"format": FORMAT, "scenario": "driving", "feature_size": model.feature_size,
                "action_mode": model.action_mode, "frames": frames, "max_landmarks": max_landmarks,
                "max_objects": max_objects, "layout": _layout_metadata("driving"),
                "actions": {"mode": model.action_mode, "heads": heads,
                            "command": ["throttle", "brake", "steering"],
                            "continuous_low": list(driving_actions.CONTINUOUS_LOW),
                            "continuous_high": list(driving_actions.CONTINUOUS_HIGH)}}

    def check_metadata(self, config: dict[str, Any]) -> None:
        driving_actions.check_action_mode(config.get("action_mode"))
        if config.get("uses_pose", False) is not False:
            raise ValueError("uses_pose: the pose estimate is a soccer input; a driving policy has none")
        if config["frames"] != 1:
            raise ValueError(f"a driving policy takes 1 frame per period, the metadata says {config['frames']}")

    def output_sizes(self, policy: OnnxPolicy) -> dict[str, tuple[int, ...]]:
        return {"acceleration_logits": (driving_actions.ACCELERATION_CHOICES,),
                "steering_logits": (driving_actions.STEERING_CHOICES,),
                "command": (2 * driving_actions.CONTINUOUS_SIZE,)}

    def runtime_heads(self, config: dict[str, Any]) -> tuple[str | None, str | None, int | None, float | None]:
        return config["action_mode"], None, None, None

    def step(self, outputs: list[torch.Tensor], policy: OnnxPolicy) -> PolicyStep:
        return _driving_step(outputs, cast(str, policy.action_mode))

    def mode_problem(self, policy: Any, action_mode: str | None) -> str:
        if action_mode is not None and policy.action_mode != action_mode:
            return f"it is a {policy.action_mode} driving policy and the simulator's action_mode is {action_mode}"
        return ""


SOCCER_FORMAT = SoccerFormat()
DRIVING_FORMAT = DrivingFormat()
# Each scenario's format, by its name (the registry, dynenv_ros.scenarios, sits above this layer).
_FORMATS: dict[str, PolicyFormat] = {f.scenario: f for f in (SOCCER_FORMAT, DRIVING_FORMAT)}


def policy_format(scenario: Any) -> PolicyFormat:
    """The format of the scenario a policy (its ``scenario``) or a file's metadata names: 'soccer' or 'driving';
    ValueError otherwise."""
    if not isinstance(scenario, str) or scenario not in _FORMATS:
        raise ValueError(f"scenario must be 'soccer' or 'driving', got {scenario!r}")
    return _FORMATS[scenario]


class _ExportWrapper(nn.Module):
    """Explicit tensors in, a flat tuple out: the exporter cannot take dataclasses or nested tuples. Runs an eval
    copy of the model (the caller's is left as it is); the network's own forward code does everything — under the
    tracer it takes its graph-only paths (``network._tracing``): all-padded trailing slots cut (``network.trim``),
    each detection embedded by its own class's block only, the folded single-head attention — so its outputs are
    the model's."""

    def __init__(self, model: DynEnvAgent) -> None:
        super().__init__()
        self.model = copy.deepcopy(model).eval()

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The inputs in ``io_names`` order (``pose_estimate`` after ``proprioception`` when the model uses it)."""
        (landmark_features, landmark_kind, landmark_mask, object_features, object_kind, object_mask,
         previous_action, proprioception), rest = inputs[:8], inputs[8:]
        if getattr(self.model, "uses_pose", False):
            proprioception, rest = torch.cat([proprioception, rest[0]], dim=-1), rest[1:]
        step = self.model(StreamBatch(landmark_features, landmark_kind, landmark_mask),
                          StreamBatch(object_features, object_kind, object_mask),
                          previous_action, proprioception, tuple(rest))
        return policy_format(self.model.scenario).graph_outputs(self.model, step)


def _example_inputs(model: DynEnvAgent, batch: int, frames: int, max_landmarks: int, max_objects: int
                    ) -> tuple[torch.Tensor, ...]:
    """Inputs with a batch of 2 and a mixed mask (a batch of 1 risks a trace that bakes in a broadcast valid only
    for one robot: seen with ``nn.MultiheadAttention``, which the network no longer uses)."""
    generator = torch.Generator().manual_seed(0)
    inputs = agent_inputs(getattr(model, "scenario", "soccer"))

    def stream(n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        features = torch.randn(batch, frames, n, FEATURES, generator=generator)
        kind = torch.randint(1, inputs.num_classes, (batch, frames, n), generator=generator)
        mask = torch.rand(batch, frames, n, generator=generator) < 0.5
        return features, kind, mask

    D = model.feature_size
    pose = (torch.rand(batch, POSE_INPUT, generator=generator),) if getattr(model, "uses_pose", False) else ()
    return (*stream(max_landmarks), *stream(max_objects), torch.zeros(batch, inputs.action_encoding),
            torch.zeros(batch, inputs.self_state), *pose, *(torch.zeros(batch, D) for _ in range(4)))


def _layout_metadata(scenario: str) -> dict[str, Any]:
    """The layout a graph's inputs come from: stream keys and classes, the proprioception, game and previous-action
    columns (driving's bounds depend on the config and are not part of the network)."""
    spec = agent_inputs(scenario).spec
    return {"streams": [{"key": st.key, "mask": st.mask, "classes": list(st.classes)} for st in spec.streams],
            "proprioception": list(spec.proprioception_columns), "game": list(spec.game_columns),
            "previous_action": list(spec.action_columns),
            "class_index": {str(k): v for k, v in agent_inputs(scenario).class_index.items()}}


def _config(model: DynEnvAgent, frames: int, max_landmarks: int, max_objects: int) -> dict[str, Any]:
    return policy_format(getattr(model, "scenario", "soccer")).metadata(model, frames, max_landmarks, max_objects)


def export_onnx(model: DynEnvAgent, path: str | os.PathLike[str], *, frames: int | None = None,
                max_landmarks: int | None = None, max_objects: int | None = None, opset: int = 17) -> None:
    """Write ``model`` to ``path`` as ONNX (via ``path.tmp`` and a rename, so a failed export never leaves a
    half-written file where a node would load it). Uses the TorchScript exporter (``dynamo=False``): it needs only
    ``onnx`` and traces this network (Python loop over frames, data-dependent slot counts) without trouble. The
    caller's model is not modified, not even its train/eval mode. Defaults: soccer 5 frames, 48 landmark and 12
    object slots; driving 1 frame (the only count it takes), 11 lane and 52 object slots (``default_maxima`` of the
    default 2-car config: give ``max_objects`` for more cars)."""
    import onnx

    frames, max_landmarks, max_objects = policy_format(getattr(model, "scenario", "soccer")).shapes(
        frames, max_landmarks, max_objects)
    if frames < 1 or max_landmarks < 1 or max_objects < 1:
        raise ValueError("frames, max_landmarks and max_objects must be at least 1")
    input_names, output_names = io_names(getattr(model, "scenario", "soccer"), getattr(model, "action_mode", None),
                                         getattr(model, "uses_pose", False))
    target = Path(path)
    if not target.parent.is_dir():
        raise ValueError(f"cannot write {target}: folder {target.parent} does not exist")
    wrapper = _ExportWrapper(model).eval()
    example = _example_inputs(model, 2, frames, max_landmarks, max_objects)
    buffer = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        # Known and harmless: the legacy exporter's deprecation notice, Slice folding it skips, and tracer notes
        # from torch.nn.functional.
        warnings.filterwarnings("ignore", message="You are using the legacy TorchScript",
                                category=DeprecationWarning)
        warnings.filterwarnings("ignore", message="The feature will be removed", category=DeprecationWarning,
                                module=r"torch\.onnx")
        warnings.filterwarnings("ignore", message="Constant folding - Only steps=1", category=UserWarning)
        warnings.filterwarnings("ignore", category=torch.jit.TracerWarning, module=r"torch\.nn\.functional")
        torch.onnx.export(wrapper, example, buffer, dynamo=False, opset_version=opset,  # type: ignore[arg-type]
                          # (the stubs omit the file-like object torch.onnx.export writes to)
                          input_names=list(input_names), output_names=list(output_names),
                          dynamic_axes={name: {0: "robots"} for name in input_names + output_names},
                          do_constant_folding=True)
    proto = onnx.load_from_string(buffer.getvalue())
    entry = proto.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, json.dumps(_config(model, frames, max_landmarks, max_objects))
    onnx.checker.check_model(proto)
    tmp = target.with_name(target.name + ".tmp")
    try:
        with open(tmp, "wb") as handle:
            handle.write(proto.SerializeToString())
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


def _numpy(tensor: torch.Tensor | np.ndarray, dtype: type) -> np.ndarray:
    """Zero-copy where the tensor already has the right dtype and layout (``collate``'s output does)."""
    array = tensor.detach().numpy() if isinstance(tensor, torch.Tensor) else tensor
    return np.ascontiguousarray(array, dtype=dtype)


def _first_line(error: BaseException) -> str:
    return str(error).strip().splitlines()[0] if str(error).strip() else ""


def check_onnx_config(config: dict[str, Any]) -> None:
    """ValueError unless an ONNX file's metadata is within the bounds (module docstring)."""
    _bounded_int(config, "feature_size", 1, MAX_FEATURE_SIZE)
    _bounded_int(config, "frames", 1, MAX_FRAMES)
    _bounded_int(config, "max_landmarks", 1, MAX_SLOTS)
    _bounded_int(config, "max_objects", 1, MAX_SLOTS)
    policy_format(config.get("scenario", "soccer")).check_metadata(config)


def _non_finite_initializers(proto: Any) -> list[str]:
    """Initializers (the weights) with a NaN or an infinity, and Constant nodes with a NaN (the exported graph's
    own constants hold −inf legitimately: the attention's mask value)."""
    from onnx import numpy_helper

    bad = []
    for tensor in proto.graph.initializer:
        array = numpy_helper.to_array(tensor)
        if np.issubdtype(array.dtype, np.floating) and not np.isfinite(array).all():
            bad.append(tensor.name)
    for node in proto.graph.node:
        for attribute in node.attribute:
            if node.op_type == "Constant" and attribute.name == "value":
                array = numpy_helper.to_array(attribute.t)
                if np.issubdtype(array.dtype, np.floating) and np.isnan(array).any():
                    bad.append(node.output[0])
    return bad


def _signature_problem(session: Any, policy: "OnnxPolicy") -> str:
    """The first way the session's declared inputs/outputs disagree with the metadata ('' if none). Dimensions the
    file leaves symbolic are not checked here (the robot axis always is); the node's trial decision runs them."""
    F, L, O, D = policy.frames, policy.max_landmarks, policy.max_objects, policy.feature_size  # noqa: E741 - the paper's dimension letters
    input_names, output_names = io_names(policy.scenario, policy.action_mode, policy.uses_pose)
    widths = agent_inputs(policy.scenario)
    static = widths.static_name
    inputs = {f"{static}_features": ("float", (F, L, FEATURES)), f"{static}_kind": ("int64", (F, L)),
              f"{static}_mask": ("bool", (F, L)), "object_features": ("float", (F, O, FEATURES)),
              "object_kind": ("int64", (F, O)), "object_mask": ("bool", (F, O)),
              "previous_action": ("float", (widths.action_encoding,)),
              "proprioception": ("float", (widths.self_state,)), POSE_INPUT_NAME: ("float", (POSE_INPUT,)),
              **{name: ("float", (D,)) for name in STATE_NAMES}}
    outputs = policy.policy_format.output_sizes(policy)
    outputs.update({"value": (), **{name + "_out": (D,) for name in STATE_NAMES}})
    declared_in, declared_out = session.get_inputs(), session.get_outputs()
    if [i.name for i in declared_in] != list(input_names):
        return f"inputs {[i.name for i in declared_in]}, expected {list(input_names)}"
    if [o.name for o in declared_out] != list(output_names):
        return f"outputs {[o.name for o in declared_out]}, expected {list(output_names)}"
    checks = [(i, *inputs[i.name]) for i in declared_in] + [(o, "float", outputs[o.name]) for o in declared_out]
    for arg, dtype, dims in checks:
        if arg.type != f"tensor({dtype})":
            return f"{arg.name} is {arg.type}, expected tensor({dtype})"
        shape = arg.shape
        if shape is None:
            continue
        if len(shape) != 1 + len(dims):
            return f"{arg.name} has shape {shape}, expected (robots, {', '.join(map(str, dims))})"
        for have, want in zip(shape[1:], dims):
            if isinstance(have, int) and have != want:
                return f"{arg.name} has shape {shape}, the metadata implies (robots, {', '.join(map(str, dims))})"
    return ""


class OnnxPolicy:
    """onnxruntime on the CPU, ``threads`` intra-op threads (1: one robot process per core, no thread pool
    contention). Called like ``DynEnvAgent``; returns a ``PolicyStep`` of torch tensors (sharing numpy memory)."""

    def __init__(self, path: str | os.PathLike[str], threads: int = 1, data: bytes | None = None) -> None:
        """``data``: the file's bytes already read (and their signature checked: the policy node's LoadPolicy),
        so nothing is read from ``path`` again, which then only names the file in errors."""
        import onnx
        import onnxruntime as ort

        source = Path(path)
        if data is None:
            check_file_size(source, "ONNX policy")
        elif len(data) > MAX_POLICY_BYTES:
            raise ValueError(f"ONNX policy {source} is {len(data) / 2**20:.0f} MiB, more than the "
                             f"{MAX_POLICY_BYTES >> 20} MiB a policy may have")
        try:
            proto = (onnx.load(str(source), load_external_data=False) if data is None else
                     onnx.load_model_from_string(data))
        except Exception as error:    # protobuf's DecodeError, onnx's own errors
            raise ValueError(f"ONNX policy {source} cannot be loaded: {type(error).__name__}: "
                             f"{_first_line(error)}") from None
        if any(onnx.external_data_helper.uses_external_data(t) for t in proto.graph.initializer):
            raise ValueError(f"ONNX policy {source} keeps weights in external files; only self-contained files "
                             f"(what export_onnx writes) are loaded")
        self._non_finite = _non_finite_initializers(proto)
        del proto
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            self.session = ort.InferenceSession(str(source) if data is None else data, sess_options=options,
                                                providers=["CPUExecutionProvider"])
        except Exception as error:    # onnxruntime raises its own Fail/InvalidProtobuf/... types
            raise ValueError(f"ONNX policy {source} cannot be loaded: {type(error).__name__}: "
                             f"{_first_line(error)}") from None
        raw = self.session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
        try:
            config = json.loads(raw) if raw else {}
        except json.JSONDecodeError as error:
            raise ValueError(f"ONNX policy {source} has unreadable {METADATA_KEY} metadata: {error}") from None
        if not isinstance(config, dict) or config.get("format") != FORMAT:
            raise ValueError(f"ONNX policy {source} is not a {FORMAT} file (no dynenv metadata)")
        try:
            check_onnx_config(config)
        except ValueError as error:
            raise ValueError(f"ONNX policy {source} has bad {METADATA_KEY} metadata: {error}") from None
        self.config: dict[str, Any] = config
        self.feature_size: int = config["feature_size"]
        self.scenario: str = config.get("scenario", "soccer")
        self.policy_format = policy_format(self.scenario)
        self.uses_pose: bool = config.get("uses_pose", False)
        self.action_mode: str | None        # driving's; soccer's head below (None in the other scenario)
        self.head_mode: str | None
        self.head_units: int | None
        self.head_max: float | None
        self.action_mode, self.head_mode, self.head_units, self.head_max = self.policy_format.runtime_heads(config)
        self.frames: int = config["frames"]
        self.max_landmarks: int = config["max_landmarks"]
        self.max_objects: int = config["max_objects"]
        problem = _signature_problem(self.session, self)
        if problem:
            raise ValueError(f"ONNX policy {source} does not match its own metadata: {problem}")

    def non_finite_weights(self) -> list[str]:
        """Names of the initializers (and Constant nodes) holding a NaN or an infinity."""
        return list(self._non_finite)

    def initial_state(self, batch: int) -> State:
        zeros = torch.zeros(batch, self.feature_size)
        return (zeros, zeros.clone(), zeros.clone(), zeros.clone())

    def _stream(self, name: str, batch: StreamBatch, slots: int) -> dict[str, np.ndarray]:
        """The stream's three inputs at the file's fixed slot count. Fewer slots (``collate`` without maxima) are
        padded, which changes no output; more keep the first ``slots``, exactly what ``collate`` with the fixed
        maximum would have kept. A different frame or feature count is an error."""
        features = _numpy(batch.features, np.float32)
        kind, mask = _numpy(batch.kind, np.int64), _numpy(batch.mask, np.bool_)
        if features.ndim != 4 or features.shape[1] != self.frames or features.shape[3] != FEATURES:
            raise ValueError(f"{name}: features of shape {features.shape}; the exported policy takes (B, "
                             f"{self.frames}, ≤{slots}, {FEATURES}): {self.frames} vision frames per period")
        have = features.shape[2]
        if have > slots:
            features, kind, mask = features[:, :, :slots], kind[:, :, :slots], mask[:, :, :slots]
        elif have < slots:
            extra = ((0, 0), (0, 0), (0, slots - have))
            features = np.pad(features, extra + ((0, 0),))
            kind, mask = np.pad(kind, extra), np.pad(mask, extra, constant_values=True)
        return {f"{name}_features": np.ascontiguousarray(features), f"{name}_kind": np.ascontiguousarray(kind),
                f"{name}_mask": np.ascontiguousarray(mask)}

    def __call__(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                 proprioception: torch.Tensor, state: State) -> PolicyStep:
        static = agent_inputs(self.scenario).static_name
        self_state = _numpy(proprioception, np.float32)
        feeds = {**self._stream(static, landmarks, self.max_landmarks),
                 **self._stream("object", objects, self.max_objects),
                 "previous_action": _numpy(previous_action, np.float32)}
        if self.uses_pose:
            width = agent_inputs(self.scenario).self_state
            if self_state.ndim != 2 or self_state.shape[1] != width + POSE_INPUT:
                raise ValueError(f"self state of shape {self_state.shape}; this policy uses the pose estimate: "
                                 f"(B, {width + POSE_INPUT}) from side_inputs(batch, head_max, pose=True)")
            feeds["proprioception"] = np.ascontiguousarray(self_state[:, :width])
            feeds[POSE_INPUT_NAME] = np.ascontiguousarray(self_state[:, width:])
        else:
            feeds["proprioception"] = self_state
        for name, tensor in zip(STATE_NAMES, state):
            feeds[name] = _numpy(tensor, np.float32)
        out = [torch.from_numpy(array) for array in self.session.run(None, feeds)]
        return self.policy_format.step(out, self)


class TorchPolicy:
    """The torch model behind the same call as ``OnnxPolicy`` (no autograd graph is built: a node never trains).
    Puts the model in eval mode."""

    def __init__(self, model: DynEnvAgent) -> None:
        self.model = model.eval()
        self.scenario: str = getattr(model, "scenario", "soccer")
        self.uses_pose: bool = getattr(model, "uses_pose", False)
        self.action_mode: str | None = getattr(model, "action_mode", None)
        self.feature_size, self.head_mode, self.head_max = model.feature_size, model.head_mode, model.head_max
        self.head_units: int | None = ((model.head_head.out_features - 1) // 2 if model.head_mode == "discrete"
                                       else None)

    def non_finite_weights(self) -> list[str]:
        """Names of the weights holding a NaN or an infinity."""
        return non_finite_tensors(self.model.state_dict())

    def initial_state(self, batch: int) -> State:
        return self.model.initial_state(batch)

    def __call__(self, landmarks: StreamBatch, objects: StreamBatch, previous_action: torch.Tensor,
                 proprioception: torch.Tensor, state: State) -> PolicyStep:
        with torch.no_grad():
            step = self.model(landmarks, objects, previous_action, proprioception, state)
        return PolicyStep(step.walk, step.turn, step.kick, step.head, step.value, step.pose, step.state,
                          step.acceleration, step.steering, step.command)


# -- from outputs to actions, and the check before a policy may act ---------------------------------------------------
def _trial_decision(policy: Any, trial: tuple[StreamBatch, StreamBatch, torch.Tensor, torch.Tensor]
                    ) -> tuple[Any, int]:
    """The policy's decision on ``trial`` and its batch size B, after refusing non-finite weights; a failing
    decision is a ValueError. Shared by the soccer and driving checks, which then judge the outputs."""
    bad = policy.non_finite_weights()
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise ValueError(f"weight {bad[0]!r}{more} holds NaN or infinite values")
    static, objects, previous, proprio = trial  # static: soccer's landmarks, driving's static streams
    B = previous.shape[0]
    try:
        step = policy(static, objects, previous, proprio, policy.initial_state(B))
    except Exception as error:
        raise ValueError(f"its trial decision failed: {type(error).__name__}: {_first_line(error)}") from None
    return step, B


def _check_recurrent_state(step: Any, B: int, feature_size: int) -> None:
    """ValueError unless a trial decision's recurrent state is 4 tensors of shape (B, feature_size)."""
    state = [tuple(torch.as_tensor(s).shape) for s in step.state]
    if len(state) != 4 or any(s != (B, feature_size) for s in state):
        raise ValueError(f"its trial decision gave a recurrent state of shapes {state}, expected 4 x "
                         f"{(B, feature_size)}")


def check_policy(policy: Any, trial: tuple[StreamBatch, StreamBatch, torch.Tensor, torch.Tensor],
                 head_bound: float, frames: int | None = None) -> None:
    """ValueError with the first reason ``policy`` (``TorchPolicy`` or ``OnnxPolicy``) must not act: head settings a
    robot cannot execute (``head_max`` beyond ``head_bound``, the simulator's largest head turn per period), a
    fixed frame count other than the graph's ``frames`` (when known), non-finite weights, or a trial decision on
    ``trial`` (landmarks, objects, previous action, self state of B robots) that fails, gives outputs of the
    wrong shape or non-finite ones, or actions outside the accepted ranges (greedy and sampled). A driving policy
    is refused here (``check_scenario``); ``check_driving_policy`` checks those."""
    check_scenario(policy, "soccer")
    check_head(policy.head_mode, policy.head_units, policy.head_max)
    if policy.head_max > head_bound + 1e-6:
        raise ValueError(f"head_max {policy.head_max:.6g} rad is beyond the ±{head_bound:.4f} rad per period the "
                         f"simulator accepts")
    fixed = getattr(policy, "frames", None)
    if frames is not None and fixed is not None and fixed != frames:
        raise ValueError(f"it takes {fixed} vision frames per period, the detections arriving have {frames}")
    step, B = _trial_decision(policy, trial)
    head = 2 * policy.head_units + 1 if policy.head_mode == "discrete" else 2
    shapes = {"walk": (B, WALK_CHOICES), "turn": (B, TURN_CHOICES), "kick": (B, KICK_CHOICES), "head": (B, head)}
    for name, shape in shapes.items():
        have = tuple(torch.as_tensor(getattr(step, name)).shape)
        if have != shape:
            raise ValueError(f"its trial decision gave {name} of shape {have}, expected {shape}")
    _check_recurrent_state(step, B, policy.feature_size)
    for greedy in (True, False):
        actions, finite = sample_actions(step, policy.head_mode, policy.head_units, policy.head_max,
                                         torch.Generator().manual_seed(0), greedy)
        if not finite.all():
            raise ValueError("its trial decision gave NaN or infinite outputs")
        for action in actions:
            problem = action_problem(action, head_bound)
            if problem:
                raise ValueError(f"its trial decision gave an action the simulator refuses: {problem}")


def check_scenario(policy: Any, scenario: str, action_mode: str | None = None) -> None:
    """ValueError unless ``policy`` was built for ``scenario`` ('soccer' or 'driving'; a policy node's ``robocup``
    is soccer) and, in driving, for the simulator's ``action_mode`` (a continuous policy's commands are refused by a
    discrete simulator; a discrete policy would act but learn about actions it cannot take under the other mode)."""
    want = next((f for f in _FORMATS.values() if scenario in (f.scenario, f.node_scenario)), None)
    if want is None:
        raise ValueError(f"scenario must be 'soccer' (a node's 'robocup') or 'driving', got {scenario!r}")
    have = policy_format(getattr(policy, "scenario", "soccer"))
    if have is not want:
        raise ValueError(f"it is a {have.scenario} policy and this node plays {want.scenario} (its observations, "
                         f"classes and actions differ); load a {want.scenario} policy or start the node with "
                         f"scenario {have.node_scenario}")
    problem = want.mode_problem(policy, action_mode)
    if problem:
        raise ValueError(problem)


def check_driving_policy(policy: Any, trial: tuple[StreamBatch, StreamBatch, torch.Tensor, torch.Tensor],
                         max_yaw_rate: float, frames: int | None = None) -> None:
    """``check_policy`` for a driving policy: a known action mode, one frame per period (the graph's and the
    detections'), finite weights, and a trial decision on ``trial`` whose outputs have the right shapes, are finite
    and give commands (greedy and sampled) the simulator accepts with steering limit ``max_yaw_rate``."""
    driving_actions.check_action_mode(policy.action_mode)
    fixed = getattr(policy, "frames", None)
    if fixed is not None and fixed != 1:
        raise ValueError(f"it takes {fixed} vision frames per period; a driving policy takes 1")
    if frames is not None and frames != 1:
        raise ValueError(f"the detections arriving have {frames} frames per period; a driving policy takes 1")
    step, B = _trial_decision(policy, trial)
    for name, shape in driving_actions.output_shapes(policy.action_mode, B).items():
        have = tuple(torch.as_tensor(getattr(step, name)).shape) if getattr(step, name) is not None else None
        if have != shape:
            raise ValueError(f"its trial decision gave {name} of shape {have}, expected {shape}")
    _check_recurrent_state(step, B, policy.feature_size)
    for greedy in (True, False):
        actions, finite = driving_actions.sample_actions(step, policy.action_mode, torch.Generator().manual_seed(0),
                                                         greedy)
        if not finite.all():
            raise ValueError("its trial decision gave NaN or infinite outputs")
        for command in driving_actions.commands(actions, policy.action_mode, max_yaw_rate):
            problem = driving_actions.command_problem(command, policy.action_mode, max_yaw_rate)
            if problem:
                raise ValueError(f"its trial decision gave a command the simulator refuses: {problem}")
