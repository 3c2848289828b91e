"""What a scenario offers the layers above the registry (``registry.Scenario`` is this protocol's base class).

The action codec's vocabulary: an *action* is what the simulator executes, in the ``dynenv_msgs/Action`` fields
the scenario uses (soccer [walk, turn, kick, head_yaw_delta rad], driving [throttle, brake, steering rad/s]); the
policy's *choices* are what its heads drew (soccer: the action itself; driving: acceleration and steering indices,
or the normalised command), kept for their log-probabilities.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import torch

from dynenv_ros.agent.export import PolicyFormat, check_scenario, policy_format
from dynenv_ros.envs.padded_layout import LayoutSpec
from dynenv_ros.envs.session import ActionSession


class Scenario:
    """One world's answers (module docstring). Subclasses set the class attributes and implement every method."""
    name: str                      # canonical: 'soccer', 'driving'
    aliases: tuple[str, ...]       # other spellings accepted on entry (parameters, configs, files, CLIs)
    parameter_value: str           # what the ROS parameter ``scenario`` and TrainConfig spell (kept: users type it)
    world_code: int                # WorldState.SCENARIO_*
    agent: str                     # 'robot', 'car': how logs and messages name one agent
    agent_pattern: str             # a regular expression matching every agent name
    count_key: str                 # the setting that says how many agents: 'players_per_team', 'n_cars'
    picks_agents_with: str         # the policy node's parameter choosing the agents it controls: 'team', 'cars'
    idle: tuple[float, ...]        # the fallback action, and the previous action an episode starts with
    idle_words: str                # what agents doing ``idle`` do, for logs: 'stand still', 'brake'
    reset_options: tuple[str, ...]  # what /sim/reset's options_yaml may set
    default_frames: int            # vision frames per period of the default settings
    legged: bool                   # agents with joints and falls (ros/sim_robot_io.py)
    team_frames: bool              # the team frames its localization outputs are in (ros/tf.py static_transforms)
    settings_type: type            # the scenario's settings class (what ``settings`` returns)
    layout_follows_settings: bool  # the padded layout depends on the game's settings (driving's steering limit): an
                                   # agent trained in a world reads that world's layout, not the defaults'
    headline_metric: str           # an evaluation's headline number ('paper_metric', 'total': dynenv_ros.evaluation)
    config_hint: str               # how to choose a training config of this scenario (dynenv-train's options)
    self_supervised: bool          # the worlds write self-supervised targets (true pose, objects) a loss can learn
    sides: int                     # the sides a world's agents form: soccer's two teams; driving's cars, one (all learn)
    teachers: tuple[str, ...]      # the teachers a training run of this scenario may imitate (TrainConfig.teacher)

    # -- the agent's and evaluation's questions (issue 40)
    policy_format: PolicyFormat    # its exported graph and policy kind (agent.export): the agent layer's row of it

    def evaluation_problem(self, model: Any) -> str:
        """Why dynenv-eval's games of this scenario cannot evaluate the agent ``model`` ('' if they can): it was
        built for another scenario (its ``scenario``; soccer where it has none)."""
        have = policy_format(getattr(model, "scenario", "soccer"))
        if have is self.policy_format:
            return ""
        return (f"is a {have.scenario} policy; {self.name} needs a policy trained with scenario: "
                f"{self.parameter_value} (evaluate it with --scenario {have.node_scenario})")

    def __repr__(self) -> str:
        return f"<scenario {self.name}>"

    # -- names and settings --------------------------------------------------------------------------------------
    def agent_names(self, count: int) -> list[str]:
        """The agents of a game with ``count`` (players per team, or cars), in id order."""
        raise NotImplementedError

    def settings(self, mapping: Mapping[str, Any]) -> Any:
        """The scenario's settings (``SoccerConfig``, ``DrivingConfig``) from a mapping; ValueError if bad."""
        raise NotImplementedError

    def agent_count(self, config: Any) -> int:
        """How many agents a game of the settings ``config`` has (both teams' robots, or the cars)."""
        raise NotImplementedError

    def game_settings(self, count: int, action_mode: str) -> Any:
        """A game's settings from a node's parameters: ``count`` agents (per team), driving's ``action_mode``."""
        raise NotImplementedError

    def describe(self, config: Any) -> str:
        """The game in a few words, for a start-up log line ('2v2', 'driving, 3 cars (discrete actions)')."""
        raise NotImplementedError

    def perception(self, preset: str, **overrides: Any) -> Any:
        """The perception parameters of a preset (``perception/presets``) with overrides."""
        raise NotImplementedError

    def make_session(self, config: Any, perception: Any, seed: int | None, missing_action: str,
                     controlled: Sequence[int] | None, localization: bool) -> ActionSession:
        """The world served to asynchronous controllers (``envs.session``); ``localization``: soccer's."""
        raise NotImplementedError

    def layout_spec(self, config: Any = None) -> LayoutSpec:
        """The padded layout (``envs.padded_layout``) of the scenario's observations (``config``: the settings it
        depends on; None: the defaults)."""
        raise NotImplementedError

    # -- the action codec ------------------------------------------------------------------------------------------
    def action_fields(self, msg: Any) -> tuple[Any, ...]:
        """The scenario's fields of an Action (read by attribute; the other scenario's are ignored)."""
        raise NotImplementedError

    def message_fields(self, action: Sequence[float]) -> dict[str, Any]:
        """The Action fields (name: value, typed as the message wants) of one action."""
        raise NotImplementedError

    def previous_action(self, action: Sequence[float]) -> tuple[Any, ...]:
        """An executed action as the next observation's previous action shows it."""
        raise NotImplementedError

    def choose(self, step: Any, policy: Any, generator: torch.Generator, greedy: bool, config: Any
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(actions (B, len(idle)), finite (B,), choices) of a policy's outputs ``step`` for B agents: sampled with
        ``generator`` (or the most likely, ``greedy``); a row whose outputs were not finite is False in ``finite``
        (its action is not to be used)."""
        raise NotImplementedError

    def log_probs(self, step: Any, policy: Any, actions: np.ndarray, choices: np.ndarray) -> np.ndarray:
        """(B,) log-probability of the choices ``choose`` made, as the learner scores them."""
        raise NotImplementedError

    def side_inputs(self, observation: Mapping[str, np.ndarray], policy: Any, spec: LayoutSpec, pose: bool
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(previous action encoding, self state) of a batch of padded observations for ``policy``."""
        raise NotImplementedError

    def takes_pose(self, policy: Any) -> bool:
        """Whether ``policy`` takes the self-localization estimate as an input."""
        raise NotImplementedError

    def trial_inputs(self, observation: dict[str, Any], policy: Any, spec: LayoutSpec) -> tuple[Any, ...]:
        """(static stream, dynamic stream, previous action, self state) of a new policy's trial decision."""
        raise NotImplementedError

    def check_kind(self, policy: Any, config: Any) -> None:
        """ValueError unless ``policy`` was built for this scenario and the game's settings ``config``
        (``agent.export.check_scenario``): checked before its trial inputs are built from its settings."""
        check_scenario(policy, self.name)

    def check_policy(self, policy: Any, trial: tuple[Any, ...], frames: int | None, config: Any) -> None:
        """ValueError with the first reason ``policy`` of the right kind (``check_kind``) must not act in a game of
        ``config`` (``agent.export``'s checks: finite weights, a trial decision on ``trial`` giving accepted
        actions)."""
        raise NotImplementedError

    # -- the experience adapter: what the trainer builds, stores and learns from ------------------------------------
    def new_agent(self, feature_size: int, head_mode: str, action_mode: str, players_per_team: int,
                  uses_pose: bool) -> Any:
        """The untrained ``DynEnvAgent`` of a training run (its width, soccer's head mode and pose input, driving's
        action mode)."""
        raise NotImplementedError

    def stored_action(self, action_mode: str) -> tuple[int, Any]:
        """(columns, dtype) of one action as rollouts store a policy's choices (``action_mode``: driving's)."""
        raise NotImplementedError

    def curiosity_heads(self, action_mode: str) -> tuple[tuple[int, ...], bool]:
        """(head sizes, continuous) of the actions as the curiosity models take them: one-hot blocks of these sizes,
        or (continuous) the action vector itself, of that one size."""
        raise NotImplementedError

    def categorical_heads(self, action_mode: str) -> tuple[str, ...]:
        """The policy's categorical action heads, by their output names, in stored-action column order; () when the
        actions are continuous (no most likely choice to compare with a teacher's)."""
        raise NotImplementedError

    def network_problem(self, config: Mapping[str, Any], action_mode: str) -> str:
        """Why a network of ``config`` (a policy file's ``config`` metadata) cannot play this scenario with the
        simulator's ``action_mode`` ('' if it can)."""
        have = config.get("scenario", "soccer")
        if have != self.policy_metadata_name():
            return f"it is a {have} policy and this node plays {self.policy_metadata_name()}"
        return ""

    def policy_metadata_name(self) -> str:
        """How a policy file's metadata names the scenario (``agent.export``: 'soccer', 'driving')."""
        return self.name
