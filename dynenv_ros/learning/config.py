"""The typed training configuration: one frozen dataclass, checked on construction, loaded from a YAML preset plus
``--set key=value`` overrides, and round-tripped through JSON for checkpoint metadata.

Paper values are those of the DynEnv paper's Table 1 (A2C). Every field carries its help text in
``dataclasses.field(metadata={"help": ...})`` (see ``field_help()``), so a CLI can print it.

Errors are ``ConfigError`` (a ``ValueError``) with ``.key`` the offending field and a message that starts with it.

Rules worth knowing:

* Integers are integers: ``True`` is not an int here, and ``2.0`` or ``"2"`` is refused for an int field. Float
  fields accept ints (stored as floats). YAML ``1e-4`` (no dot) reads as a float, unlike plain PyYAML.
* ``variant`` picks the paper row (see ``Losses``/``TrainConfig.losses``); ``use_localization`` and
  ``use_reconstruction`` (None = from the variant) switch those two self-supervised losses on or off on any row.
* ``variant: recon`` REQUIRES ``pretrained_encoder`` (the paper's recon row is defined by the pretrained
  reconstruction encoder). To train localization + reconstruction from scratch, use ``variant: pred`` with
  ``use_localization: true`` and ``use_reconstruction: true``. The path's existence is checked by the trainer when it
  loads it, not here (a config read back from a checkpoint may name a file of another machine).
* ``scenario: driving`` trains the driving agent (``DynEnvAgent(scenario='driving', action_mode)``) on
  ``DrivingVectorEnv`` with ``n_cars`` cars per world, every car learning with the shared network. Its teacher is
  ``scripted`` (the scripted driver; soccer's is ``chaser``), without teacher-driven worlds. Soccer-only settings
  are refused there with the key named: ``teacher: chaser``, ``teacher_driven_worlds``, ``opponent`` other than
  ``self``, ``variant: recon``, ``use_localization`` / ``use_reconstruction``, ``pretrained_encoder``,
  ``privileged_pose_seeding`` (driving has no learning targets: no pose, no reconstruction), ``localization:
  estimate`` (no self-localization). ``action_mode`` and
  ``n_cars`` other than their defaults are refused for ``scenario: robocup``.
* ``ltp_horizon <= rollout_length`` is required only when the LTP loss is on; ``ppo_minibatches`` may not exceed
  the number of learning robot sequences (``learning_robots``) only when ``algorithm`` is ppo.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import yaml

from dynenv_ros.envs.league import LEAGUE_MEMBERS
from dynenv_ros.learning.curriculum import CurriculumError, CurriculumStage, parse_curriculum, stage_at

if TYPE_CHECKING:        # the registry is imported where a config's scenario is asked (it loads torch)
    from dynenv_ros.scenarios import Scenario

ALGORITHMS = ("a2c", "ppo")
VARIANTS = ("baseline", "icm", "rcm", "pred", "recon")
OPPONENTS = ("self", "snapshot", "scripted", "perceiving", "league", "random")
BACKENDS = ("auto", "inprocess", "subprocess", "ray")
RUNNERS = ("sync", "async")
INFERENCES = ("worker", "server")                   # runner async: where the acting forward runs
# one shared network has no slot input, so it cannot imitate a keeper in one slot: chasers only ('perceiving': the
# chaser on the robot's own observation and pose estimate, soccer.perceiving)
HEAD_MODES = ("discrete", "continuous")
PERCEPTIONS = ("realistic", "dynenv", "none")        # the presets of dynenv_ros.perception (config/perception/)
LOCALIZATIONS = ("none", "estimate")                # envs.soccer_observations.LOCALIZATION_OPTIONS
SCENARIOS = ("robocup", "driving")
ACTION_MODES = ("discrete", "continuous")           # driving's actor heads (driving/agent_actions.py)
MAX_CARS = 10
MAX_PLAYERS_PER_TEAM = 5
_DEVICE = re.compile(r"^(cpu|cuda(:\d+)?|mps)$")

# Bounds of every size setting, inclusive, checked first when a config is validated (before anything is allocated:
# a world, a network, a rollout buffer). Whether a run inside them fits this machine's memory and cores is
# learning/resources.py's check_machine, where the run starts. docs/training.md "Bounds" lists them.
SIZE_BOUNDS: dict[str, tuple[int, int]] = {
    "num_envs": (1, 1024),              # worlds per run (paper: 8)
    "players_per_team": (1, MAX_PLAYERS_PER_TEAM),
    "n_cars": (1, MAX_CARS),
    "feature_size": (1, 1024),          # the streams' width D (paper: 64); weights grow with D squared
    "rollout_length": (1, 1024),        # motion periods per rollout (paper: 6)
    "ltp_horizon": (1, 1024),           # and at most rollout_length when the LTP loss is on
    "ppo_epochs": (1, 100),
    "ppo_minibatches": (1, 4096),       # and at most learning_robots under ppo
    "rollouts_per_update": (1, 64),
    "workers": (1, 256),                # and at most num_envs (null: one per core)
    "torch_threads": (1, 256),
    "snapshot_pool": (1, 100),
    "keep_checkpoints": (1, 100),
    "best_policy_window": (1, 100_000),
    "keep_policy_every_env_steps": (1, 10**12),
}


class ConfigError(ValueError):
    """A training setting is unknown, of the wrong type or impossible; ``key`` names it."""

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"{key}: {reason}")
        self.key = key
        self.reason = reason


@dataclass(frozen=True)
class Losses:
    """Which losses a run trains besides the actor-critic loss (a paper row, possibly with overrides)."""
    icm_forward: bool      # ICM's plain forward model: predict φ(s_{t+1}) from φ(s_t) and a_t (weight forward_coef)
    inverse: bool          # inverse model: predict a_t from φ(s_t), φ(s_{t+1}) (weight inverse_coef)
    rcm_attention: bool    # RCM's forward model, its error weighted by the attention confidences (forward_coef)
    ltp: bool              # long-term prediction over ltp_horizon periods (weight ltp_coef)
    localization: bool     # pose regression of the localization stream (weight self_supervised_coef)
    reconstruction: bool   # object reconstruction from the object stream (weight self_supervised_coef)

    @property
    def forward(self) -> bool:
        """A forward model (plain or attention-weighted) is trained: curiosity can be an intrinsic reward."""
        return self.icm_forward or self.rcm_attention

    @property
    def curiosity(self) -> bool:
        return self.forward or self.inverse or self.ltp

    def as_dict(self) -> dict[str, bool]:
        return dataclasses.asdict(self)


# The paper's rows (before use_localization/use_reconstruction overrides).
VARIANT_LOSSES: dict[str, Losses] = {
    # vanilla A2C/PPO: no curiosity, no self-supervision
    "baseline": Losses(icm_forward=False, inverse=False, rcm_attention=False, ltp=False, localization=False,
                       reconstruction=False),
    # ICM: forward + inverse
    "icm": Losses(icm_forward=True, inverse=True, rcm_attention=False, ltp=False, localization=False,
                  reconstruction=False),
    # RCM: attention-weighted forward + inverse
    "rcm": Losses(icm_forward=False, inverse=True, rcm_attention=True, ltp=False, localization=False,
                  reconstruction=False),
    # pred: RCM + long-term prediction
    "pred": Losses(icm_forward=False, inverse=True, rcm_attention=True, ltp=True, localization=False,
                   reconstruction=False),
    # recon: pred + localization + reconstruction, starting from the pretrained reconstruction encoder
    "recon": Losses(icm_forward=False, inverse=True, rcm_attention=True, ltp=True, localization=True,
                    reconstruction=True),
}


def _f(default: Any, help: str) -> Any:       # noqa: A002 - "help" reads best at the call sites
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs, checked on construction (``ConfigError`` on anything wrong)."""

    # -- what is trained ---------------------------------------------------------------------------------------
    algorithm: str = _f("a2c", "Policy-gradient algorithm: 'a2c' (paper) or 'ppo'.")
    variant: str = _f("pred", "Paper row: 'baseline' (no curiosity), 'icm' (forward + inverse), 'rcm' "
                              "(attention-weighted forward + inverse), 'pred' (RCM + LTP, paper's best), "
                              "'recon' (pred + localization + reconstruction from the pretrained encoder; needs "
                              "pretrained_encoder).")
    use_localization: bool | None = _f(None, "Override: train the localization (pose) loss; null = as the variant.")
    use_reconstruction: bool | None = _f(None, "Override: train the object reconstruction loss; null = as the "
                                               "variant.")

    # -- environment -------------------------------------------------------------------------------------------
    scenario: str = _f("robocup", "World: 'robocup' (2 teams of players_per_team robots) or 'driving' (n_cars cars, "
                                  "every car learning; docs/training.md 'Driving').")
    n_cars: int = _f(2, f"Driving: cars per world, 1..{MAX_CARS} (paper: 2).")
    action_mode: str = _f("discrete", "Driving: 'discrete' (two categorical heads [3, 3], paper) or 'continuous' "
                                      "(a clipped 3-d Gaussian over [throttle, brake, steering / limit]).")
    players_per_team: int = _f(2, f"Robots per team, 1..{MAX_PLAYERS_PER_TEAM} (paper: 2, i.e. 2v2).")
    team_sizes: tuple | None = _f(None, "runner async, soccer: robots per team, e.g. [2, 5]: rollout worker i plays "
                                        "size i mod len (so at least one worker per size), the objects padded to the "
                                        "largest size, so one network learns every size; must hold "
                                        "players_per_team; null = players_per_team only.")
    num_envs: int = _f(8, "Parallel worlds, 1..1024 (paper: 8).")
    perception: str = _f("realistic", f"Perception preset: one of {PERCEPTIONS}.")
    localization: str = _f("none", "Self-localization as an input: 'none' (paper) or 'estimate' (the worlds run the "
                                   "emulated localization, the observations carry pose_estimate (7 values, team "
                                   "frame: envs/pose_features.py) and the agent takes it as an input beside its "
                                   "self state; checkpoints record it as uses_pose). Not use_localization, which "
                                   "is the pose-regression loss.")
    backend: str = _f("auto", "Vector env backend: 'auto' (worker processes for many worlds), 'inprocess', "
                              "'subprocess'.")

    # -- schedule ----------------------------------------------------------------------------------------------
    rollout_length: int = _f(6, "Motion periods per rollout and world before each update, 1..1024 (paper: 6).")
    total_env_steps: int = _f(2_000_000, "Stop after this many env steps; one env step = one motion period of one "
                                         "world (paper: 60,000 updates x 8 worlds x 6 = 2,880,000).")
    max_minutes: float | None = _f(None, "Stop (and checkpoint) after this much wall time in minutes; null = no "
                                         "limit.")

    episode_seconds: float | None = _f(None, "Episode length in seconds; null = the world's own (soccer 120, driving "
                                             "60). Shorter episodes make curricula and small test tasks.")
    curriculum: tuple[CurriculumStage, ...] | None = _f(
        None, "Soccer: how training episodes start, stage by stage (docs/training.md, 'A curriculum of start "
              "states'): a list of {until: env steps at which the stage ends (left out on the last, which lasts to "
              "the run's end), start: kickoff | attack, ball_distance: [min, max] m from the attacked goal, "
              "attacker_distance: m, defenders: present | absent, episode_seconds}; the worlds change stage between "
              "episodes once the learner's env steps reach a stage's until. null = every episode a kickoff.")
    reward_weights: tuple = _f((1.0, 1.0, 1.0, 1.0), "Weights of the four reward terms [primary, rule, auxiliary, "
                                                     "observation] in the reward learnt; [1, 1, 1, 1] = the world's "
                                                     "total. Logged episode returns and terms stay unweighted.")

    # -- returns -----------------------------------------------------------------------------------------------
    gamma: float = _f(0.99, "Discount per motion period, in (0, 1] (paper: 0.99).")
    gae_lambda: float = _f(1.0, "GAE λ in [0, 1]; 1 = A2C's n-step returns (paper), PPO usually 0.95.")

    # -- optimiser ---------------------------------------------------------------------------------------------
    learning_rate: float = _f(1e-4, "Adam learning rate (paper: 1e-4).")
    adam_eps: float = _f(1e-5, "Adam epsilon.")
    max_grad_norm: float = _f(0.5, "Global gradient-norm clip (paper: 0.5).")

    # -- actor-critic loss -------------------------------------------------------------------------------------
    value_coef: float = _f(0.5, "Weight of the value loss (paper: 0.5).")
    entropy_coef: float = _f(0.1, "Weight of the entropy bonus (paper: 0.1).")

    # -- PPO only ----------------------------------------------------------------------------------------------
    ppo_epochs: int = _f(4, "PPO: passes over each rollout.")
    ppo_minibatches: int = _f(4, "PPO: minibatches per pass; they split robot sequences, so at most "
                                 "learning_robots.")
    ppo_clip: float = _f(0.2, "PPO: ratio clip ε.")
    clip_value_loss: bool = _f(False, "PPO: clip the value update like the policy ratio.")
    normalize_advantages: bool = _f(False, "Normalise advantages per minibatch (A2C: per rollout).")
    target_kl: float | None = _f(None, "PPO: stop a rollout's epochs early once the approximate KL exceeds this; "
                                       "null = never.")

    # -- curiosity and self-supervision ------------------------------------------------------------------------
    forward_coef: float = _f(1e-2, "Weight of the forward-model loss (ICM or RCM) (paper: 1e-2).")
    inverse_coef: float = _f(1e-2, "Weight of the inverse-model loss, the paper's ICM β (paper: 1e-2).")
    ltp_coef: float = _f(1e-3, "Weight of the long-term prediction loss (paper: 1e-3).")
    ltp_horizon: int = _f(6, "LTP horizon in motion periods; at most rollout_length (paper: 6).")
    self_supervised_coef: float = _f(1e-2, "Weight of localization + reconstruction, the paper's recon factor "
                                           "(paper: 1e-2).")
    intrinsic_reward_coef: float = _f(0.0, "Curiosity (forward-model error) as an intrinsic reward with its own "
                                           "advantage when > 0; 0 = curiosity only as auxiliary losses (paper).")
    pretrained_encoder: str | None = _f(None, "Path of a pretrained localization/reconstruction checkpoint; "
                                              "required by variant 'recon'.")
    init_policy: str | None = _f(None, "Path of a policy file whose weights start the run (the optimiser starts "
                                       "fresh): training on from a shipped or earlier policy, e.g. kickstarting "
                                       "from an imitation policy; it must fit this run's agent (same variant, "
                                       "localization, feature_size). Its sha256 goes into summary.json.")
    privileged_pose_seeding: bool = _f(False, "Re-seed the localization LSTM from the true pose every rollout, as "
                                              "the original code did (privileged information).")

    # -- imitation (not in the paper) -------------------------------------------------------------------------
    teacher: str | None = _f(None, "Scripted teacher whose actions label every learning robot's states for an "
                                   "imitation loss (DAgger: the learner acts, the teacher labels): 'chaser' "
                                   "(every robot a chaser: one shared network cannot tell a keeper slot from a "
                                   "chaser slot) or 'eager_chaser' (a chaser that also kicks a ball at its foot "
                                   "whenever it roughly faces the goal), 'perceiving' (the chaser on the robot's "
                                   "own padded observation and self-localization estimate, which the worlds then "
                                   "run; with localization: none the learner does not see that estimate); driving: "
                                   "'scripted' (the scripted driver); null = none (paper).")
    imitation_coef: float = _f(0.0, "Weight of the imitation loss −log π(teacher's action | s) at the start of "
                                    "training; needs a teacher.")
    imitation_decay_env_steps: int = _f(0, "Env steps over which imitation_coef falls linearly to "
                                           "imitation_final_coef; 0 = no decay.")
    imitation_final_coef: float = _f(0.0, "Imitation weight after the decay.")
    teacher_driven_worlds: int = _f(0, "Worlds (of num_envs) whose learning robots execute the teacher's actions "
                                       "instead of their own (DAgger's β); their steps train only the imitation "
                                       "and auxiliary losses. 0 = the learner acts everywhere.")
    teacher_driven_env_steps: int = _f(0, "Env steps after which the teacher-driven worlds go back to the learner; "
                                          "0 = never.")

    # -- opponents ---------------------------------------------------------------------------------------------
    opponent: str = _f("self", "Team B: 'self' (both teams learn, shared weights), 'snapshot' (frozen past "
                               "copies), 'scripted' (keeper_and_chasers on the ground truth), 'perceiving' (keeper_and_chasers on "
                               "its robots' own detections and pose estimates, soccer.perceiving), 'league' (per world "
                               "and episode one of perceiving, perceiving_chasers, scripted and a frozen snapshot, "
                               "drawn by prioritized fictitious self-play: envs.league), 'random'.")
    snapshot_every_updates: int = _f(200, "Opponent 'snapshot' (and the league's snapshot): add a frozen copy every this many updates.")
    snapshot_pool: int = _f(5, "Opponent 'snapshot': most recent copies kept to play against.")
    league_members: tuple[str, ...] | None = _f(None, "Opponent 'league': the members drawn from, some of "
                                                      "perceiving, perceiving_chasers, keeper_and_chasers (the "
                                                      "ground-truth team) and snapshot; null = all four.")

    # -- asynchronous actor-learner (runner: async; docs/training.md "Three ways to train") -------------------
    runner: str = _f("sync", "'sync': one process collects a rollout, then learns from it (the worlds may step in "
                             "worker processes, see backend); 'async': rollout workers step the worlds and act "
                             "while the learner trains in this process, experience and weights through shared "
                             "memory (backend 'ray': the workers are Ray actors).")
    workers: int | None = _f(None, "runner async: rollout workers (processes or Ray actors), each stepping its "
                                   "share of num_envs; null = one per CPU core this process may use, minus one "
                                   "for a CPU learner and one for the inference server (inference: server) (at "
                                   "least 1).")
    max_policy_lag: int = _f(4, "runner async: a rollout whose behaviour policy is more than this many updates "
                                "older than the learner's is dropped (counted); PPO's ratio against the "
                                "behaviour log-probabilities corrects the lag within it.")
    rollouts_per_update: int = _f(1, "runner async: worker rollouts joined (along the robot axis) into one update.")
    inference: str = _f("worker", "runner async, worker processes (backend auto): where the learning robots' "
                                  "acting forward runs. 'worker': each rollout worker acts for its own worlds on its "
                                  "own core; 'server': the workers only step their worlds and one inference server "
                                  "process batches every worker's robots into one forward on device (a GPU with "
                                  "device cuda), keeps their recurrent states and draws their actions from each "
                                  "worker's seeded generator, the same actions a worker would draw "
                                  "(docs/training.md, 'The asynchronous runner'). It pays with many workers and a "
                                  "GPU; on a machine of few cores and no GPU it is not expected to.")
    worker_restarts: int = _f(3, "runner async: a worker (or node) that dies is replaced at most this many times "
                                 "in a run; after that the run continues on the workers left, or stops cleanly "
                                 "with its reason when none is left.")
    ray_address: str | None = _f(None, "backend ray: null = an embedded local Ray; 'HOST:PORT' joins the Ray "
                                       "cluster whose head listens there (this machine must be one of its nodes: "
                                       "docs/training.md, 'On a Ray cluster').")
    ray_connect_timeout_s: float = _f(10.0, "backend ray: give up on ray_address after this many seconds.")
    torch_compile: bool = _f(False, "Compile the learner's hot modules (per-class embeddings, RTA) with "
                                    "torch.compile; falls back to eager, with a warning, where compiling fails. "
                                    "Costs minutes at start (docs/benchmarks.md).")

    # -- network -----------------------------------------------------------------------------------------------
    feature_size: int = _f(64, "Width D of the agent's streams, 1..1024 (paper: 64).")
    head_mode: str = _f("discrete", "Head-turn action: 'discrete' (paper) or 'continuous'.")

    # -- run ---------------------------------------------------------------------------------------------------
    seed: int = _f(0, "Seed of weights, worlds and action sampling (>= 0).")
    device: str = _f("cpu", "Torch device for learning: 'cpu', 'cuda', 'cuda:N' or 'mps'.")
    torch_threads: int = _f(1, "torch.set_num_threads for the learner (>= 1).")
    log_every_updates: int = _f(10, "Write scalars every this many updates.")
    checkpoint_every_minutes: float = _f(5.0, "Write a training checkpoint every this many minutes of wall time, "
                                              "after a first one as the run starts (a kill loses at most this much).")
    keep_checkpoints: int = _f(3, "Training checkpoints kept (the newest ones).")
    best_policy_window: int | None = _f(None, "Keep best_policy.safetensors, the policy at the best moving average "
                                              "of this many logged episode returns so far (the training curve's "
                                              "peak, what dynenv-eval training-best --window reads), for a "
                                              "held-out evaluation of it; null: only the last policy.")
    keep_policy_every_env_steps: int | None = _f(None, "Keep the policy each time the learner's env steps pass a "
                                                       "multiple of this, as kept_policies/step_<env steps>."
                                                       "safetensors, never deleted: the copies a validation "
                                                       "chooses among (learning/run/kept_policies.py); null: none.")

    def __post_init__(self) -> None:
        self.validate()

    # -- derived -----------------------------------------------------------------------------------------------
    def losses(self) -> Losses:
        """The variant's losses with the use_localization/use_reconstruction overrides applied."""
        row = VARIANT_LOSSES[self.variant]
        return dataclasses.replace(
            row,
            localization=row.localization if self.use_localization is None else self.use_localization,
            reconstruction=row.reconstruction if self.use_reconstruction is None else self.use_reconstruction)

    @property
    def world(self) -> Scenario:
        """The scenario (``dynenv_ros.scenarios``) a run of this config plays."""
        from dynenv_ros.scenarios import get_scenario
        return get_scenario(self.scenario)

    @property
    def learning_robots(self) -> int:
        """Robot sequences per rollout that are learned from: both teams in self-play, team A otherwise; driving:
        every car."""
        agents = min(self.team_sizes) if self.team_sizes else getattr(self, self.world.count_key)   # (team_sizes:
        return self.num_envs * agents * (self.world.sides if self.opponent == "self" else 1)   # the smallest rollout)

    @property
    def env_steps_per_update(self) -> int:
        return self.num_envs * self.rollout_length

    def curriculum_stage(self, env_steps: int) -> int:
        """The curriculum's stage after ``env_steps`` of the learner's (0 = the first; 0 without a curriculum)."""
        return stage_at(self.curriculum, env_steps)

    def imitation_weight(self, env_steps: int) -> float:
        """The imitation loss's weight after ``env_steps``: imitation_coef, linearly to imitation_final_coef."""
        if self.imitation_decay_env_steps <= 0:
            return self.imitation_coef
        done = min(1.0, env_steps / self.imitation_decay_env_steps)
        return self.imitation_coef + done * (self.imitation_final_coef - self.imitation_coef)

    def _validate_soccer(self) -> None:
        """Driving-only settings refused for soccer; each curriculum stage's world settings checked by the world's
        own config (distances inside the field, room for the attackers)."""
        for key, default in (("n_cars", 2), ("action_mode", "discrete")):
            if getattr(self, key) != default:
                raise ConfigError(key, f"applies to scenario 'driving' only (scenario is {self.scenario!r})")
        from dynenv_ros.soccer.config import SoccerConfig
        base: dict[str, Any] = {"players_per_team": self.players_per_team}
        if self.episode_seconds is not None:
            base["episode_seconds"] = self.episode_seconds
        for i, stage in enumerate(self.curriculum or ()):
            try:
                SoccerConfig.from_mapping({**base, **stage.soccer_settings()})
            except ValueError as error:         # named by the stage's keys, not the world's
                reason = str(error).replace("start.ball_distance_min/max", "ball_distance").replace("start.", "")
                raise ConfigError("curriculum", f"stage {i}: {reason}") from None

    def _validate_driving(self) -> None:
        """Soccer-only settings refused for driving, each with its key (module docstring)."""
        why = "is soccer-only; scenario 'driving' "
        if self.teacher_driven_worlds:
            raise ConfigError("teacher_driven_worlds", why + "has no teacher-driven worlds (the teacher labels, "
                                                             "the learner drives)")
        if self.opponent != "self":
            raise ConfigError("opponent", why + "has no opponent team: every car of every world is driven and "
                                                "trained by the policy (keep opponent: self)")
        if self.variant == "recon":
            raise ConfigError("variant", "'recon' " + why + "has no localization or reconstruction targets; "
                                                            "use baseline, icm, rcm or pred")
        for key in ("use_localization", "use_reconstruction"):
            if getattr(self, key):
                raise ConfigError(key, why + "has no learning targets (no pose, no reconstruction heads)")
        if self.pretrained_encoder:
            raise ConfigError("pretrained_encoder", why + "has no reconstruction encoder to load")
        if self.localization != "none":
            raise ConfigError("localization", why + "has no self-localization estimate (keep localization: none)")
        if self.privileged_pose_seeding:
            raise ConfigError("privileged_pose_seeding", why + "has no pose")
        if self.curriculum is not None:
            raise ConfigError("curriculum", why + "starts every episode with its own traffic (no start states)")

    def _validate_runner(self) -> None:
        """The asynchronous runner's settings (machine-dependent limits are checked where the run starts:
        ``resources.check_machine``)."""
        if self.runner == "sync":
            if self.backend == "ray":
                raise ConfigError("backend", "'ray' runs rollout workers as Ray actors, which needs runner: async")
            if self.inference != "worker":
                raise ConfigError("inference", f"{self.inference!r} serves rollout workers, which needs runner: "
                                               f"async (runner sync acts in this process)")
            return
        if self.inference == "server" and self.backend == "ray":
            raise ConfigError("inference", "'server' serves the worker processes of backend 'auto' (Ray actors act "
                                           "for themselves, maybe on other machines)")
        if self.backend not in ("auto", "ray"):
            raise ConfigError("backend", f"{self.backend!r} does not apply to runner async (each rollout worker "
                                         f"steps its worlds itself); use 'auto' (worker processes) or 'ray'")
        if self.algorithm != "ppo":
            raise ConfigError("algorithm", "runner async needs 'ppo': its ratio against the behaviour "
                                           "log-probabilities corrects the policy lag (A2C is on-policy only)")
        if self.workers is not None and not 1 <= self.workers <= self.num_envs:
            raise ConfigError("workers", f"must be in 1..num_envs ({self.num_envs}): every worker steps at least "
                                         f"one world, got {self.workers}")
        if self.max_policy_lag < 0:
            raise ConfigError("max_policy_lag", f"must be >= 0, got {self.max_policy_lag}")
        if self.worker_restarts < 0:
            raise ConfigError("worker_restarts", f"must be >= 0, got {self.worker_restarts}")
        if self.ray_address is not None and self.backend != "ray":
            raise ConfigError("ray_address", "applies to backend 'ray' only")
        if self.ray_address is not None and not re.match(r"^[A-Za-z0-9_.\-\[\]:]+:\d{1,5}$", self.ray_address):
            raise ConfigError("ray_address", f"expected HOST:PORT (e.g. 10.0.0.5:6379), got {self.ray_address!r}")
        if not 0.0 < self.ray_connect_timeout_s <= 600.0 or not math.isfinite(self.ray_connect_timeout_s):
            raise ConfigError("ray_connect_timeout_s", f"must be in (0, 600], got {self.ray_connect_timeout_s}")

    # -- JSON --------------------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Every field, JSON-ready (str, int, float, bool, None only)."""
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> TrainConfig:
        """Inverse of ``to_dict``; missing keys take their defaults, unknown keys are refused."""
        if not isinstance(values, Mapping):
            raise ConfigError("<config>", f"expected a mapping of settings, got {type(values).__name__}")
        for key in values:
            _check_known(key)
        return cls(**dict(values))

    def replace(self, **changes: Any) -> TrainConfig:
        """A copy with ``changes`` (checked like everything else)."""
        for key in changes:
            _check_known(key)
        return dataclasses.replace(self, **changes)

    # -- checks ------------------------------------------------------------------------------------------------
    def validate(self) -> None:
        """Raise ConfigError for a wrong type or an impossible value (types first, then ranges, then relations)."""
        for f in dataclasses.fields(self):
            value = _check_type(f.name, getattr(self, f.name), _FIELD_TYPES[f.name])
            object.__setattr__(self, f.name, value)             # ints given for floats become floats
        for key, (low, high) in SIZE_BOUNDS.items():
            value = getattr(self, key)
            if value is not None and not low <= value <= high:
                raise ConfigError(key, f"must be in {low}..{high}, got {value}")
        _choice("algorithm", self.algorithm, ALGORITHMS)
        _choice("variant", self.variant, VARIANTS)
        _choice("opponent", self.opponent, OPPONENTS)
        _choice("backend", self.backend, BACKENDS)
        _choice("runner", self.runner, RUNNERS)
        _choice("inference", self.inference, INFERENCES)
        _choice("scenario", self.scenario, SCENARIOS)
        if self.teacher is not None:
            teachers = self.world.teachers
            from dynenv_ros.scenarios import SCENARIOS as ALL_SCENARIOS
            owner = [s for s in ALL_SCENARIOS if s is not self.world and self.teacher in s.teachers]
            if self.teacher not in teachers and owner:
                raise ConfigError("teacher", f"{self.teacher!r} is a {owner[0].name} teacher; scenario "
                                             f"{self.scenario!r} has {', '.join(teachers)}")
            _choice("teacher", self.teacher, teachers)
        _choice("head_mode", self.head_mode, HEAD_MODES)
        if self.head_mode != "discrete":
            raise ConfigError("head_mode", "only 'discrete' can be trained so far: the rollout stores integer actions "
                              "and the curiosity heads one-hot encode the 7 head choices (the continuous head runs "
                              "in the policy node and the env, not in the trainer yet)")
        _choice("perception", self.perception, PERCEPTIONS)
        _choice("localization", self.localization, LOCALIZATIONS)
        _choice("action_mode", self.action_mode, ACTION_MODES)
        getattr(self, f"_validate_{self.world.name}")()
        if not _DEVICE.match(self.device):
            raise ConfigError("device", f"expected 'cpu', 'cuda', 'cuda:N' or 'mps', got {self.device!r}")
        for key in ("total_env_steps", "snapshot_every_updates", "log_every_updates"):
            if getattr(self, key) < 1:
                raise ConfigError(key, f"must be >= 1, got {getattr(self, key)}")
        if self.seed < 0:
            raise ConfigError("seed", f"must be >= 0, got {self.seed}")
        for key in ("gamma", "gae_lambda", "learning_rate", "adam_eps", "max_grad_norm", "value_coef",
                    "entropy_coef", "ppo_clip", "forward_coef", "inverse_coef", "ltp_coef", "self_supervised_coef",
                    "intrinsic_reward_coef", "checkpoint_every_minutes", "max_minutes", "target_kl",
                    "imitation_coef", "imitation_final_coef"):
            value = getattr(self, key)
            if value is not None and not math.isfinite(value):
                raise ConfigError(key, f"must be finite, got {value}")
        if not 0.0 < self.gamma <= 1.0:
            raise ConfigError("gamma", f"must be in (0, 1], got {self.gamma}")
        if not 0.0 <= self.gae_lambda <= 1.0:
            raise ConfigError("gae_lambda", f"must be in [0, 1], got {self.gae_lambda}")
        for key in ("learning_rate", "adam_eps", "max_grad_norm", "ppo_clip", "checkpoint_every_minutes",
                    "max_minutes", "target_kl"):
            value = getattr(self, key)
            if value is not None and value <= 0.0:
                raise ConfigError(key, f"must be > 0, got {value}")
        for key in ("value_coef", "entropy_coef", "forward_coef", "inverse_coef", "ltp_coef", "self_supervised_coef",
                    "intrinsic_reward_coef", "imitation_coef", "imitation_final_coef"):
            if getattr(self, key) < 0.0:
                raise ConfigError(key, f"must be >= 0 (a weight), got {getattr(self, key)}")
        losses = self.losses()
        if losses.ltp and self.ltp_horizon > self.rollout_length:
            raise ConfigError("ltp_horizon", f"{self.ltp_horizon} exceeds rollout_length {self.rollout_length} "
                                             f"(the LTP target must lie inside the rollout)")
        if self.algorithm == "ppo" and self.ppo_minibatches > self.learning_robots:
            raise ConfigError("ppo_minibatches", f"{self.ppo_minibatches} minibatches of robot sequences, but a "
                                                 f"rollout has only {self.learning_robots} learning robots "
                                                 + f"(num_envs x {self.world.count_key}"
                                                 + (f" x {self.world.sides} teams)" if self.opponent == "self"
                                                    and self.world.sides > 1 else ")"))
        if self.variant == "recon" and not self.pretrained_encoder:
            raise ConfigError("pretrained_encoder", "variant 'recon' requires the pretrained reconstruction "
                                                    "encoder; to train localization + reconstruction from scratch "
                                                    "use variant 'pred' with use_localization and "
                                                    "use_reconstruction true")
        if self.init_policy is not None and self.pretrained_encoder:
            raise ConfigError("init_policy", "init_policy starts every network from a policy file; with "
                                             "pretrained_encoder as well one would overwrite the other (set one)")
        if self.imitation_decay_env_steps < 0:
            raise ConfigError("imitation_decay_env_steps", f"must be >= 0, got {self.imitation_decay_env_steps}")
        if (self.imitation_coef > 0.0 or self.imitation_final_coef > 0.0) and self.teacher is None:
            raise ConfigError("imitation_coef", "an imitation loss needs a teacher (set teacher: chaser; driving: scripted)")
        if self.teacher_driven_env_steps < 0:
            raise ConfigError("teacher_driven_env_steps", f"must be >= 0, got {self.teacher_driven_env_steps}")
        if self.teacher_driven_worlds:
            if self.teacher is None:
                raise ConfigError("teacher_driven_worlds", "teacher-driven worlds need a teacher (set teacher: chaser)")
            if not 0 < self.teacher_driven_worlds < self.num_envs:
                raise ConfigError("teacher_driven_worlds", f"must be in 0..{self.num_envs - 1} (num_envs - 1: the "
                                                           f"learner needs a world of its own), got "
                                                           f"{self.teacher_driven_worlds}")
        if self.episode_seconds is not None and not (math.isfinite(self.episode_seconds)
                                                     and 0.0 < self.episode_seconds <= 3600.0):
            raise ConfigError("episode_seconds", f"must be in (0, 3600] seconds, got {self.episode_seconds}")
        if not all(math.isfinite(w) for w in self.reward_weights):
            raise ConfigError("reward_weights", f"must be finite, got {list(self.reward_weights)}")
        self._validate_runner()
        if self.team_sizes is not None:
            if self.world.sides < 2 or self.runner != "async":
                raise ConfigError("team_sizes", "applies to soccer on the asynchronous runner (runner: async) only")
            if self.players_per_team not in self.team_sizes:
                raise ConfigError("team_sizes", f"must hold players_per_team ({self.players_per_team}), got "
                                                f"{list(self.team_sizes)}")
            if self.workers is not None and self.workers < len(self.team_sizes):
                raise ConfigError("workers", f"{self.workers} workers cannot play {len(self.team_sizes)} team sizes "
                                             f"(each worker plays one)")
        if self.league_members is not None:
            if self.opponent != "league":
                raise ConfigError("league_members", f"applies to opponent: league only (opponent is {self.opponent!r})")
            unknown = [m for m in self.league_members if m not in LEAGUE_MEMBERS]
            if unknown:
                raise ConfigError("league_members", f"unknown member(s) {unknown}; expected some of "
                                                    f"{', '.join(LEAGUE_MEMBERS)}")
        if self.intrinsic_reward_coef > 0.0 and not losses.forward:
            raise ConfigError("intrinsic_reward_coef", f"> 0 needs a forward model, which variant "
                                                       f"{self.variant!r} does not train")


def _plain(value: Any) -> Any:
    """A field's value as JSON: tuples as lists, curriculum stages as mappings."""
    if isinstance(value, tuple):
        return [v.as_dict() if isinstance(v, CurriculumStage) else v for v in value]
    return value


# -- type checking -------------------------------------------------------------------------------------------------
class _Names(tuple):
    """The kind of a field that is a list of distinct names (``league_members``)."""


# (base type, None allowed) per field, from the annotations (strings under `from __future__ import annotations`).
_BASE_TYPES = {"int": int, "float": float, "bool": bool, "str": str}


def _parse_annotation(annotation: str) -> tuple[type, bool]:
    if str(annotation) == "tuple":                  # a list of 4 numbers (reward_weights)
        return tuple, False
    if str(annotation) == "tuple | None":           # a list of distinct team sizes (team_sizes)
        return list, True
    if str(annotation) == "tuple[str, ...] | None":   # a list of distinct names (league_members)
        return _Names, True
    if str(annotation) == "tuple[CurriculumStage, ...] | None":     # a list of stages (curriculum)
        return CurriculumStage, True
    parts = [p.strip() for p in str(annotation).split("|")]
    optional = "None" in parts
    (base,) = [p for p in parts if p != "None"]
    return _BASE_TYPES[base], optional


_FIELD_TYPES: dict[str, tuple[type, bool]] = {f.name: _parse_annotation(f.type)
                                              for f in dataclasses.fields(TrainConfig)}


def _check_type(key: str, value: Any, expected: tuple[type, bool]) -> Any:
    kind, optional = expected
    if value is None:
        if optional:
            return None
        raise ConfigError(key, f"expected {kind.__name__}, got null")
    described = f"{type(value).__name__} {value!r}"
    if kind is CurriculumStage:
        try:
            return parse_curriculum(value)
        except CurriculumError as error:
            raise ConfigError(key, str(error)) from None
    if kind is _Names:
        if not isinstance(value, (list, tuple)) or not value or len(set(value)) != len(value) or \
                any(not isinstance(v, str) for v in value):
            raise ConfigError(key, f"expected a list of distinct names, got {described}")
        return tuple(value)
    if kind is list:
        if not isinstance(value, (list, tuple)) or not value or len(set(value)) != len(value) or \
                any(isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_PLAYERS_PER_TEAM
                    for v in value):
            raise ConfigError(key, f"expected a list of distinct robots-per-team sizes in "
                                   f"1..{MAX_PLAYERS_PER_TEAM}, got {described}")
        return tuple(int(v) for v in value)
    if kind is tuple:
        if not isinstance(value, (list, tuple)) or len(value) != 4 or \
                any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
            raise ConfigError(key, f"expected a list of 4 numbers, got {described}")
        return tuple(float(v) for v in value)
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true or false, got {described}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            hint = " (write it without a decimal point or exponent)" if isinstance(value, float) and \
                value.is_integer() else ""
            raise ConfigError(key, f"expected an integer, got {described}{hint}")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f"expected a number, got {described}")
        return float(value)
    if not isinstance(value, str):
        raise ConfigError(key, f"expected a string, got {described}")
    return value


def _choice(key: str, value: str, choices: Sequence[str]) -> None:
    if value not in choices:
        close = difflib.get_close_matches(value, choices, n=1)
        raise ConfigError(key, f"unknown value {value!r}; expected one of {', '.join(choices)}"
                               + (f" (did you mean {close[0]!r}?)" if close else ""))


def _check_known(key: Any) -> None:
    if not isinstance(key, str):
        raise ConfigError(str(key), "setting names must be strings")
    if key not in _FIELD_TYPES:
        close = difflib.get_close_matches(key, list(_FIELD_TYPES), n=1)
        raise ConfigError(key, "unknown setting" + (f"; did you mean {close[0]!r}?" if close else
                                                    f"; known settings: {', '.join(_FIELD_TYPES)}"))


def field_help() -> dict[str, str]:
    """Each field's help text, in declaration order."""
    helps = {}
    for f in dataclasses.fields(TrainConfig):
        text = f.metadata["help"]
        if f.name in SIZE_BOUNDS and "{}..{}".format(*SIZE_BOUNDS[f.name]) not in text:
            text += " Bounds: {}..{}.".format(*SIZE_BOUNDS[f.name])
        helps[f.name] = text
    return helps


# -- YAML ------------------------------------------------------------------------------------------------------------
class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats without a dot (1e-4, 3E5) as floats."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def parse_value(text: str) -> Any:
    """A ``--set`` value: YAML scalar syntax (``1e-4``, ``true``, ``null``, ``'quoted'``)."""
    try:
        return yaml.load(text, Loader=_Loader)       # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as error:
        raise ValueError(f"not a YAML value: {error}") from None


def load_config(path: str | Path | None, overrides: Sequence[str] = (), base: TrainConfig | None = None
                ) -> TrainConfig:
    """Defaults (or ``base``, e.g. a resumed run's config) ← the YAML file ``path`` (a mapping of settings; None = defaults only) ← ``overrides``
    (``"key=value"``, value in YAML syntax), then checked once. ConfigError names the offending key (and the file
    or override it came from)."""
    values: dict[str, Any] = base.to_dict() if base is not None else {}
    if path is not None:
        source = Path(path)
        try:
            text = source.read_text(encoding="utf-8")
        except OSError as error:
            raise ConfigError("<config>", f"cannot read {source}: {error}") from None
        try:
            loaded = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
        except yaml.YAMLError as error:
            raise ConfigError("<config>", f"{source} is not valid YAML: {error}") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError("<config>", f"{source} must hold a mapping of settings, got {type(loaded).__name__}")
        for key, value in loaded.items():
            try:
                _check_known(key)
            except ConfigError as error:
                raise ConfigError(error.key, f"{error.reason} (in {source})") from None
            values[key] = value
    for item in overrides:
        key, sep, text = str(item).partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(key or str(item), f"override {item!r} must look like key=value")
        _check_known(key)
        try:
            values[key] = parse_value(text)
        except ValueError as error:
            raise ConfigError(key, f"override {item!r}: {error}") from None
        _check_type(key, values[key], _FIELD_TYPES[key])         # name the override's type error right here
    return TrainConfig(**values)
