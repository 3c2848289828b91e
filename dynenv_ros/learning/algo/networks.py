"""The networks a run trains: the agent of its config (``make_agent``, the one place an agent for training is built:
the trainer, the rollout workers, the trainer node, learning from bags, pretraining, the evaluation of a checkpoint)
and, beside it in ``TrainingNetworks``, the paper's curiosity heads (ICM forward and inverse models, the RCM
attention, the LTP predictors and their attention), an optional intrinsic critic and the privileged pose seeder.
Only the policy network (``DynEnvAgent``) ships; the rest exist for training and are checkpointed with it.

The curiosity models' action input follows the agent's action heads (``action_heads``): soccer's one-hot walk, turn,
kick, head (5 + 3 + 3 + 7 = 18); driving's discrete one-hot acceleration and steering (3 + 3 = 6, as the paper);
driving's continuous action vector itself (the normalised [throttle, brake, steering / limit], 3 values), whose
inverse model regresses the 3 values (squared error) instead of classifying."""
from __future__ import annotations

import torch
from torch import Tensor, nn

from dynenv_ros.agent.losses import (ROBOCUP_HEADS, ForwardModel, InverseModel, LongTermPredictor, RCMAttention,
                                     one_hot_actions)
from dynenv_ros.agent.network import POSE_SIZE, DynEnvAgent
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.scenarios import scenario_of

def action_heads(agent: DynEnvAgent) -> tuple[tuple[int, ...], bool]:
    """(head sizes, continuous) of an agent's actions as the curiosity models take them: soccer (5, 3, 3, 7) and
    driving discrete (3, 3) one-hot; driving continuous (3,) the action vector as it is (continuous True)."""
    return scenario_of(agent).curiosity_heads(agent.action_mode or "discrete")


def action_features(actions: Tensor, heads: tuple[int, ...], continuous: bool) -> Tensor:
    """The curiosity models' action input of (…, H) stored actions: one-hot blocks, or the continuous vector."""
    return actions.float() if continuous else one_hot_actions(actions, heads)


class CuriosityHeads(nn.Module):
    """Forward model f(φ_t, a_t), inverse model g(φ_t, φ_{t+1}), the RCM attention W(φ_{t+1}), and the LTP chain
    with its own attention over the previous error (paper eqs. 1–6; docs/original.md §9.5 for the sizes: hidden 140)."""

    def __init__(self, feature_size: int, horizon: int, head_sizes: tuple[int, ...] = ROBOCUP_HEADS) -> None:
        super().__init__()
        action_size = sum(head_sizes)
        self.forward_model = ForwardModel(feature_size, action_size)
        self.inverse_model = InverseModel(feature_size, head_sizes)
        self.rcm_attention = RCMAttention(feature_size)
        self.ltp = LongTermPredictor(feature_size, action_size, horizon)
        self.ltp_attention = RCMAttention(feature_size)


class TrainingNetworks(nn.Module):
    """Everything the optimiser trains: the agent, the curiosity heads, an intrinsic critic (used only when
    curiosity is also an intrinsic reward) and the pose seeder (used only with privileged pose seeding)."""

    def __init__(self, agent: DynEnvAgent, horizon: int) -> None:
        super().__init__()
        phi = 2 * agent.feature_size
        self.agent = agent
        self.action_heads, self.continuous_actions = action_heads(agent)
        self.curiosity = CuriosityHeads(phi, horizon, self.action_heads)
        self.intrinsic_critic = nn.Sequential(nn.Linear(phi, agent.feature_size), nn.LeakyReLU(0.1),
                                              nn.Linear(agent.feature_size, 1))
        self.pose_seeder = nn.Linear(POSE_SIZE, agent.feature_size)

    def seeded_cell(self, pose: Tensor) -> Tensor:
        """The localization LSTM's cell state from a pose (DynEnv's ``set_state``: tanh of a linear map)."""
        return torch.tanh(self.pose_seeder(pose))

    def seeded_state(self, pose: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """DynEnv's privileged rollout start: every recurrent state zero except the localization cell, seeded
        from a (noisy) true pose — the object memory is wiped too, as there."""
        cell = self.seeded_cell(pose)
        zeros = torch.zeros_like(cell)
        return (zeros, cell, zeros.clone(), zeros.clone())


def make_agent(cfg: TrainConfig) -> DynEnvAgent:
    """The untrained agent a run of ``cfg`` trains (its scenario, width, head and action mode, and whether it takes
    the pose estimate: ``localization: estimate``)."""
    agent: DynEnvAgent = cfg.world.new_agent(cfg.feature_size, cfg.head_mode, cfg.action_mode, cfg.players_per_team,
                                             cfg.localization == "estimate")
    return agent
