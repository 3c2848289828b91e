"""Learning from recorded bags (``dynenv-train --from-bag BAG …``): the recorder's MCAP bags give the same per-robot
sequences as the live trainer node (``learning.messages.assembly``, fed from the bag in time order), and the learner trains
offline on them:

- **behaviour cloning** of whoever chose the recorded actions (a scripted team, a robot's own stack, the scripted
  drivers): the imitation loss −log π(recorded action | observation) (``algo.auxiliary.imitation_loss``), a warm start;
- **the self-supervised heads** (soccer): localization (pose) and reconstruction (ball, robots) from the ground
  truth the bag holds (``/world_state`` and the feedback's seen objects) — the paper's pretraining, from real
  recordings.

No reward term is learnt (the recorded actions are not the learner's: no importance ratio applies). Sequences
start from a zero recurrent state (``starts[0]``): offline, nothing is known of the state the recording policy had.
A recorded head turn is mapped to the nearest of the discrete head's steps.

The bags say which scenario they hold: soccer robots (``team_a_<k>`` …) or driving cars (``car_<k>``); the config
must name the same ``scenario`` (a driving bag with ``--config driving_quick`` or ``--set scenario=driving``), and the
agent count (``players_per_team``, ``n_cars``) is taken from the bags. A driving bag clones the cars' recorded
commands into the agent of the config's ``action_mode`` (discrete: the nearest of the nine commands; continuous:
the normalised command) and each car's sequences end where its own episode ended; driving has no self-supervised
heads.

The run directory holds what ``dynenv-train`` writes: ``config.json``, ``metrics.csv``, ``tensorboard/``, a
training checkpoint, ``policy.safetensors`` (a policy file for the policy node, ``pretrained_encoder`` of
``dynenv-train``, or the trainer node's ``initial_policy``) and ``summary.json``.
"""
from __future__ import annotations

import json
import re
import time
from collections import Counter
from pathlib import Path
from typing import Any, Sequence as Seq

import numpy as np
import torch

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning.algo.experience import Experience, Progress, arrays_as_tensors
from dynenv_ros.learning.algo.loop import train
from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.algo.ppo import UpdateSettings, update
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.messages.assembly import ExperienceAssembler, Sequence, batch
from dynenv_ros.learning.messages.scenarios import DRIVING_AGENT, SOCCER_AGENT, experience_scenario
from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.run.metrics import RunLogger
from dynenv_ros.scenarios import get_scenario


def agent_topic(agent_pattern: str) -> re.Pattern[str]:
    """``<game>/<agent>/detections|action|feedback`` for the agents ``agent_pattern`` names."""
    return re.compile(rf"^(?P<source>(/[A-Za-z0-9_]+)*)/(?P<robot>{agent_pattern})/"
                      r"(?P<kind>detections|action|feedback)$")


# The agents' topics of each scenario, as ``learning.messages.scenarios`` names the agents.
AGENT_TOPICS = {"robocup": agent_topic(SOCCER_AGENT), "driving": agent_topic(DRIVING_AGENT)}
WORLD_TOPIC = re.compile(r"^(?P<source>(/[A-Za-z0-9_]+)*)/world_state$")


def bag_scenario(paths: Seq[str | Path]) -> str:
    """The scenario the bags record ('robocup' or 'driving'), from their agents' topics; ValueError for bags with
    no agent, or with both kinds (one run learns one agent)."""
    from dynenv_ros.bags.inspect import open_bag
    found: dict[str, str] = {}
    for path in paths:
        with open_bag(path) as bag:
            for connection in bag.connections:
                for scenario, pattern in AGENT_TOPICS.items():
                    if pattern.match(connection.topic):
                        found.setdefault(scenario, f"{path}: {connection.topic}")
    if not found:
        raise ValueError(f"no robot detections in {', '.join(map(str, paths))}: not a recording of a game")
    if len(found) > 1:
        raise ValueError(f"the bags record both soccer and driving games ({found['robocup']}, {found['driving']}); "
                         "learn from one scenario's bags at a time")
    return next(iter(found))


def bag_layout(paths: Seq[str | Path], scenario: str = "robocup") -> tuple[int, int]:
    """(players per team — driving: cars —, frames per period) of the games in the bags: the agents' names and the
    detections."""
    from dynenv_ros.bags.inspect import open_bag
    topic = AGENT_TOPICS[scenario]
    players, frames = 0, 0
    for path in paths:
        with open_bag(path) as bag:
            for connection in bag.connections:
                match = topic.match(connection.topic)
                if match:       # team_a_<k>, car_<k>: k + 1 agents (per team) at least
                    players = max(players, int(match["robot"].rsplit("_", 1)[1]) + 1)
            first = [c for c in bag.connections if topic.match(c.topic) and c.topic.endswith("/detections")]
            for connection, _, raw in bag.messages(first[:1]):
                frames = max(frames, int(bag.deserialize(raw, connection.msgtype).frames_per_period))
                break
    if not players or not frames:
        raise ValueError(f"no robot detections in {', '.join(map(str, paths))}: not a recording of a game")
    return players, frames


def bag_sequences(paths: Seq[str | Path], steps: int, players: int, frames: int, with_targets: bool,
                  learns=None, scenario: str = "robocup", action_mode: str = "discrete"
                  ) -> tuple[list[Sequence], Counter[str]]:
    """Every sequence of ``steps`` periods in the bags (each bag's games kept apart), and the assembler's counts.
    ``players``: per team, or (driving) cars; ``action_mode``: driving's, how the recorded commands are learnt."""
    from dynenv_ros.bags.inspect import open_bag
    agents = experience_scenario(scenario, players, frames, action_mode)
    assembler = ExperienceAssembler(steps, agents, with_targets=with_targets, learns=learns,
                                    require_learning_fields=False)
    topic = AGENT_TOPICS[scenario]
    out: list[Sequence] = []
    for index, path in enumerate(paths):
        with open_bag(path) as bag:
            for connection, _, raw in bag.messages():
                robot = topic.match(connection.topic)
                world = WORLD_TOPIC.match(connection.topic)
                if robot is None and (world is None or not with_targets):
                    continue
                msg = bag.deserialize(raw, connection.msgtype)
                if robot is None:
                    assembler.add_world_state(f"{index}:{world['source']}", msg)
                    continue
                source = f"{index}:{robot['source']}"
                {"detections": assembler.add_frame, "action": assembler.add_action,
                 "feedback": assembler.add_feedback}[robot["kind"]](source, robot["robot"], msg)
            out += assembler.take()
    # the last episode's final steps short of a whole sequence (it needs the observation after them)
    assembler.counts["steps_unused"] = assembler.pending_steps
    return out, assembler.counts


def clone_settings(cfg: TrainConfig, with_targets: bool) -> UpdateSettings:
    """Imitation and the self-supervised losses only (no policy-gradient, value or curiosity terms)."""
    return UpdateSettings(algorithm="a2c", policy_coef=0.0, value_coef=0.0, entropy_coef=0.0,
                          max_grad_norm=cfg.max_grad_norm, use_forward=False, use_rcm=False, use_inverse=False,
                          use_ltp=False, use_localization=with_targets, use_reconstruction=with_targets,
                          self_supervised_coef=cfg.self_supervised_coef, imitation_coef=1.0)


class BagSource:
    """The bags' sequences (of ``steps`` periods) as the training loop's experience (``algo.loop``): ``epochs``
    passes, each in a fresh random order (``generator``, drawn as a pass starts), ``batch_sequences`` per update."""

    def __init__(self, sequences: list[Sequence], epochs: int, batch_sequences: int, generator: torch.Generator,
                 agent: DynEnvAgent, steps: int) -> None:
        self.sequences, self.epochs, self.batch_sequences, self.steps = sequences, epochs, batch_sequences, steps
        self.generator, self.agent = generator, agent
        self.epoch = -1                 # the pass the last batch came from
        self.epoch_done = False         # the last batch ended its pass
        self._order: list[int] = []
        self._next = 0

    def next(self, progress: Progress, deadline: float) -> Experience | None:
        if self._next >= len(self._order):
            if self.epoch + 1 >= self.epochs:
                return None
            self.epoch += 1
            self._order = torch.randperm(len(self.sequences), generator=self.generator).tolist()
            self._next = 0
        chosen = [self.sequences[i] for i in self._order[self._next:self._next + self.batch_sequences]]
        self._next += self.batch_sequences
        self.epoch_done = self._next >= len(self._order)
        return Experience(_tensors(chosen, self.agent), self.steps * len(chosen))

    def learned(self, progress: Progress) -> None:
        pass

    def close(self) -> None:
        pass


def train_from_bags(cfg: TrainConfig, paths: Seq[str | Path], run_dir: str | Path, epochs: int = 10,
                    batch_sequences: int = 16, with_targets: bool = True, learns=None,
                    log: bool = True) -> dict[str, Any]:
    """Train a fresh agent on the bags' sequences for ``epochs`` passes; returns the summary (also written)."""
    if epochs < 1 or batch_sequences < 1:
        raise ValueError(f"epochs and batch_sequences must be >= 1, got {epochs}, {batch_sequences}")
    scenario = bag_scenario(paths)
    world = get_scenario(scenario)
    if world is not cfg.world:
        raise ValueError(f"the bags record {world.name} games and the config's scenario is {cfg.scenario!r}: use "
                         f"{world.config_hint}")
    if world.sides == 1 and learns is not None:
        raise ValueError(f"--team applies to soccer bags; every {world.agent} of a {world.name} bag is cloned")
    if cfg.localization != "none":
        raise ValueError("localization: 'estimate' trains on the simulator's pose estimates; a recording carries "
                         "none yet: use localization: none here")
    players, frames = bag_layout(paths, scenario)
    if cfg.head_mode != "discrete":
        raise ValueError("head_mode: learning from bags supports the discrete head only")
    with_targets = with_targets and world.self_supervised      # (driving has no self-supervised heads)
    cfg = cfg.replace(**{world.count_key: players})
    run = Path(run_dir)
    run.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    sequences, counts = bag_sequences(paths, cfg.rollout_length, players, frames, with_targets, learns, scenario,
                                      cfg.action_mode)
    if not sequences:
        raise ValueError(f"no whole sequence of {cfg.rollout_length} periods in the bags ({dict(counts)})")
    torch.set_num_threads(cfg.torch_threads)
    seeds = np.random.SeedSequence(cfg.seed).spawn(2)
    generator = torch.Generator().manual_seed(int(seeds[0].generate_state(1)[0]))
    torch.manual_seed(int(seeds[1].generate_state(1)[0]))          # parameter init only
    agent = make_agent(cfg)
    networks = TrainingNetworks(agent, cfg.ltp_horizon)
    optimizer = torch.optim.Adam(networks.parameters(), lr=cfg.learning_rate, eps=cfg.adam_eps)
    settings = clone_settings(cfg, with_targets)
    (run / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
    logger = RunLogger(run) if log else None
    history: list[dict[str, float]] = []
    epoch_stats: dict[str, list[float]] = {}
    source = BagSource(sequences, epochs, batch_sequences, generator, agent, cfg.rollout_length)
    progress = Progress()

    def learn(experience: Experience) -> dict[str, float]:
        return update(networks, optimizer, experience.batch, settings, generator)

    def record(experience: Experience, stats: dict[str, float], waited: float, learnt: float) -> None:
        """Each pass's means, logged as it ends."""
        for key, value in stats.items():
            epoch_stats.setdefault(key, []).append(value)
        if source.epoch_done:
            means = {k: float(np.mean(v)) for k, v in epoch_stats.items()}
            epoch_stats.clear()
            history.append(means)
            if logger is not None:
                logger.log(progress.env_steps, progress.updates, time.perf_counter() - started,
                           {f"bc/{k}": v for k, v in means.items()} | {"bc/epoch": float(source.epoch)})

    train(source, learn, progress, record)
    networks.eval()
    meta = {"version": checkpoints.META_VERSION, "source": "bags", "bags": [str(p) for p in paths],
            "updates": progress.updates, "env_steps": progress.env_steps, "episodes": 0,
            "wall_seconds": time.perf_counter() - started, "config": cfg.to_dict(),
            "code_revision": checkpoints.code_revision()}
    checkpoints.save_training_checkpoint(run, progress.env_steps, networks, optimizer, meta, {},
                                         keep=cfg.keep_checkpoints)
    from dynenv_ros.agent.checkpoint import save_policy
    save_policy(agent, str(run / "policy.safetensors"), {k: v for k, v in meta.items() if k != "config"})
    if logger is not None:
        logger.close()
    keys = ("imitation_loss", "teacher_agreement", "teacher_command_error", "localization_loss",
            "reconstruction_loss", "localization_within_50cm")
    summary = {"scenario": scenario, "sequences": len(sequences), "robot_periods": len(sequences) * cfg.rollout_length,
               world.count_key: players, "frames_per_period": frames, "epochs": epochs,
               "updates": progress.updates,
               "counts": dict(counts), "first_epoch": {k: history[0][k] for k in keys if k in history[0]},
               "last_epoch": {k: history[-1][k] for k in keys if k in history[-1]},
               "wall_seconds": time.perf_counter() - started}
    (run / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _tensors(sequences: list[Sequence], agent: DynEnvAgent) -> dict[str, Any]:
    arrays = batch(sequences)
    arrays["starts"][0] = True              # offline: the recording policy's state is unknown
    arrays["teacher_actions"] = arrays["actions"]
    del arrays["versions"]
    B = len(sequences)
    return arrays_as_tensors(arrays, tuple(s.expand(B, -1).clone() for s in agent.initial_state(1)))
