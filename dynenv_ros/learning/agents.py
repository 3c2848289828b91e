"""The agent a training run trains, and the policy of a training checkpoint — what the trainer, the sequence learner
and the evaluation (``dynenv_ros.evaluation``, which must not import the trainer) share. ROS-free.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.learning import checkpoints
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.heads import Learner
from dynenv_ros.soccer.config import SoccerConfig


def make_agent(cfg: TrainConfig) -> DynEnvAgent:
    """The untrained agent a run of ``cfg`` trains (its scenario, width, head and action mode, and whether it takes
    the pose estimate: ``localization: estimate``)."""
    if cfg.driving:
        return DynEnvAgent(cfg.feature_size, scenario="driving", action_mode=cfg.action_mode)
    motion = SoccerConfig.from_mapping({"players_per_team": cfg.players_per_team, "head_mode": cfg.head_mode}).motion
    return DynEnvAgent(cfg.feature_size, cfg.head_mode, motion.head_units, motion.head_max_delta,
                       uses_pose=cfg.localization == "estimate")


def policy_from_training_checkpoint(path: str | Path) -> tuple[DynEnvAgent, dict[str, Any]]:
    """The policy of a training checkpoint — a ``step_*`` folder, or a run folder or its ``checkpoints`` folder (then
    the latest valid one) — in eval mode on the CPU, with the checkpoint's meta: to evaluate a run part-way, or one
    stopped before it wrote ``policy.safetensors``. The agent is rebuilt from the config the checkpoint carries.
    ValueError (from ``checkpoints``) for a missing, damaged or foreign checkpoint, or weights that do not fit."""
    meta = checkpoints.read_checkpoint_meta(path)
    try:
        cfg = TrainConfig.from_dict(meta["config"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"checkpoint {meta['checkpoint']['path']} has no usable training config: {error}") from None
    agent = make_agent(cfg)
    meta, _ = checkpoints.load_training_checkpoint(meta["checkpoint"]["path"], Learner(agent, cfg.ltp_horizon))
    return agent.eval(), meta


__all__ = ["make_agent", "policy_from_training_checkpoint"]
