"""The snapshot opponent's pool across --resume: the learner takes the copies the worlds take (update 0 and every
``snapshot_every_updates``), keeps the last ``snapshot_pool`` in its checkpoints and hands them back to the worlds."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from dynenv_ros.learning.algo.networks import make_agent
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.distributed.rollout_worker import RolloutWorker
from dynenv_ros.learning.run import checkpoints
from dynenv_ros.learning.run.snapshot_history import SnapshotHistory
from dynenv_ros.learning.trainer import Trainer

SMALL = {"algorithm": "ppo", "variant": "baseline", "players_per_team": 1, "num_envs": 2, "perception": "none",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "opponent": "snapshot",
         "snapshot_every_updates": 2, "snapshot_pool": 3, "backend": "inprocess"}


def _first_weight(state) -> np.ndarray:
    return np.asarray(next(iter(state.values())))


def test_the_history_keeps_the_last_copies_taken_at_the_multiples():
    agent = make_agent(TrainConfig(**SMALL))
    history = SnapshotHistory(every=2, pool=3)
    first = next(iter(agent.parameters()))
    for update in range(0, 9):                  # copies at 0, 2, 4, 6, 8; the last three kept
        with torch.no_grad():
            first.fill_(float(update))
        history.after_update(update, agent)
    assert [float(_first_weight(s).flat[0]) for s in history.states] == [4.0, 6.0, 8.0]
    again = SnapshotHistory.from_checkpoint(history.tensors(), 2, 3, agent)
    assert [float(_first_weight(s).flat[0]) for s in again.states] == [4.0, 6.0, 8.0]
    assert set(again.states[0]) == set(agent.state_dict())
    other = make_agent(TrainConfig(**{**SMALL, "feature_size": 8}))
    with pytest.raises(ValueError, match="does not fit"):
        SnapshotHistory.from_checkpoint(history.tensors(), 2, 3, other)


def test_a_resumed_run_plays_the_pool_its_checkpoint_held(tmp_path):
    """8 env steps an update, 48 env steps: updates 1..6, copies at updates 0, 2, 4, 6 → the pool holds 2, 4, 6."""
    cfg = TrainConfig(**{**SMALL, "total_env_steps": 48})
    Trainer(cfg, tmp_path, progress=False).run()
    model = make_agent(cfg)
    from dynenv_ros.learning.algo.networks import TrainingNetworks
    _, extra = checkpoints.load_training_checkpoint(tmp_path, TrainingNetworks(model, cfg.ltp_horizon))
    saved = SnapshotHistory.from_checkpoint(extra, 2, 3, model).states
    assert len(saved) == 3
    assert not np.array_equal(_first_weight(saved[0]), _first_weight(saved[2]))   # copies of different updates
    resumed = Trainer(cfg.replace(total_env_steps=56), tmp_path, resume=True, progress=False)
    pool = resumed.source.opponent.pool
    assert len(pool) == 3
    for member, state in zip(pool, saved):
        for name, value in member.state_dict().items():
            assert np.array_equal(value.numpy(), state[name])
    resumed.close()


def test_a_rollout_worker_starts_from_the_pool_it_is_given():
    cfg = TrainConfig(**{**SMALL, "runner": "async", "workers": 1, "backend": "auto"})
    agent = make_agent(cfg)
    history = SnapshotHistory(2, 3)
    for scale in (1.0, 2.0):
        with torch.no_grad():
            for p in agent.parameters():
                p.mul_(scale)
        history.take(agent)
    worker = RolloutWorker(cfg, 0, 0, 2, snapshot_states=history.states)
    worker.adopt(0)
    worker.collect(0)
    pool = worker.worlds.opponent.pool
    assert len(pool) == 2
    for member, state in zip(pool, history.states):
        for name, value in member.state_dict().items():
            assert np.array_equal(value.numpy(), state[name])
    worker.close()
