"""The policy's forward passes on padded observations: one acting step of many robots (``policy_step``, then
``sample_actions``), and a whole sequence per robot from a start state (``run_sequence``, then ``log_prob_entropy``):
what the rollouts act with and what the update re-runs.
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any, Mapping, cast

import numpy as np
import torch
from torch import Tensor

from dynenv_ros.agent.inputs import side_inputs, streams_from_padded, StreamBatch
from dynenv_ros.agent.network import DynEnvAgent, State
from dynenv_ros.envs.padded_layout import PROPRIOCEPTION_COLUMNS, SOCCER, LayoutSpec
from dynenv_ros.scenarios import scenario_of

FALLEN = PROPRIOCEPTION_COLUMNS.index("fallen")
PENALIZED = PROPRIOCEPTION_COLUMNS.index("penalized")


def can_act(proprioception: np.ndarray) -> np.ndarray:
    """(…, F, 4) proprioception → (…) bool: neither fallen nor penalized at the period's last frame."""
    last = proprioception[..., -1, :]
    return (last[..., FALLEN] < 0.5) & (last[..., PENALIZED] < 0.5)


def device_of(module: torch.nn.Module) -> torch.device:
    return next(module.parameters()).device


_DEFAULT_SPECS: dict[str, LayoutSpec] = {}     # scenario name: its layout of the default settings

def layout_spec(agent: Any) -> LayoutSpec:
    """The padded layout's spec an agent reads: soccer's, or driving's of the default ``DrivingConfig`` (its only
    config-dependent value is the steering limit, which scales the previous action; ``agent.layout_spec`` set by
    the trainer from its env overrides it)."""
    spec = getattr(agent, "layout_spec", None)
    if spec is not None:
        return cast(LayoutSpec, spec)
    world = scenario_of(agent)
    if world.name not in _DEFAULT_SPECS:
        _DEFAULT_SPECS[world.name] = world.layout_spec()
    return _DEFAULT_SPECS[world.name]


def action_width(agent: Any) -> tuple[int, Any]:
    """(columns, dtype) of one stored action: soccer 4 int64; driving discrete 2 int64, continuous 3 float32."""
    return scenario_of(agent).stored_action(getattr(agent, "action_mode", None) or "discrete")


def head_outputs(step: Any, steps: int | None = None, flat: bool = False) -> SimpleNamespace:
    """The action-head outputs of an acting step or a sequence (the fields ``agent.distributions`` reads): soccer's
    walk, turn, kick, head; driving's acceleration and steering, or command. ``steps``: keep the first T periods of a
    sequence; ``flat``: merge its (T, B) leading axes. Tensors stay on their device."""
    names = ("acceleration", "steering", "command") if getattr(step, "walk", None) is None else \
        ("walk", "turn", "kick", "head")
    out: dict[str, Tensor | None] = {}
    for name in names:
        value = getattr(step, name, None)
        if value is None:               # driving's heads of the other action mode
            out[name] = None
            continue
        if steps is not None:
            value = value[:steps]
        if flat:
            value = value.reshape(-1, *value.shape[2:])
        out[name] = value
    return SimpleNamespace(**out)


def _cpu(value: Tensor | None) -> Tensor | None:
    return None if value is None else value.cpu()


def policy_step(agent: DynEnvAgent, obs: Mapping[str, Any], state: State) -> Any:
    """One acting forward on padded observations with robots leading (numpy or torch), on the agent's device."""
    device = device_of(agent)
    spec = layout_spec(agent)
    landmarks, objects = streams_from_padded(obs, spec)
    previous, self_state = side_inputs(obs, agent.head_max, spec, pose=getattr(agent, "uses_pose", False))
    if device.type != "cpu":
        landmarks, objects = (type(b)(b.features.to(device), b.kind.to(device), b.mask.to(device))
                              for b in (landmarks, objects))
        previous, self_state = previous.to(device), self_state.to(device)
    return agent(landmarks, objects, previous, self_state, state)


def reset_state(state: State, starts: Tensor) -> State:
    """The state with the rows of robots starting an episode zeroed."""
    keep = (~starts.to(state[0].device)).to(state[0].dtype).unsqueeze(-1)
    return tuple(s * keep for s in state)  # type: ignore[return-value]


def sample_actions(agent: DynEnvAgent, step: Any, generator: torch.Generator | None, greedy: bool = False
                   ) -> tuple[Tensor, Tensor]:
    """(actions (B, 4) — driving (B, 2) or (B, 3) —, their log-probabilities (B,)) on the CPU — the sum over the
    action heads. Sampling is on the CPU whatever the learner's device, with one CPU generator: the draws are the
    same on any device, the actions only where the device's logits agree to the last bit (docs/benchmarks.md)."""
    heads: Any = SimpleNamespace(**{k: _cpu(v) for k, v in vars(head_outputs(step)).items()})
    actions = agent.act(heads, generator=generator, greedy=greedy)
    log_prob = cast(Tensor, sum(d.log_prob(a) for d, a in zip(agent.distributions(heads), actions.unbind(-1))))
    return actions, log_prob


def action_log_prob(agent: DynEnvAgent, step: Any, actions: Tensor) -> Tensor:
    """(B,) log-probability of given (B, 4) actions under an acting step's distributions, on the CPU."""
    heads: Any = SimpleNamespace(**{k: _cpu(v) for k, v in vars(head_outputs(step)).items()})
    return cast(Tensor, sum(d.log_prob(a) for d, a in zip(agent.distributions(heads), actions.unbind(-1))))


def _flat(x: Tensor) -> Tensor:
    return x.reshape(-1, *x.shape[2:])


def sequence_inputs(obs: Mapping[str, Tensor], head_max: float | None, spec: LayoutSpec = SOCCER,
                    pose: bool = False) -> tuple[StreamBatch, StreamBatch, Tensor, Tensor]:
    """The network's inputs for observations with (T, B) leading axes (``spec``: the layout's, soccer's default;
    ``pose``: the agent's ``uses_pose``)."""
    T, B = obs["game"].shape[:2]
    flat = {k: _flat(v) for k, v in obs.items()}
    previous, self_state = side_inputs(flat, head_max, spec, pose=pose)
    landmarks, objects = streams_from_padded(obs, spec)
    return landmarks, objects, previous.reshape(T, B, -1), self_state.reshape(T, B, -1)


def run_sequence(agent: Any, obs: Mapping[str, Tensor], state: tuple[Tensor, ...], starts: Tensor) -> Any:
    landmarks, objects, previous, self_state = sequence_inputs(obs, agent.head_max, layout_spec(agent),
                                                               getattr(agent, "uses_pose", False))
    return agent.forward_sequence(landmarks, objects, previous, self_state, state, starts)


def log_prob_entropy(agent: Any, out: Any, actions: Tensor) -> tuple[Tensor, Tensor]:
    """log π(a|s) and the policy entropy, each summed over the action heads; (T, B) inputs give (T, B)."""
    T, B = actions.shape[:2]
    step = head_outputs(out, flat=True)
    dists = agent.distributions(step)
    flat_actions = _flat(actions).unbind(-1)
    log_prob = sum(d.log_prob(a.float() if isinstance(d, torch.distributions.Normal) else a)
                   for d, a in zip(dists, flat_actions))
    entropy = sum(d.entropy() for d in dists)
    return log_prob.reshape(T, B), entropy.reshape(T, B)
