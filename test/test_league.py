"""The league opponent: PFSP weights as Vinyals et al. (2019) define them ((1 − s)², here with a floor), the
scores it keeps, the worlds playing the drawn member, and a training run against it."""
from __future__ import annotations

import numpy as np
import pytest

from dynenv_ros.envs.league import LEAGUE_MEMBERS, League, pfsp_weights
from dynenv_ros.envs.vector import SoccerVectorEnv
from dynenv_ros.learning.config import ConfigError, TrainConfig
from dynenv_ros.learning.trainer import Trainer
from dynenv_ros.soccer.scripted import team_policies


def test_pfsp_weights_are_the_hard_weighting_with_a_floor():
    # scores 0, ½, 1, ½: (1 − s)² = 1, ¼, 0, ¼ → 2/3, 1/6, 0, 1/6; with floor 0.05 over 4 members:
    # 0.05 + 0.8·p → 0.5833, 0.1833, 0.05, 0.1833
    w = pfsp_weights(np.array([0.0, 0.5, 1.0, 0.5]), floor=0.05)
    assert w == pytest.approx([0.05 + 0.8 * 2 / 3, 0.05 + 0.8 / 6, 0.05, 0.05 + 0.8 / 6])
    assert w.sum() == pytest.approx(1.0)
    assert pfsp_weights(np.ones(3), floor=0.1) == pytest.approx([1 / 3] * 3)   # all beaten: uniform


def test_the_score_is_a_running_mean_then_a_moving_average():
    league = League(("perceiving", "snapshot"), np.random.default_rng(0), memory=4)
    league.record("perceiving", 1, 0)          # 1 game: mean 1
    assert league.scores[0] == pytest.approx(1.0)
    league.record("perceiving", 0, 0)          # 2 games: (1 + ½)/2
    assert league.scores[0] == pytest.approx(0.75)
    for _ in range(2):
        league.record("perceiving", 0, 2)      # 3 games: 0.5; 4 games: 0.375
    assert league.scores[0] == pytest.approx(0.375)
    league.record("perceiving", 0, 1)          # past memory 4: s += ¼ (0 − s)
    assert league.scores[0] == pytest.approx(0.375 * 0.75)
    assert league.scores[1] == pytest.approx(0.5) and league.games.tolist() == [5, 0]


def test_the_opponent_the_learner_loses_to_is_drawn_most():
    league = League(LEAGUE_MEMBERS, np.random.default_rng(1))
    for _ in range(20):
        league.record("perceiving", 0, 1)
        league.record("perceiving_chasers", 1, 0)
        league.record("keeper_and_chasers", 1, 0)
        league.record("snapshot", 1, 0)
    draws = [league.draw() for _ in range(4000)]
    share = draws.count("perceiving") / len(draws)
    expected = pfsp_weights(league.scores)[0]
    assert expected > 0.8
    assert share == pytest.approx(expected, abs=4 * np.sqrt(expected * (1 - expected) / len(draws)))
    with pytest.raises(ValueError, match="league members"):
        League(("nobody",), np.random.default_rng(0))


def test_league_worlds_play_the_drawn_member_and_score_its_games():
    env = SoccerVectorEnv(3, backend="inprocess", config={"players_per_team": 1, "episode_seconds": 4},
                          scripted_team_b="league")
    env.reset(seed=5)
    batch = env._batch
    drawn = set()
    for _ in range(40):                       # 8 periods an episode: 5 episodes per world
        drawn.update(batch._team_b)
        env.step(np.zeros((3, 2, 4), np.int64))
    stats = env.league_stats()
    assert sum(stats[f"league/{m}_games"] for m in LEAGUE_MEMBERS) == 15
    assert drawn <= set(LEAGUE_MEMBERS) and len(drawn) >= 2
    assert sum(stats[f"league/{m}_share"] for m in LEAGUE_MEMBERS) == pytest.approx(1.0)
    env.close()


def test_a_ground_truth_member_moves_team_b_and_the_snapshot_member_takes_the_callers_rows():
    env = SoccerVectorEnv(1, backend="inprocess", config={"players_per_team": 1}, scripted_team_b="league")
    env.reset(seed=0)
    batch = env._batch
    standing = [0, 0, 0, 0]
    batch._team_b[0] = "snapshot"
    assert batch._with_team_b(0, [standing, [1, 0, 0, 0]])[1] == [1, 0, 0, 0]
    batch._team_b[0] = "keeper_and_chasers"
    scripted = batch._with_team_b(0, [standing, standing])[1]
    # what the ground-truth team's robot 1 does in this state, asked of a fresh copy of that team
    fresh = team_policies(1, "keeper_and_chasers", field=batch.config.field, head_mode=batch.config.head_mode,
                          motion=batch.config.motion)
    assert scripted == fresh[1].act(batch.worlds[0].snapshot(), 1)
    assert int(scripted.walk) != 0             # at kick-off the chaser walks to the ball
    env.close()


SMALL = {"algorithm": "ppo", "variant": "baseline", "players_per_team": 1, "num_envs": 2, "perception": "realistic",
         "rollout_length": 4, "ltp_horizon": 2, "feature_size": 16, "ppo_epochs": 1, "ppo_minibatches": 1,
         "log_every_updates": 1, "checkpoint_every_minutes": 10.0, "opponent": "league",
         "snapshot_every_updates": 2, "episode_seconds": 2.0}


@pytest.mark.parametrize("runner", ["sync", "async"])
def test_a_run_against_the_league_trains_and_logs_the_members(tmp_path, runner):
    extra = {"backend": "inprocess"} if runner == "sync" else {"runner": "async", "workers": 1}
    cfg = TrainConfig(**{**SMALL, **extra, "total_env_steps": 48})
    summary = Trainer(cfg, tmp_path, progress=False).run()
    assert summary["env_steps"] >= 48
    logged = (tmp_path / "metrics.csv").read_text()
    for member in LEAGUE_MEMBERS:
        assert f"league/{member}_share" in logged


def test_team_sizes_give_each_worker_its_size_with_one_layout(tmp_path):
    from dynenv_ros.envs.padded_layout import EXTRA_OBJECT_SLOTS
    from dynenv_ros.learning.distributed.rollout_worker import RolloutWorker, resolve_workers, shard_sizes
    cfg = TrainConfig(**{**SMALL, "runner": "async", "opponent": "perceiving", "players_per_team": 1,
                         "team_sizes": [1, 3], "workers": 2, "num_envs": 2})
    shapes = []
    for index, (first, count) in enumerate(shard_sizes(cfg.num_envs, 2)):
        worker = RolloutWorker(cfg, index, first, count)
        worker.adopt(0)
        shapes.append(worker.layout_shapes)
        arrays, _ = worker.collect(0)
        robots = worker.worlds.env.config.players_per_team
        assert robots == (1, 3)[index]
        worker.close()
    # every worker pads its objects to the largest size's: the ball and the 2 x 3 - 1 other robots, plus extra slots
    assert shapes[0] == shapes[1] and shapes[0]["objects"][1] == 2 * 3 + EXTRA_OBJECT_SLOTS
    assert resolve_workers(TrainConfig(**{**SMALL, "runner": "async", "team_sizes": [1, 2], "workers": None}),
                           cores=2) == 2


def test_team_sizes_need_the_async_runner_a_worker_each_and_players_per_team_among_them():
    with pytest.raises(ConfigError, match="team_sizes"):
        TrainConfig(**{**SMALL, "team_sizes": [1, 2], "backend": "inprocess"})
    with pytest.raises(ConfigError, match="team_sizes"):
        TrainConfig(**{**SMALL, "runner": "async", "team_sizes": [2, 3]})
    with pytest.raises(ConfigError, match="workers"):
        TrainConfig(**{**SMALL, "runner": "async", "team_sizes": [1, 2], "workers": 1})
    with pytest.raises(ConfigError, match="distinct"):
        TrainConfig(**{**SMALL, "runner": "async", "team_sizes": [1, 1]})


def test_a_run_over_two_team_sizes_trains(tmp_path):
    cfg = TrainConfig(**{**SMALL, "runner": "async", "team_sizes": [1, 2], "workers": 2, "total_env_steps": 48})
    summary = Trainer(cfg, tmp_path, progress=False).run()
    assert summary["env_steps"] >= 48 and summary["worker_deaths"] == 0


# -- the league across --resume: the trainer checkpoints each worker's league (scores and game counts) -----------

def test_a_league_state_round_trips_and_a_misfit_changes_nothing():
    league = League(LEAGUE_MEMBERS, np.random.default_rng(0))
    for _ in range(3):
        league.record("perceiving", 0, 1)
    league.record("snapshot", 2, 0)
    again = League(LEAGUE_MEMBERS, np.random.default_rng(1))
    again.restore(league.state())
    # 3 losses: running mean ½ → 0 after the first game (rate 1), so 0; one win against the snapshot: 1
    assert again.scores.tolist() == [0.0, 0.5, 0.5, 1.0] and again.games.tolist() == [3, 0, 0, 1]
    bad = [{**league.state(), "members": ["perceiving", "snapshot"]},
           {**league.state(), "scores": [0.0, 0.5, 1.5, 1.0]},
           {**league.state(), "scores": [0.0, float("nan"), 0.5, 1.0]},
           {**league.state(), "games": [3, -1, 0, 1]},
           {**league.state(), "games": [3, 0.5, 0, 1]},
           {**league.state(), "games": [3, 0, 0]},
           {"members": list(LEAGUE_MEMBERS)}]
    fresh = League(LEAGUE_MEMBERS, np.random.default_rng(2))
    for state in bad:
        with pytest.raises(ValueError, match="league"):
            fresh.restore(state)
        assert fresh.scores.tolist() == [0.5] * 4 and fresh.games.tolist() == [0] * 4


def test_league_worlds_carry_on_a_given_league_before_or_after_reset():
    saved = {"members": list(LEAGUE_MEMBERS), "scores": [0.1, 0.2, 0.3, 0.9], "games": [50, 40, 30, 20]}
    env = SoccerVectorEnv(1, backend="inprocess", config={"players_per_team": 1}, scripted_team_b="league")
    env.start_league_from(saved)              # before reset: the league is made there
    env.reset(seed=0)
    assert env.league_state() == saved
    env.start_league_from({**saved, "scores": [0.5] * 4})     # after: at once
    assert env.league_state()["scores"] == [0.5] * 4
    env.close()
    plain = SoccerVectorEnv(1, backend="inprocess", config={"players_per_team": 1}, scripted_team_b="perceiving")
    with pytest.raises(ValueError, match="not the league"):
        plain.start_league_from(saved)
    plain.close()


def _checkpoint_league(run_dir) -> dict:
    import json
    latest = (run_dir / "checkpoints" / "latest").read_text().strip()
    return json.loads((run_dir / "checkpoints" / latest / "meta.json").read_text())["meta"].get("league", {})


@pytest.mark.parametrize("runner", ["sync", "async"])
def test_a_resumed_league_run_carries_on_each_workers_league(tmp_path, runner):
    """Two worlds of 2-second episodes (5 periods each): 48 env steps play about ten games, all checkpointed; one
    more update after --resume plays at most a game or two, so a league started again from nothing would hold far
    fewer games than the checkpoint's."""
    extra = {"backend": "inprocess"} if runner == "sync" else {"runner": "async", "workers": 1}
    cfg = TrainConfig(**{**SMALL, **extra, "total_env_steps": 48})
    Trainer(cfg, tmp_path, progress=False).run()
    saved = _checkpoint_league(tmp_path)
    assert list(saved) == ["0"] and saved["0"]["members"] == list(LEAGUE_MEMBERS)
    saved_games = sum(saved["0"]["games"])
    assert saved_games >= 6
    lines: list[str] = []
    resumed = Trainer(cfg.replace(total_env_steps=56), tmp_path, resume=True, progress=False, log=lines.append)
    assert "resuming the league of 1 worker(s) from the checkpoint" in lines
    resumed.run()
    after = _checkpoint_league(tmp_path)["0"]
    assert sum(after["games"]) >= saved_games
    assert all(a >= s for a, s in zip(after["games"], saved["0"]["games"]))


def test_a_checkpoint_whose_league_does_not_fit_stops_the_resume_with_the_reason(tmp_path):
    import json
    cfg = TrainConfig(**{**SMALL, "backend": "inprocess", "total_env_steps": 8})
    Trainer(cfg, tmp_path, progress=False).run()
    latest = tmp_path / "checkpoints" / (tmp_path / "checkpoints" / "latest").read_text().strip()
    record = json.loads((latest / "meta.json").read_text())
    record["meta"]["league"] = {"0": {"members": ["perceiving"], "scores": [0.5], "games": [1]}}
    (latest / "meta.json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match="worker 0's league"):
        Trainer(cfg.replace(total_env_steps=16), tmp_path, resume=True, progress=False)


def test_league_members_narrow_the_draws_and_are_checked():
    env = SoccerVectorEnv(2, backend="inprocess", config={"players_per_team": 1, "episode_seconds": 2},
                          scripted_team_b="league", league_members=["perceiving", "keeper_and_chasers"])
    env.reset(seed=3)
    drawn = set()
    for _ in range(30):                       # 5 periods an episode: 6 episodes per world
        drawn.update(env._batch._team_b)
        env.step(np.zeros((2, 2, 4), np.int64))
    assert drawn == {"perceiving", "keeper_and_chasers"}
    assert env.league_state()["members"] == ["perceiving", "keeper_and_chasers"]
    with pytest.raises(ValueError, match="members"):       # a full league's state does not fit this one
        env.start_league_from({"members": list(LEAGUE_MEMBERS), "scores": [0.5] * 4, "games": [0] * 4})
    env.close()
    with pytest.raises(ValueError, match="league members"):
        SoccerVectorEnv(1, backend="inprocess", config={"players_per_team": 1}, scripted_team_b="league",
                        league_members=["perceiving", "nobody"])
    with pytest.raises(ValueError, match="league_members"):
        SoccerVectorEnv(1, backend="inprocess", config={"players_per_team": 1}, scripted_team_b="perceiving",
                        league_members=["perceiving"])
    with pytest.raises(ConfigError, match="league_members"):
        TrainConfig(**{**SMALL, "league_members": ["perceiving", "nobody"]})
    with pytest.raises(ConfigError, match="league_members"):
        TrainConfig(**{**SMALL, "league_members": ["perceiving", "perceiving"]})
    with pytest.raises(ConfigError, match="league_members"):
        TrainConfig(**{**SMALL, "opponent": "perceiving", "league_members": ["perceiving"]})
    assert TrainConfig(**{**SMALL, "league_members": ["snapshot"]}).league_members == ("snapshot",)
