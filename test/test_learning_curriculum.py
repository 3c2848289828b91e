"""The training curriculum of start states (``TrainConfig.curriculum``, docs/training.md "A curriculum of start
states"): stages end at the stated env steps; bad curricula are refused naming the key; a worker's worlds change
stage only between episodes; the run logs the stage, saves it in its checkpoints and goes on in it after --resume;
the ``async_curriculum`` preset is the pure-RL async setting with the stated stages, and trains end to end; so does
``async_curriculum_mix``, keeping its policies at the stated marks."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch

from dynenv_ros.learning.algo.networks import TrainingNetworks, make_agent
from dynenv_ros.learning.config import ConfigError, TrainConfig, load_config
from dynenv_ros.learning.curriculum import stage_at
from dynenv_ros.learning.distributed.rollout_worker import RolloutWorker
from dynenv_ros.learning.distributed.worker_pool import ProcessPool
from dynenv_ros.learning.messages.message_trainer import MessageTrainer
from dynenv_ros.learning.train_cli import main
from dynenv_ros.learning.trainer import Trainer

ROOT = Path(__file__).resolve().parent.parent
# 1v1, ground-truth perception, a small network: cheap worlds and updates
SMALL = {"algorithm": "ppo", "variant": "baseline", "players_per_team": 1, "num_envs": 2, "perception": "none",
         "rollout_length": 3, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "backend": "inprocess"}
# an empty goal with the ball 1-3 m away in 4-s episodes (8 periods) until 12 env steps, then 4-s kickoffs
TWO_STAGES = [{"until": 12, "start": "attack", "ball_distance": [1.0, 3.0], "defenders": "absent",
               "episode_seconds": 4.0},
              {"start": "kickoff", "episode_seconds": 4.0}]


def small(**changes) -> TrainConfig:
    return TrainConfig(**{**SMALL, **changes})


def test_a_stage_lasts_until_its_env_steps_and_the_last_to_the_end():
    cfg = small(curriculum=[{"until": 300, "start": "attack"}, {"until": 600, "start": "attack",
                                                                   "ball_distance": [2.0, 6.0]}, {}])
    assert [cfg.curriculum_stage(n) for n in (0, 299, 300, 599, 600, 10**9)] == [0, 0, 1, 1, 2, 2]
    assert small().curriculum_stage(10**9) == 0 and stage_at(None, 5) == 0


@pytest.mark.parametrize("curriculum, reason", [
    ([{"until": 10, "start": "penalty_kick"}, {}], "unknown start 'penalty_kick'"),
    ([{"until": 10, "start": "attack", "ball_distance": [3.0, 1.0]}, {}], "is inverted"),
    ([{"until": 10}, {"until": 10}, {}], "stage ends must increase"),
    ([{"until": 20}, {"until": 10}, {}], "stage ends must increase"),
    ([{"until": 10, "start": "attack", "ball_distance": [1.0, 12.0]}, {}], "ball_distance must lie in"),  # 9 m field
    ([{"until": 10, "start": "attack", "ball_distance": [0.1, 2.0]}, {}], "ball_distance must lie in"),
    ([{"until": 10, "start": "attack", "attacker_distance": 0.3}, {}], "attacker_distance must be at least"),
    ([{"until": 10, "start": "attack", "defenders": "few"}, {}], "unknown defenders"),
    ([{"start": "attack"}, {}], "until (the env steps at which it ends) is required"),
    ([{"until": 10}, {"until": 20}], "lasts to the run's end"),
    ([{"until": 10, "defenders": "absent"}, {}], "defenders applies to start: attack only"),
    ([{"until": 10, "start": "attack", "goals": 2}, {}], "unknown key 'goals'"),
    ([{"until": 0}, {}], "until must be a whole number of env steps >= 1"),
    ([{"until": 10, "episode_seconds": 0}, {}], "episode_seconds must be in"),
    ([{"until": 10, "start": "attack", "kickoff_share": 1.2}, {}], "kickoff_share must be in [0, 1]"),
    ([{"until": 10, "start": "attack", "kickoff_share": "half"}, {}], "kickoff_share must be a number"),
    ([{"until": 10, "start": "attack", "kickoff_share": 0.5, "defenders": "absent"}, {}],
     "kickoff_share needs"),
    ([{"until": 10, "kickoff_share": 0.5}, {}], "kickoff_share applies to start: attack only"),
    ([], "expected a list of stages"),
    ("attack", "expected a list of stages"),
])
def test_a_curriculum_that_cannot_work_is_refused_naming_the_key(curriculum, reason):
    with pytest.raises(ConfigError) as error:
        small(curriculum=curriculum)
    assert error.value.key == "curriculum" and reason in str(error.value)


def test_driving_has_no_curriculum_and_bad_overrides_are_refused_by_the_cli(tmp_path, capsys):
    with pytest.raises(ConfigError) as error:
        TrainConfig(scenario="driving", curriculum=[{"start": "kickoff"}])
    assert error.value.key == "curriculum"
    code = main(["--config", "quick", "--run-dir", str(tmp_path / "run"), "--no-progress",
                 "--set", "curriculum=[{until: 100, start: attack, ball_distance: [4, 2]}, {start: kickoff}]"])
    assert code == 2 and "curriculum: stage 0: ball_distance [4, 2] is inverted" in capsys.readouterr().err
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_learning_from_messages_or_bags_refuses_a_curriculum_it_could_not_follow(tmp_path):
    with pytest.raises(ConfigError) as error:
        MessageTrainer(small(curriculum=TWO_STAGES), tmp_path / "run", log=False)
    assert error.value.key == "curriculum" and not (tmp_path / "run").exists()


def test_a_curriculum_survives_json_and_a_set_override():
    cfg = small(curriculum=TWO_STAGES)
    again = TrainConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg and again.curriculum[0].ball_distance == (1.0, 3.0)
    flow = load_config(None, ["curriculum=[{until: 12, start: attack, ball_distance: [1.0, 3.0], defenders: absent, "
                              "episode_seconds: 4.0}, {start: kickoff, episode_seconds: 4.0}]"], base=small())
    assert flow == cfg


def test_the_preset_is_the_pure_rl_async_setting_with_the_stated_stages():
    cfg = load_config(ROOT / "config/train/async_curriculum.yaml")
    plain = load_config(ROOT / "config/train/async.yaml")
    assert cfg.replace(curriculum=None) == plain            # the async preset's pure-RL setting, its budget too
    assert (cfg.teacher, cfg.localization, cfg.opponent, cfg.players_per_team, cfg.perception, cfg.variant) == \
        (None, "none", "self", 2, "realistic", "pred")
    stages = [(s.until, s.start, s.ball_distance, s.defenders, s.episode_seconds) for s in cfg.curriculum]
    assert stages == [(300_000, "attack", (1.0, 3.0), "absent", 20.0), (600_000, "attack", (2.0, 6.0), "absent", 30.0),
                      (900_000, "attack", (2.0, 6.0), "present", 30.0), (None, "kickoff", None, None, None)]
    assert cfg.total_env_steps == 2_880_000


def test_the_mixed_preset_is_async_curriculum_with_a_mixed_last_stage_a_shorter_budget_and_kept_policies():
    cfg = load_config(ROOT / "config/train/async_curriculum_mix.yaml")
    plain = load_config(ROOT / "config/train/async_curriculum.yaml")
    assert cfg.curriculum[:3] == plain.curriculum[:3]
    last = cfg.curriculum[3]
    assert (last.until, last.start, last.ball_distance, last.defenders, last.kickoff_share, last.episode_seconds) == \
        (None, "attack", (2.0, 6.0), "present", 0.5, 120.0)
    assert (cfg.total_env_steps, cfg.keep_policy_every_env_steps) == (1_500_000, 250_000)
    assert cfg.replace(curriculum=plain.curriculum, total_env_steps=plain.total_env_steps,
                       keep_policy_every_env_steps=None) == plain


def _world_starts(worker: RolloutWorker) -> list[tuple[str, int]]:
    return [(w.config.start.kind, w.episode_id) for w in worker.worlds.env._batch.worlds]


def test_a_workers_worlds_change_stage_only_between_episodes():
    """Rollouts of 3 periods, 4-s episodes of 8: the learner's env steps pass the first stage's end (12) while every
    world is 6 periods into its first episode; the worlds finish it as attacks and start the next as kickoffs."""
    cfg = small(curriculum=[{**TWO_STAGES[0], "until": 12}, TWO_STAGES[1]])
    worker = RolloutWorker(cfg, 0, 0, 2)
    worker.adopt(0)
    try:
        _, info = worker.collect(0)                                  # periods 1-3 of episode 1
        assert info["curriculum_stage"] == 0 and _world_starts(worker) == [("attack", 1)] * 2
        _, info = worker.collect(12)                                 # told stage 1; periods 4-6
        assert info["curriculum_stage"] == 1 and _world_starts(worker) == [("attack", 1)] * 2
        worker.collect(12)                                           # periods 7-9: episode 2 from period 9
        assert _world_starts(worker) == [("kickoff", 2)] * 2
        assert all(w.ball_xy == pytest.approx((0.0, 0.0), abs=1e-6) for w in worker.worlds.env._batch.worlds)
    finally:
        worker.close()


def _metrics(run_dir: Path, name: str) -> list[tuple[int, float]]:
    with open(run_dir / "metrics.csv", newline="") as f:
        return [(int(row["env_steps"]), float(row["value"])) for row in csv.DictReader(f) if row["name"] == name]


def _meta(run_dir: Path) -> dict:
    """The run's metadata in its latest checkpoint."""
    latest = (run_dir / "checkpoints" / "latest").read_text().strip()
    return json.loads((run_dir / "checkpoints" / latest / "meta.json").read_text())["meta"]


def test_a_run_logs_the_stage_saves_it_and_goes_on_in_it_after_resume(tmp_path):
    """Two worlds x 3 periods = 6 env steps an update: stage 0 until 12, logged after each update at its env steps;
    the checkpoint at 18 records stage 1; the resumed run's worlds start in stage 1 (kickoffs), and it says so."""
    run_dir = tmp_path / "run"
    cfg = small(curriculum=TWO_STAGES, total_env_steps=18)
    Trainer(cfg, run_dir, progress=False).run()
    assert _metrics(run_dir, "curriculum/stage") == [(6, 0.0), (12, 1.0), (18, 1.0)]
    assert _meta(run_dir)["curriculum_stage"] == 1 and _meta(run_dir)["env_steps"] == 18
    lines: list[str] = []
    resumed = Trainer(cfg.replace(total_env_steps=24), run_dir, resume=True, progress=False, log=lines.append)
    assert lines == ["resuming at 18 env steps in curriculum stage 1 (of 0..1)"]
    worlds = resumed.source.worlds
    assert worlds.stage == 1 and all(w.config.start.kind == "kickoff" for w in worlds.env._batch.worlds)
    resumed.run()
    assert _metrics(run_dir, "curriculum/stage")[-1] == (24, 1.0)
    # a curriculum changed at --resume: its own stage at the saved env steps, and a line saying so
    lines.clear()
    longer = cfg.replace(total_env_steps=30, curriculum=[{**TWO_STAGES[0], "until": 100}, TWO_STAGES[1]])
    again = Trainer(longer, run_dir, resume=True, progress=False, log=lines.append)
    assert lines == ["the checkpoint was in curriculum stage 1; this run's curriculum puts 24 env steps in stage 0 "
                     "(of 0..1): going on there"]
    assert all(w.config.start.kind == "attack" for w in again.source.worlds.env._batch.worlds)
    again.close()


def test_a_worker_process_started_for_a_resumed_run_starts_in_its_stage():
    cfg = small(runner="async", workers=1, curriculum=TWO_STAGES, backend="auto")
    torch.manual_seed(0)
    networks = TrainingNetworks(make_agent(cfg), cfg.ltp_horizon)
    pool = ProcessPool(cfg, networks, workers=1, first_update=3, log=lambda line: None, first_env_steps=18)
    try:
        delivery = pool.get(timeout=120)
        while delivery is None:
            delivery = pool.get(timeout=120)
        assert delivery.info["curriculum_stage"] == 1
        pool.release(delivery, 18)
    finally:
        pool.close()


def test_the_async_curriculum_preset_trains_across_a_stage_end(tmp_path, capsys):
    """dynenv-train --config async_curriculum with the stage ends scaled down by --set: two worlds, one worker, 32 env
    steps an update, the first stage ending at 32; three updates."""
    run_dir = tmp_path / "run"
    code = main(["--config", "async_curriculum", "--run-dir", str(run_dir), "--no-progress",
                 "--set", "num_envs=2", "--set", "workers=1", "--set", "total_env_steps=96",
                 "--set", "log_every_updates=1",
                 "--set", "curriculum=[{until: 32, start: attack, ball_distance: [1.0, 3.0], defenders: absent, "
                          "episode_seconds: 4}, {until: 64, start: attack, ball_distance: [2.0, 6.0], "
                          "defenders: present, episode_seconds: 4}, {start: kickoff}]"])
    assert code == 0, capsys.readouterr().err
    stages = _metrics(run_dir, "curriculum/stage")
    assert [stage for _, stage in stages] == [1.0, 2.0, 2.0] and [n for n, _ in stages] == [32, 64, 96]
    assert _meta(run_dir)["curriculum_stage"] == 2
    config = json.loads((run_dir / "config.json").read_text())
    assert config["curriculum"][0] == {"until": 32, "start": "attack", "ball_distance": [1.0, 3.0],
                                       "defenders": "absent", "episode_seconds": 4.0}


def test_the_mixed_preset_trains_and_keeps_a_policy_at_each_mark(tmp_path, capsys):
    """dynenv-train --config async_curriculum_mix scaled down: 32 env steps an update, a policy kept every 64 env
    steps, 160 in all: marks 64 and 128 are passed (at 64 and 128), 192 is not."""
    from dynenv_ros.agent.checkpoint import load_policy
    run_dir = tmp_path / "run"
    code = main(["--config", "async_curriculum_mix", "--run-dir", str(run_dir), "--no-progress",
                 "--set", "num_envs=2", "--set", "workers=1", "--set", "total_env_steps=160",
                 "--set", "keep_policy_every_env_steps=64",
                 "--set", "curriculum=[{until: 32, start: attack, defenders: absent, episode_seconds: 4}, "
                          "{start: attack, kickoff_share: 0.5, episode_seconds: 4}]"])
    assert code == 0, capsys.readouterr().err
    kept = sorted(p.name for p in (run_dir / "kept_policies").iterdir())
    assert kept == ["step_000000000064.safetensors", "step_000000000128.safetensors"]
    _, meta = load_policy(run_dir / "kept_policies" / kept[1])
    assert meta["kept_at_mark"] == 128 and meta["config"]["keep_policy_every_env_steps"] == 64
