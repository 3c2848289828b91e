"""The trainer fed by message experience: updates and versions, weights a policy node can load, the staleness bound,
the recurrent state carried from one sequence of a stream to the next, checkpoints it resumes from, and a learner
thread that never blocks whoever feeds it."""
from __future__ import annotations

import json
import time

import pytest
import torch

from dynenv_ros.agent.checkpoint import policy_from_bytes
from dynenv_ros.learning.config import TrainConfig
from dynenv_ros.learning.messages.assembly import ExperienceAssembler
from dynenv_ros.learning.messages.scenarios import SoccerExperience
from dynenv_ros.learning.messages.message_trainer import TrainingThread, MessageTrainer
from experience_game import HEAD_MAX, HEAD_UNITS, play
from policy_node.policy_files import version_of
from test_messages_assembly import _feed

T = 4


@pytest.fixture(scope="module")
def sequences():
    game = play(episodes=3, players=1, seed=0, episode_seconds=3.0, version=1)
    assembler = ExperienceAssembler(T, SoccerExperience(1, game.frames, HEAD_MAX, HEAD_UNITS))
    return _feed(assembler, game.messages)          # 4 sequences per robot, 2 robots


def _config(**changes) -> TrainConfig:
    values = dict(algorithm="ppo", variant="pred", players_per_team=1, rollout_length=T, ltp_horizon=T,
                  ppo_epochs=2, ppo_minibatches=1, seed=3)
    values.update(changes)
    return TrainConfig(**values)


def test_an_update_gives_a_new_version_whose_weights_a_policy_node_loads(sequences, tmp_path):
    trainer = MessageTrainer(_config(), tmp_path / "run", batch_sequences=2, max_policy_lag=4)
    assert trainer.version == 1
    before = {k: v.clone() for k, v in trainer.agent.state_dict().items()}
    first = [s for s in sequences if s.index == 0]
    stats = trainer.learn(first)
    assert trainer.version == 2 and trainer.progress.env_steps == 2 * T
    assert any(not torch.equal(before[k], v) for k, v in trainer.agent.state_dict().items())
    for key in ("policy_loss", "value_loss", "entropy", "lag_versions_mean", "behaviour_log_prob_error"):
        assert key in stats and stats[key] == stats[key], key          # present and not NaN
    assert stats["lag_versions_mean"] == 0.0                          # acted with version 1, learnt at version 1
    agent, meta = policy_from_bytes(trainer.weights(), "weights")
    assert version_of(meta) == trainer.version
    for (name, a), b in zip(agent.state_dict().items(), trainer.agent.state_dict().values()):
        assert torch.equal(a, b), name


def test_each_streams_state_carries_over_and_stale_sequences_are_dropped(sequences, tmp_path):
    trainer = MessageTrainer(_config(), tmp_path / "run", batch_sequences=2, max_policy_lag=1)
    by_index = {i: [s for s in sequences if s.index == i] for i in range(4)}
    trainer.learn(by_index[0])
    assert set(trainer.states) == {s.stream for s in by_index[0]}
    trainer.learn(by_index[1])                       # continues both streams: no restart
    assert trainer.counts["state_restarts"] == 0 and trainer.version == 3
    # acted with version 1, now at 3: lag 2 > 1, dropped, and the stream's stored state is forgotten
    assert all(not trainer.fresh(s) for s in by_index[2])
    assert trainer.counts["stale_sequences"] == 2 and not trainer.states
    trainer.max_policy_lag = 5
    assert [s.keys[0][1] for s in by_index[3]] == [0, 0]      # index 3 starts an episode: nothing to carry
    trainer.learn(by_index[3])
    assert trainer.counts["state_restarts"] == 0


def test_a_sequence_whose_predecessor_was_not_learnt_starts_afresh(sequences, tmp_path):
    trainer = MessageTrainer(_config(), tmp_path / "run", batch_sequences=2, max_policy_lag=5)
    by_index = {i: [s for s in sequences if s.index == i] for i in range(4)}
    assert all(s.keys[0][1] > 0 for s in by_index[2])         # starts inside an episode
    trainer.learn(by_index[0])
    trainer.learn(by_index[2])                                # index 1 never learnt: no state to carry
    assert trainer.counts["state_restarts"] == 2


def test_a_checkpoint_resumes_the_update_count_and_the_weights(sequences, tmp_path):
    run = tmp_path / "run"
    trainer = MessageTrainer(_config(), run, batch_sequences=2)
    trainer.learn([s for s in sequences if s.index == 0])
    trainer.save_checkpoint()
    trainer.close()
    again = MessageTrainer(_config(), run, resume=True, batch_sequences=2)
    assert again.version == 2 and again.progress.env_steps == 2 * T
    for (name, a), b in zip(again.agent.state_dict().items(), trainer.agent.state_dict().values()):
        assert torch.equal(a, b), name


def test_the_learner_thread_takes_each_streams_waiting_sequences_in_order(sequences, tmp_path):
    """8 sequences of 2 streams waiting at once, at most 6 per batch: the first batch takes 3 of each stream in
    order (chained states), the second the last one of each."""
    trainer = MessageTrainer(_config(), tmp_path / "run", batch_sequences=2, max_policy_lag=10, log=False,
                              max_batch_sequences=6)
    updates = []
    background = TrainingThread(trainer, on_update=lambda lrn, stats: updates.append(lrn.version))
    background.start()
    started = time.perf_counter()
    background.put(sequences)                        # 8 sequences of 2 streams, fed at once
    assert time.perf_counter() - started < 0.5       # the feeder never waits for a gradient step
    deadline = time.monotonic() + 60.0
    while len(updates) < 2 and time.monotonic() < deadline and not background.error:
        time.sleep(0.05)
    background.stop()
    assert not background.error, background.error
    assert updates == [2, 3] and background.depth() == 0 and trainer.progress.env_steps == 8 * T
    assert trainer.counts["state_restarts"] == 0     # every batch continued both streams in order
    assert {stream: entry[0] for stream, entry in trainer.states.items()} == {("game", "team_a_0"): 3,
                                                                               ("game", "team_b_0"): 3}


def test_settings_that_cannot_learn_from_lagging_experience_are_refused(tmp_path):
    with pytest.raises(ValueError, match="needs 'ppo'"):
        MessageTrainer(_config(algorithm="a2c"), tmp_path / "a")
    with pytest.raises(ValueError, match="batch_sequences"):
        MessageTrainer(_config(ppo_minibatches=4), tmp_path / "b", batch_sequences=2)


def test_a_warm_start_from_a_policy_file_and_a_file_that_does_not_fit(tmp_path):
    from dynenv_ros.agent.checkpoint import save_policy
    from dynenv_ros.agent.network import DynEnvAgent
    torch.manual_seed(5)
    warm = DynEnvAgent(feature_size=64)
    save_policy(warm, tmp_path / "warm.safetensors")
    trainer = MessageTrainer(_config(), tmp_path / "run", initial_policy=tmp_path / "warm.safetensors")
    for (name, a), b in zip(trainer.agent.state_dict().items(), warm.state_dict().values()):
        assert torch.equal(a, b), name
    save_policy(DynEnvAgent(feature_size=16), tmp_path / "small.safetensors")
    with pytest.raises(ValueError, match="does not fit the learner"):
        MessageTrainer(_config(), tmp_path / "run2", initial_policy=tmp_path / "small.safetensors")


def test_dynenv_train_resumes_a_run_directory_the_trainer_node_wrote(sequences, tmp_path):
    from dynenv_ros.learning.train_cli import main as train_main
    run = tmp_path / "run"
    trainer = MessageTrainer(_config(num_envs=1, backend="inprocess", total_env_steps=8 + 4), run,
                              batch_sequences=2)
    trainer.learn([s for s in sequences if s.index == 0])           # 2 sequences x 4 steps = 8 env steps
    trainer.save_checkpoint()
    trainer.close()
    assert train_main(["--resume", str(run), "--no-progress"]) == 0     # one more in-process update: 12 steps
    summary = json.loads((run / "summary.json").read_text())
    assert summary["updates"] == 2 and summary["env_steps"] == 12


def test_the_learner_thread_takes_sequences_from_anywhere_in_its_queue(sequences, tmp_path):
    """A stream that produced two sequences before another produced one: the batch takes the first of each, from
    the middle of the queue too (a queue used to compare sequences by their arrays there, and the thread died)."""
    trainer = MessageTrainer(_config(), tmp_path / "run", batch_sequences=2, max_policy_lag=10, log=False,
                              max_batch_sequences=2)
    a = sorted((s for s in sequences if s.stream[1] == "team_a_0"), key=lambda s: s.index)
    b = sorted((s for s in sequences if s.stream[1] == "team_b_0"), key=lambda s: s.index)
    updates = []
    background = TrainingThread(trainer, on_update=lambda lrn, stats: updates.append(lrn.version))
    background.put([a[0], a[1], b[0], b[1]])
    background.start()
    deadline = time.monotonic() + 60.0
    while len(updates) < 2 and time.monotonic() < deadline and not background.error:
        time.sleep(0.05)
    background.stop()
    assert not background.error, background.error
    assert updates == [2, 3] and background.depth() == 0 and trainer.counts["state_restarts"] == 0


def test_the_learner_resumes_a_run_directory_dynenv_train_wrote(tmp_path):
    from dynenv_ros.learning.train_cli import main as train_main
    run = tmp_path / "run"
    assert train_main(["--config", "quick", "--run-dir", str(run), "--no-progress", "--set", "num_envs=1",
                       "--set", "backend=inprocess", "--set", "algorithm=ppo", "--set", "ppo_minibatches=1",
                       "--set", "players_per_team=1", "--set", "rollout_length=4", "--set", "ltp_horizon=4",
                       "--set", "total_env_steps=8"]) == 0
    cfg = TrainConfig.from_dict(json.loads((run / "config.json").read_text()))
    trainer = MessageTrainer(cfg, run, resume=True, batch_sequences=1, log=False)
    assert trainer.progress.updates == json.loads((run / "summary.json").read_text())["updates"] and trainer.version >= 2
    agent, _ = policy_from_bytes((run / "policy.safetensors").read_bytes(), "the run's policy")
    for (name, a), b in zip(agent.state_dict().items(), trainer.agent.state_dict().values()):
        assert torch.equal(a, b), name
