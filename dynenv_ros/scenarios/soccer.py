"""RoboCup SPL soccer as a ``Scenario``: two teams of ``players_per_team`` robots (``team_a_0`` …), actions
[walk, turn, kick, head_yaw_delta rad], up to 5 vision frames per period, an optional self-localization input."""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import math

import numpy as np
import torch

from dynenv_ros.agent.export import SOCCER_FORMAT, check_policy
from dynenv_ros.agent.losses import ROBOCUP_HEADS
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
from dynenv_ros.envs.padded_layout import SOCCER as SOCCER_LAYOUT
from dynenv_ros.envs.padded_layout import LayoutSpec
from dynenv_ros.envs.pose_features import POSE_KEY
from dynenv_ros.envs.pose_messages import LOST_ROW
from dynenv_ros.envs.session import ActionSession
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.params import load_preset
from dynenv_ros.scenarios.base import Scenario
from dynenv_ros.soccer.agent_actions import behaviour_log_probs, sample_actions
from dynenv_ros.soccer.config import MotionConfig, SoccerConfig, robot_names
from dynenv_ros.soccer.world import SCENARIO_SOCCER

# The simulator refuses a head turn beyond this per period (docs/ros_graph.md): a policy must stay inside it.
HEAD_BOUND = MotionConfig().head_max_delta
STAND_STILL = (0, 0, 0, 0.0)


def uses_pose(policy: Any) -> bool:
    """Whether a policy takes the ``pose_estimate`` input: its torch model's ``uses_pose`` (absent, so False, in
    older checkpoints), or an ONNX file's input of that name."""
    own = getattr(policy, "uses_pose", None)        # TorchPolicy / OnnxPolicy say it themselves
    if isinstance(own, bool):
        return own
    model = getattr(policy, "model", None)
    if model is not None:
        return bool(getattr(model, "uses_pose", False))
    session = getattr(policy, "session", None)
    if session is not None:
        return any(i.name == POSE_KEY for i in session.get_inputs())
    return False


class SoccerScenario(Scenario):
    name = "soccer"
    aliases = ("robocup_v0",)          # the PettingZoo env's name
    parameter_value = "robocup"        # scenario:=robocup, TrainConfig scenario: robocup
    world_code = SCENARIO_SOCCER
    agent = "robot"
    agent_pattern = r"team_[ab]_[0-9]+"
    count_key = "players_per_team"
    picks_agents_with = "team"
    idle = STAND_STILL
    idle_words = "stand still"
    reset_options = ("kickoff_team",)
    default_frames = SoccerConfig().rates.frames_per_period
    legged = True
    team_frames = True
    settings_type = SoccerConfig
    layout_follows_settings = False
    headline_metric = "paper_metric"
    config_hint = "a soccer config (e.g. --config quick)"
    self_supervised = True
    sides = 2
    teachers = ("chaser", "eager_chaser", "perceiving")

    # -- the agent's and evaluation's questions (issue 40)
    policy_format = SOCCER_FORMAT

    def agent_names(self, count: int) -> list[str]:
        return robot_names(count)

    def settings(self, mapping: Mapping[str, Any]) -> SoccerConfig:
        return SoccerConfig.from_mapping(mapping)

    def agent_count(self, config: Any) -> int:
        return int(config.n_robots)

    def game_settings(self, count: int, action_mode: str) -> SoccerConfig:
        """A game's settings from a node's parameters (``action_mode`` is driving's)."""
        return SoccerConfig.from_mapping({"players_per_team": count})

    def describe(self, config: Any) -> str:
        return f"{config.players_per_team}v{config.players_per_team}"

    def perception(self, preset: str, **overrides: Any) -> Any:
        return load_preset(preset, **overrides)

    def make_session(self, config: Any, perception: Any, seed: int | None, missing_action: str,
                     controlled: Sequence[int] | None, localization: bool) -> ActionSession:
        return SoccerSession(config, perception, seed=seed, missing_action=missing_action,
                             controlled=None if controlled is None else list(controlled), localization=localization)

    def layout_spec(self, config: Any = None) -> LayoutSpec:
        return SOCCER_LAYOUT

    def action_fields(self, msg: Any) -> tuple[Any, ...]:
        return msg.walk, msg.turn, msg.kick, float(msg.head_yaw_delta)

    def message_fields(self, action: Sequence[float]) -> dict[str, Any]:
        return {"walk": int(action[0]), "turn": int(action[1]), "kick": int(action[2]),
                "head_yaw_delta": float(action[3])}

    def previous_action(self, action: Sequence[float]) -> tuple[Any, ...]:
        return (int(action[0]), int(action[1]), int(action[2]), float(action[3]))

    def choose(self, step: Any, policy: Any, generator: torch.Generator, greedy: bool, config: Any
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        actions, finite = sample_actions(step, policy.head_mode, policy.head_units, float(policy.head_max),
                                         generator, greedy)
        return actions, finite, actions

    def log_probs(self, step: Any, policy: Any, actions: np.ndarray, choices: np.ndarray) -> np.ndarray:
        return behaviour_log_probs(step, actions, policy.head_mode, policy.head_units, float(policy.head_max))

    def side_inputs(self, observation: Mapping[str, Any], policy: Any, spec: LayoutSpec, pose: bool
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self._side_inputs(observation, float(policy.head_max), pose)

    @staticmethod
    def _side_inputs(observation: Mapping[str, Any], head_max: float, pose: bool
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """A policy taking the pose gets the batch's ``pose_estimate`` appended (``side_inputs(..., pose=True)``)."""
        return side_inputs(observation, head_max, pose=True) if pose else side_inputs(observation, head_max)

    def takes_pose(self, policy: Any) -> bool:
        return uses_pose(policy)

    def trial_inputs(self, observation: dict[str, Any], policy: Any, spec: LayoutSpec) -> tuple[Any, ...]:
        """A new policy's trial batch from padded observations: run as robots that have lost their pose."""
        head_max = float(policy.head_max)
        if not math.isfinite(head_max) or head_max <= 0:
            head_max = 1.0            # check_policy refuses it with the reason; the trial inputs must stay finite
        pose = uses_pose(policy)
        if pose:
            observation[POSE_KEY] = np.tile(LOST_ROW, (len(observation["previous_action"]), 1))
        return (*streams_from_padded(observation), *self._side_inputs(observation, head_max, pose))

    def check_policy(self, policy: Any, trial: tuple[Any, ...], frames: int | None, config: Any) -> None:
        check_policy(policy, trial, HEAD_BOUND, frames)

    def new_agent(self, feature_size: int, head_mode: str, action_mode: str, players_per_team: int,
                  uses_pose: bool) -> DynEnvAgent:
        motion = SoccerConfig.from_mapping({"players_per_team": players_per_team, "head_mode": head_mode}).motion
        return DynEnvAgent(feature_size, head_mode, motion.head_units, motion.head_max_delta, uses_pose=uses_pose)

    def stored_action(self, action_mode: str) -> tuple[int, Any]:
        return len(ROBOCUP_HEADS), np.int64

    def curiosity_heads(self, action_mode: str) -> tuple[tuple[int, ...], bool]:
        return ROBOCUP_HEADS, False

    def categorical_heads(self, action_mode: str) -> tuple[str, ...]:
        return ("walk", "turn", "kick", "head")
