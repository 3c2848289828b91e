"""Observations → the network's inputs: padded tensors and masks per stream, batched over robots.

The one observation layout is ``dynenv_ros.envs.padded_layout`` (what ``robocup_v0(observation="padded")`` and the
vectorised batch return, and what the policy node builds from DetectionArray messages): ``streams_from_padded``
turns it into the two streams of the paper's encoder — landmarks (for localization) and dynamic objects (ball,
robots) — with tensor operations only, and ``side_inputs`` into the self-state and previous-action vectors.
``collate`` packs variable-length detection rows into that layout first. Padding is explicit (``mask`` True =
padded slot), so no detection, frame or batch entry ever needs special-casing downstream.

Both scenarios go through the same functions, read through the layout's ``LayoutSpec`` (``spec=``, soccer's by
default): the stream keys, the class embedding indices and the side inputs. ``agent_inputs(scenario)`` says what a
scenario's network takes (``AgentInputs``):

- **Class embedding indices, per scenario** (one table each, 0 = padding or a class the scenario does not have): the
  dynamic stream's classes first, then the static stream's, from 1. Soccer's table is exactly the one soccer
  checkpoints were trained with (BALL 1, ROBOT 2, GOALPOST 3 … CENTER_CIRCLE 7; 8 embedding blocks per stream);
  driving's is CAR 1, PEDESTRIAN 2, OBSTACLE 3, UNKNOWN 4, SELF 5, LANE 6 (7 blocks). Why tables, not one list with
  the driving classes appended: appending would give soccer's network 6 more blocks per stream (its parameter
  count, its seeded initialisation and every soccer checkpoint's strict load would change) and a driving network 8
  blocks it never uses; a network only ever sees one scenario's classes.
- **Previous action**: soccer's ``encode_previous_action`` (12 values); driving's ``encode_driving_action``: [throttle,
  brake, steering / the steering limit] (3 values in [−1, 1] / [0, 1] / [−1, 1]; the limit is the layout spec's
  previous-action bound), the command a discrete choice became included.
- **Self state**: soccer's last-frame proprioception (4) and the GameController's values scaled (3); driving's
  last-frame ego values scaled by ``DRIVING_EGO_SCALE`` (speed /10 m/s, yaw rate as is, destination /50 m, length
  and width /5 m, crashed and finished as is: 8) and the seconds remaining over a 60 s episode (1).
- **Pose estimate** (soccer, an agent with ``uses_pose``, trained with ``localization: estimate``):
  ``side_inputs(..., pose=True)`` appends the batch's ``pose_estimate`` (B, 7) (``envs.pose_features``: x, y,
  cos yaw, sin yaw, σx, σy, σyaw in the team frame) to the self state *as it is*, so the self state is (B, 14); the
  network scales it itself (``encode_pose``), which keeps an exported graph's ``pose_estimate`` input the raw row.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

import numpy as np
import torch

if TYPE_CHECKING:
    from numpy.typing import ArrayLike
    TensorLike = torch.Tensor | ArrayLike

from dynenv_ros.envs.padded_layout import (FEATURES, GAME_COLUMNS, LANDMARK_CLASSES, OBJECT_CLASSES,
                                           PROPRIOCEPTION_COLUMNS, SOCCER, LayoutSpec, PaddedLayout, pack_frames)
from dynenv_ros.envs.pose_features import POSE_COLUMNS, POSE_KEY

SCENARIOS = ("soccer", "driving")


def class_index(spec: LayoutSpec) -> dict[int, int]:
    """Embedding index of each class of a layout (one MLP per class): the dynamic stream's classes, then the static
    stream's, from 1; 0 is reserved for padding and classes the layout does not have."""
    return {int(c): i + 1 for i, c in enumerate(spec.streams[1].classes + spec.streams[0].classes)}


def _kind_table(index: Mapping[int, int]) -> torch.Tensor:
    # on the CPU explicitly: the cached table may first be built inside a torch.device("meta") context (a policy
    # file's model is constructed there before its weights are loaded)
    table = torch.zeros(256, dtype=torch.int64, device="cpu")
    for cls, position in index.items():
        table[cls] = position
    return table


DYNAMIC_CLASSES = OBJECT_CLASSES
# Soccer's table (what every soccer checkpoint was trained with): BALL 1, ROBOT 2, then the landmarks 3..7.
CLASS_INDEX = class_index(SOCCER)
assert CLASS_INDEX == {int(c): i + 1 for i, c in enumerate(DYNAMIC_CLASSES + LANDMARK_CLASSES)}
NUM_CLASSES = len(CLASS_INDEX) + 1
_KIND = _kind_table(CLASS_INDEX)
# The GameController's values reach the network scaled to about unit size: ownership relation as is, its seconds
# over a free kick's length, the game's seconds over a 10-minute half.
GAME_SCALE = torch.tensor([1.0, 1 / 10.0, 1 / 600.0])


@dataclass
class StreamBatch:
    """One stream's detections: ``features`` (B, F, N, FEATURES), ``kind`` (B, F, N) class embedding index,
    ``mask`` (B, F, N) True where padded."""
    features: torch.Tensor
    kind: torch.Tensor
    mask: torch.Tensor


def _as_tensor(value: TensorLike) -> torch.Tensor:
    return value if isinstance(value, torch.Tensor) else torch.from_numpy(np.asarray(value, np.float32))


def stream(features: TensorLike, valid: TensorLike, kind_table: torch.Tensor | None = None) -> StreamBatch:
    """One stream from padded rows (B, F, N, FEATURES) and a validity mask (B, F, N), 1 = a detection;
    ``kind_table``: the scenario's class → embedding index table (``AgentInputs.kind_table``; soccer's by default)."""
    features, valid = _as_tensor(features), _as_tensor(valid)
    table = (_KIND if kind_table is None else kind_table).to(features.device)     # the tables live on the CPU
    kind = table[features[..., 0].long().clamp(0, 255)]
    padded = valid < 0.5
    return StreamBatch(features, kind.masked_fill(padded, 0), padded)


def streams_from_padded(observation: Mapping[str, Any], spec: LayoutSpec = SOCCER
                        ) -> tuple[StreamBatch, StreamBatch]:
    """(static stream, dynamic stream) of a batch of padded observations (keys of the layout ``spec``, robots
    leading): soccer's (landmarks, objects), driving's (lanes with the SELF row, objects)."""
    table = agent_inputs(spec.scenario).kind_table
    (static, dynamic) = spec.streams
    return (stream(observation[static.key], observation[static.mask], table),
            stream(observation[dynamic.key], observation[dynamic.mask], table))


def side_inputs(observation: Mapping[str, Any], head_max: float | None = None, spec: LayoutSpec = SOCCER,
                pose: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """(previous action encoding (B, action_encoding), self state (B, self_state)) of padded observations: the
    period's last proprioception row and the game's values, scaled. ``head_max`` (soccer only): the head turn's
    bound; driving scales the steering by its layout spec's bound. ``pose`` (soccer, an agent's ``uses_pose``): the
    self state ends with the observation's ``pose_estimate`` row, unscaled (B, 7 more)."""
    action = _as_tensor(observation["previous_action"])
    proprioception = _as_tensor(observation["proprioception"])[:, -1]
    return agent_inputs(spec.scenario).side_inputs(action, proprioception, observation, head_max, spec, pose)


def _soccer_side_inputs(action: torch.Tensor, proprioception: torch.Tensor, observation: Mapping[str, Any],
                        head_max: float | None, spec: LayoutSpec, pose: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``side_inputs`` of soccer: the one-hot previous action and the head turn over ``head_max``; the self state,
    the pose estimate appended when ``pose``."""
    if head_max is None:
        raise ValueError("soccer's side inputs need head_max (the head turn's bound, rad per period)")
    previous = encode_previous_action(action[:, 0], action[:, 1], action[:, 2], action[:, 3], head_max)
    state = self_state(proprioception, observation["game"])
    if pose:
        state = torch.cat([state, pose_input(observation)], dim=-1)
    return previous, state


def _driving_side_inputs(action: torch.Tensor, proprioception: torch.Tensor, observation: Mapping[str, Any],
                         head_max: float | None, spec: LayoutSpec, pose: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``side_inputs`` of driving: the command with its steering over the spec's bound; the ego values and the
    seconds remaining. No pose estimate (``head_max`` does not apply)."""
    if pose:
        raise ValueError("the pose estimate is a soccer input; driving has none")
    return encode_driving_action(action, spec), driving_self_state(proprioception, observation["game"])


def pose_input(observation: Mapping[str, Any]) -> torch.Tensor:
    """The batch's ``pose_estimate`` (B, 7) float32, checked; ValueError naming the key when it is missing."""
    if POSE_KEY not in observation:
        raise ValueError(f"this agent takes the self-localization estimate (uses_pose): the batch needs "
                         f"{POSE_KEY!r} (B, {len(POSE_COLUMNS)}) float32, team frame (envs/pose_features.py); an env "
                         f"gives it with localization='estimate'")
    value = _as_tensor(observation[POSE_KEY]).float()
    if value.dim() != 2 or value.shape[-1] != len(POSE_COLUMNS):
        raise ValueError(f"{POSE_KEY} must be (B, {len(POSE_COLUMNS)}), got {tuple(value.shape)}")
    return value


# The pose estimate to about unit size inside the network: x and y over 5 m (a field half is 4.5 m long), the
# heading's cos and sin as they are, each σ as log(1 + σ / 0.1 m or rad) — 1 cm 0.1, 10 cm 0.7, 1 m 2.4, the bound
# 50 m 6.2 — so a lost robot's large σ stays within reach of the same weights as a tracking one's few centimetres.
POSE_INPUT = len(POSE_COLUMNS)
POSE_XY_SCALE = 1 / 5.0
POSE_STD_UNIT = 0.1


def encode_pose(pose: torch.Tensor) -> torch.Tensor:
    """(…, 7) ``pose_estimate`` rows → the network's scaled (…, 7) (constants above)."""
    return torch.cat([pose[..., :2] * POSE_XY_SCALE, pose[..., 2:4],
                      torch.log1p(pose[..., 4:].clamp(min=0.0) / POSE_STD_UNIT)], dim=-1)


def self_state(proprioception: TensorLike, game: TensorLike) -> torch.Tensor:
    """(B, SELF_STATE): the last frame's proprioception (B, 4) and the GameController's values (B, 3), scaled."""
    values = _as_tensor(game)
    return torch.cat([_as_tensor(proprioception), values * GAME_SCALE.to(values.device)], dim=-1)


def collate(observations: Sequence[Sequence[np.ndarray]], max_landmarks: int | None = None,
            max_objects: int | None = None, spec: LayoutSpec = SOCCER) -> tuple[StreamBatch, StreamBatch]:
    """(landmarks, dynamic objects) for a batch of robots; each observation is a sequence of frames, each frame a
    (k, FEATURES) float array of detection rows nearest first (``robocup_v0``'s ``obs["detections"]``). Packed
    into the padded layout — with the batch's own maxima where none are given; beyond a fixed maximum the
    farthest rows are dropped, as everywhere. ``spec``: the layout's (driving's: ``driving_layout_spec``)."""
    frames = [[np.asarray(rows, np.float32).reshape(-1, FEATURES) for rows in entry] for entry in observations]
    arrays, _ = pack_frames(PaddedLayout.fitting(frames, max_landmarks, max_objects, spec), frames)
    return streams_from_padded(arrays, spec)


def encode_previous_action(walk: torch.Tensor, turn: torch.Tensor, kick: torch.Tensor, head: torch.Tensor,
                           head_max: float) -> torch.Tensor:
    """(B, 12): one-hot walk (5), turn (3), kick (3) and the head turn scaled to [-1, 1] — every dimension kept
    (DynEnv folded both side steps into one value and dropped the kick, docs/original.md §12.16)."""
    return torch.cat([torch.nn.functional.one_hot(walk.long(), 5).float(),
                      torch.nn.functional.one_hot(turn.long(), 3).float(),
                      torch.nn.functional.one_hot(kick.long(), 3).float(),
                      (head.float() / head_max).unsqueeze(-1)], dim=-1)


ACTION_ENCODING = 12
PROPRIOCEPTION = len(PROPRIOCEPTION_COLUMNS) + len(GAME_COLUMNS)      # the network's self-state input

# Driving's ego values (``perception.driving_model.EGO_COLUMNS``: speed, yaw_rate, goal_x, goal_y, length, width,
# crashed, finished) to about unit size: m/s over a 10 m/s cruise, rad/s as is, the destination over 50 m, the outline
# over 5 m, flags as is; the seconds remaining over a 60 s episode.
DRIVING_EGO_SCALE = torch.tensor([0.1, 1.0, 0.02, 0.02, 0.2, 0.2, 1.0, 1.0])
DRIVING_GAME_SCALE = 1 / 60.0
DRIVING_ACTION_ENCODING = 3
DRIVING_SELF_STATE = len(DRIVING_EGO_SCALE) + 1


def encode_driving_action(action: TensorLike, spec: LayoutSpec) -> torch.Tensor:
    """(B, 3) of (B, 3) [throttle, brake, steering rad/s]: throttle and brake as they are, the steering over the
    layout's steering bound (``spec.action_high[2]``, ``cars.max_yaw_rate``)."""
    command = _as_tensor(action).float()
    scale = torch.tensor([1.0, 1.0, 1.0 / spec.action_high[2]], device=command.device)
    return command * scale


def driving_self_state(ego: TensorLike, game: TensorLike) -> torch.Tensor:
    """(B, 9): the last frame's ego values (B, 8) and the seconds remaining (B, 1), scaled."""
    values = _as_tensor(ego)
    return torch.cat([values * DRIVING_EGO_SCALE.to(values.device), _as_tensor(game) * DRIVING_GAME_SCALE], dim=-1)


# (previous action (B, k), last-frame proprioception (B, p), observation, head_max, spec, pose) -> (encoding, state)
SideInputs = Callable[[torch.Tensor, torch.Tensor, Mapping[str, Any], float | None, LayoutSpec, bool],
                      tuple[torch.Tensor, torch.Tensor]]


@dataclass(frozen=True)
class AgentInputs:
    """What a scenario's network takes: its class table (``kind_table`` (256,) class id → embedding index,
    ``num_classes`` embedding blocks per stream, padding's included), the width of its previous-action encoding and
    of its self state, its stream keys (static, dynamic), the name of its static stream's inputs in an exported
    graph (``<name>_features``…), the layout of the scenario's default settings and how ``side_inputs`` encodes
    its previous action and self state (from the batch's previous actions and last-frame proprioception)."""
    scenario: str
    class_index: dict[int, int]
    kind_table: torch.Tensor
    num_classes: int
    action_encoding: int
    self_state: int
    stream_keys: tuple[str, str]
    static_name: str
    spec: LayoutSpec
    side_inputs: SideInputs


def _driving_spec() -> LayoutSpec:
    from dynenv_ros.driving.config import DrivingConfig
    from dynenv_ros.envs.driving_observations import driving_layout_spec
    spec: LayoutSpec = driving_layout_spec(DrivingConfig())
    return spec


_AGENT_INPUTS: dict[str, AgentInputs] = {}


def agent_inputs(scenario: str) -> AgentInputs:
    """The ``AgentInputs`` of ``"soccer"`` or ``"driving"`` (driving's classes and widths do not depend on the
    config: its bounds only scale the steering, which ``side_inputs`` reads from the observation's spec)."""
    if scenario not in _AGENT_INPUTS:
        if scenario not in _INPUTS_OF:
            raise ValueError(f"scenario must be one of {SCENARIOS}, got {scenario!r}")
        _AGENT_INPUTS[scenario] = _INPUTS_OF[scenario]()
    return _AGENT_INPUTS[scenario]


def _soccer_inputs() -> AgentInputs:
    return AgentInputs("soccer", CLASS_INDEX, _KIND, NUM_CLASSES, ACTION_ENCODING, PROPRIOCEPTION,
                       ("landmarks", "objects"), "landmark", SOCCER, _soccer_side_inputs)


def _driving_inputs() -> AgentInputs:
    spec = _driving_spec()
    index = class_index(spec)
    return AgentInputs("driving", index, _kind_table(index), len(index) + 1, DRIVING_ACTION_ENCODING,
                       DRIVING_SELF_STATE, (spec.streams[0].key, spec.streams[1].key), "lane", spec,
                       _driving_side_inputs)


# Each scenario's inputs, by its name (the registry, dynenv_ros.scenarios, sits above this layer).
_INPUTS_OF = {"soccer": _soccer_inputs, "driving": _driving_inputs}
