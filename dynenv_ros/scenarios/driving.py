"""Urban driving as a ``Scenario``: ``n_cars`` cars (``car_0`` …), actions [throttle, brake, steering rad/s] (the
policy's discrete indices or normalised command turned into them, ``driving.agent_actions``), one frame per
period, no self-localization input."""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import torch

from dynenv_ros.agent.export import DRIVING_FORMAT, check_driving_policy, check_scenario
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
from dynenv_ros.driving import agent_actions
from dynenv_ros.driving.config import SCENARIO_DRIVING, DrivingConfig, car_names
from dynenv_ros.envs.driving_observations import driving_layout_spec
from dynenv_ros.envs.driving_session import DrivingSession
from dynenv_ros.envs.padded_layout import LayoutSpec
from dynenv_ros.envs.session import ActionSession
from dynenv_ros.perception.driving_params import load_driving_preset
from dynenv_ros.scenarios.base import Scenario


class DrivingScenario(Scenario):
    name = "driving"
    aliases = ()
    parameter_value = "driving"
    world_code = SCENARIO_DRIVING
    agent = "car"
    agent_pattern = r"car_[0-9]+"
    count_key = "n_cars"
    picks_agents_with = "cars"
    idle = agent_actions.BRAKE_COMMAND
    idle_words = "brake"
    reset_options = ()
    default_frames = 1
    legged = False
    team_frames = False
    settings_type = DrivingConfig
    layout_follows_settings = True
    headline_metric = "total"
    config_hint = "--config driving_quick or --set scenario=driving"
    self_supervised = False
    sides = 1
    teachers = ("scripted",)           # the scripted driver (driving.scripted.ScriptedDriver)

    # -- the agent's and evaluation's questions (issue 40)
    policy_format = DRIVING_FORMAT

    def agent_names(self, count: int) -> list[str]:
        return car_names(count)

    def settings(self, mapping: Mapping[str, Any]) -> DrivingConfig:
        return DrivingConfig.from_mapping(mapping)

    def agent_count(self, config: Any) -> int:
        return int(config.n_cars)

    def game_settings(self, count: int, action_mode: str) -> DrivingConfig:
        """A game's settings from a node's parameters."""
        return DrivingConfig(n_cars=count, action_mode=action_mode)

    def describe(self, config: Any) -> str:
        return f"driving, {config.n_cars} cars ({config.action_mode} actions)"

    def perception(self, preset: str, **overrides: Any) -> Any:
        return load_driving_preset(preset, **overrides)

    def network_problem(self, config: Mapping[str, Any], action_mode: str) -> str:
        problem = super().network_problem(config, action_mode)
        if not problem and config.get("action_mode") != action_mode:
            problem = (f"it is a {config.get('action_mode')} driving policy and the simulator's action_mode is "
                       f"{action_mode}")
        return problem

    def make_session(self, config: Any, perception: Any, seed: int | None, missing_action: str,
                     controlled: Sequence[int] | None, localization: bool) -> ActionSession:
        return DrivingSession(config, perception, seed=seed, missing_action=missing_action,
                              controlled=None if controlled is None else list(controlled))

    def layout_spec(self, config: Any = None) -> LayoutSpec:
        spec: LayoutSpec = driving_layout_spec(DrivingConfig() if config is None else config)
        return spec

    def action_fields(self, msg: Any) -> tuple[Any, ...]:
        return float(msg.throttle), float(msg.brake), float(msg.steering)

    def message_fields(self, action: Sequence[float]) -> dict[str, Any]:
        return {"throttle": float(action[0]), "brake": float(action[1]), "steering": float(action[2])}

    def previous_action(self, action: Sequence[float]) -> tuple[Any, ...]:
        return tuple(float(v) for v in action)

    def choose(self, step: Any, policy: Any, generator: torch.Generator, greedy: bool, config: Any
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        chosen, finite = agent_actions.sample_actions(step, policy.action_mode, generator, greedy)
        return agent_actions.commands(chosen, policy.action_mode, config.cars.max_yaw_rate), finite, chosen

    def log_probs(self, step: Any, policy: Any, actions: np.ndarray, choices: np.ndarray) -> np.ndarray:
        return agent_actions.log_probs(step, choices, policy.action_mode)

    def side_inputs(self, observation: Mapping[str, Any], policy: Any, spec: LayoutSpec, pose: bool
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        return side_inputs(observation, spec=spec)

    def takes_pose(self, policy: Any) -> bool:
        return False

    def trial_inputs(self, observation: dict[str, Any], policy: Any, spec: LayoutSpec) -> tuple[Any, ...]:
        """A new policy's trial batch from padded observations."""
        return (*streams_from_padded(observation, spec), *side_inputs(observation, spec=spec))

    def check_kind(self, policy: Any, config: Any) -> None:
        """Also of the simulator's action mode (a continuous policy's commands are refused by a discrete one)."""
        check_scenario(policy, self.name, config.action_mode)

    def check_policy(self, policy: Any, trial: tuple[Any, ...], frames: int | None, config: Any) -> None:
        check_driving_policy(policy, trial, config.cars.max_yaw_rate, frames)

    def new_agent(self, feature_size: int, head_mode: str, action_mode: str, players_per_team: int,
                  uses_pose: bool) -> DynEnvAgent:
        return DynEnvAgent(feature_size, scenario="driving", action_mode=action_mode)

    def stored_action(self, action_mode: str) -> tuple[int, Any]:
        return (2, np.int64) if action_mode == "discrete" else (agent_actions.CONTINUOUS_SIZE, np.float32)

    def curiosity_heads(self, action_mode: str) -> tuple[tuple[int, ...], bool]:
        if action_mode == "continuous":
            return (agent_actions.CONTINUOUS_SIZE,), True
        return (agent_actions.ACCELERATION_CHOICES, agent_actions.STEERING_CHOICES), False

    def categorical_heads(self, action_mode: str) -> tuple[str, ...]:
        return () if action_mode == "continuous" else ("acceleration", "steering")
