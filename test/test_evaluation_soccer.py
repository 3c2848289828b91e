"""dynenv-eval: team policies on either side, reproducible seeding, bookkeeping identities, the paper's metric."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from dynenv_ros.agent.checkpoint import save_policy
from dynenv_ros.agent.network import DynEnvAgent
from dynenv_ros.envs.robocup_v0 import parallel_env
from dynenv_ros.evaluation.best import seed_values
from dynenv_ros.evaluation.cli import main
from dynenv_ros.evaluation.episodes import episode_seeds
from dynenv_ros.evaluation.results import FORMAT, TERMS, load_evaluation, write_json
from dynenv_ros.evaluation.soccer import (SEED_METRICS, AgentTeam, RandomTeam, ScriptedTeam, evaluate, format_table,
                                          make_team_policy, paper_metric, play_episode, positive_reward)

SHORT = {"episode_seconds": 5.0}          # 10 motion periods


def untrained_agent(seed: int = 0) -> DynEnvAgent:
    torch.manual_seed(seed)
    return DynEnvAgent()


# -- the paper's metric ------------------------------------------------------------------------------------------
def test_paper_metric_is_positive_reward_minus_observation_reward_from_written_terms():
    steps = [{"primary": 2.5, "rule": 0.0, "auxiliary": -0.3, "observation": 0.05},
             {"primary": -2.5, "rule": -2.0, "auxiliary": 0.4, "observation": 0.0525},
             {"primary": 0.0, "rule": 0.0, "auxiliary": 0.1, "observation": 0.0}]
    # positive parts per term and step: 2.5 + 0.05 | 0.4 + 0.0525 | 0.1
    assert positive_reward(steps) == pytest.approx(3.1025)
    # minus the observation reward 0.05 + 0.0525 + 0.0
    assert paper_metric(steps) == pytest.approx(3.0)
    assert paper_metric([]) == 0.0


def test_episode_record_metric_matches_the_per_step_definition():
    """play_episode's per-side numbers equal the definitions applied to the env's per-step reward terms."""
    env = parallel_env(players_per_team=1, observation="padded", perception="realistic", **SHORT)
    env_seed, seed_a, seed_b = episode_seeds(0, 0)
    out = play_episode(env, ScriptedTeam("chaser"), RandomTeam(), env_seed, seed_a, seed_b)
    # replay the same episode by hand, keeping every step's terms
    env2 = parallel_env(players_per_team=1, observation="padded", perception="realistic", **SHORT)
    a, b = ScriptedTeam("chaser"), RandomTeam()
    obs, _ = env2.reset(seed=env_seed)
    a.reset(env2, [0], seed_a)
    b.reset(env2, [1], seed_b)
    steps: dict[str, list] = {name: [] for name in env2.possible_agents}
    while env2.agents:
        names = env2.possible_agents
        actions = {names[0]: a.act(env2, [obs[names[0]]])[0], names[1]: b.act(env2, [obs[names[1]]])[0]}
        obs, _, _, _, infos = env2.step(actions)
        for name in names:
            steps[name].append(dict(infos[name]["reward_terms"]))
    for side, name in (("a", "team_a_0"), ("b", "team_b_0")):
        assert out[side]["paper_metric"] == pytest.approx(paper_metric(steps[name]))
        assert out[side]["positive"] == pytest.approx(positive_reward(steps[name]))
        for term in TERMS:
            assert out[side]["terms"][term] == pytest.approx(sum(s[term] for s in steps[name]))
    assert out["periods"] == 10


# -- bookkeeping -------------------------------------------------------------------------------------------------
def test_bookkeeping_identities():
    result = evaluate("chaser", "random", episodes=3, seeds=[0, 5], players_per_team=2, perception="none",
                      env_config={"episode_seconds": 20.0})
    records = result["episodes"]
    assert len(records) == 6 and result["counts"]["episodes"] == 6
    counts = result["counts"]
    assert counts["wins"] + counts["draws"] + counts["losses"] == 6
    for r in records:
        assert r["total"] == pytest.approx(sum(r["terms"].values()))
        assert r["opponent"]["total"] == pytest.approx(sum(r["opponent"]["terms"].values()))
        assert r["paper_metric"] == pytest.approx(r["positive"] - r["terms"]["observation"])
        assert r["result"] == ("win" if r["goals_for"] > r["goals_against"] else
                               "loss" if r["goals_for"] < r["goals_against"] else "draw")
        assert r["periods"] == 40
    for row in result["per_seed"]:
        assert set(SEED_METRICS) <= set(row)
        assert row["win_rate"] + row["draw_rate"] + row["loss_rate"] == pytest.approx(1.0)
        mine = [r for r in records if r["seed"] == row["seed"]]
        assert row["total"] == pytest.approx(np.mean([r["total"] for r in mine]))
        assert row["goal_difference"] == pytest.approx(row["goals_for"] - row["goals_against"])
    assert result["summary"]["total"]["mean"] == pytest.approx(np.mean([row["total"] for row in result["per_seed"]]))
    assert seed_values(result, "total") == [row["total"] for row in result["per_seed"]]
    table = format_table(result)
    assert table.count("\n| ") == 4 and "mean ± sd" in table     # header, 2 seeds, the mean row


def test_goals_for_of_one_side_are_goals_against_of_the_other_and_falls_come_from_events():
    env = parallel_env(players_per_team=2, observation="padded", perception="none", episode_seconds=60.0)
    env_seed, seed_a, seed_b = episode_seeds(1, 0)
    out = play_episode(env, ScriptedTeam("chaser"), RandomTeam(), env_seed, seed_a, seed_b)
    assert out["a"]["goals_for"] == out["b"]["goals_against"] == env.world.snapshot().score_team_a
    assert out["b"]["goals_for"] == out["a"]["goals_against"] == env.world.snapshot().score_team_b
    assert out["a"]["goals_for"] >= 1
    for side in "ab":
        assert out[side]["falls"] >= 0 and out[side]["penalties"] >= 0


def test_falls_and_penalties_are_counted_per_team(monkeypatch):
    """A fall and a penalty event of a team-B robot count for team B only."""
    from dynenv_ros.sim.scenario import GameEvent
    env = parallel_env(players_per_team=1, observation="padded", perception="none", episode_seconds=1.0)
    real_step = env.step

    def step(actions):
        out = real_step(actions)
        env.world.events = [GameEvent("fall", 0, robot=1, team=-1), GameEvent("penalty", 0, robot=1, team=-1),
                            GameEvent("fall", 0, robot=1, team=-1), GameEvent("goal", 0, team=1)]
        return out
    monkeypatch.setattr(env, "step", step)
    env_seed, seed_a, seed_b = episode_seeds(0, 0)
    out = play_episode(env, RandomTeam(), RandomTeam(), env_seed, seed_a, seed_b)
    assert (out["a"]["falls"], out["a"]["penalties"]) == (0, 0)
    assert (out["b"]["falls"], out["b"]["penalties"]) == (2 * out["periods"], out["periods"])


def test_chaser_team_beats_random_team_on_either_side():
    """Verified over 20 episodes of 60 s (seeds 0-9): the chasers score in most and never concede."""
    result = evaluate("chaser", "random", episodes=2, seeds=[0, 1], perception="none",
                      env_config={"episode_seconds": 60.0})
    records = result["episodes"]
    assert [r["side"] for r in records] == ["a", "b", "a", "b"]
    assert all(r["goals_for"] >= r["goals_against"] for r in records)
    assert sum(r["goals_for"] for r in records) > sum(r["goals_against"] for r in records)
    assert result["counts"]["losses"] == 0


# -- sides -------------------------------------------------------------------------------------------------------
def test_sides_alternate_and_swapping_the_teams_mirrors_the_records():
    kw = dict(episodes=2, seeds=[2], perception="none", env_config={"episode_seconds": 15.0})
    alternate = evaluate("chaser", "keeper_and_chasers", **kw)
    as_a = evaluate("chaser", "keeper_and_chasers", sides="a", **kw)
    as_b = evaluate("chaser", "keeper_and_chasers", sides="b", **kw)
    mirror = evaluate("keeper_and_chasers", "chaser", sides="b", **kw)   # the chasers on A, seen from B
    assert [r["side"] for r in alternate["episodes"]] == ["a", "b"]
    assert {r["side"] for r in as_a["episodes"]} == {"a"} and {r["side"] for r in as_b["episodes"]} == {"b"}
    assert alternate["episodes"][0] == as_a["episodes"][0]
    assert alternate["episodes"][1] == as_b["episodes"][1]
    for mine, theirs in zip(as_a["episodes"], mirror["episodes"]):
        assert mine["env_seed"] == theirs["env_seed"]
        assert (mine["goals_for"], mine["goals_against"]) == (theirs["goals_against"], theirs["goals_for"])
        assert mine["terms"] == theirs["opponent"]["terms"]
        assert mine["total"] == theirs["opponent"]["total"]
        assert mine["falls"] == theirs["opponent"]["falls"]


# -- seeding -----------------------------------------------------------------------------------------------------
def test_same_call_gives_the_same_json_and_other_seeds_differ():
    def run(seeds):
        result = evaluate(AgentTeam(untrained_agent()), "random", episodes=2, seeds=seeds, players_per_team=1,
                          perception="realistic", env_config={"episode_seconds": 2.5})
        return json.dumps(result, sort_keys=True)
    first = run([3])
    assert run([3]) == first
    assert run([4]) != first
    env_seed, ours, theirs = episode_seeds(3, 1)
    assert episode_seeds(3, 1)[0] == env_seed and env_seed != episode_seeds(3, 0)[0] != episode_seeds(4, 1)[0]
    assert ours.generate_state(2).tolist() != theirs.generate_state(2).tolist()


def test_untrained_agent_plays_on_both_sides_and_greedy_is_deterministic():
    result = evaluate(AgentTeam(untrained_agent(1)), AgentTeam(untrained_agent(2), greedy=True), episodes=2,
                      seeds=[0], players_per_team=2, env_config=SHORT)
    assert [r["side"] for r in result["episodes"]] == ["a", "b"]
    assert all(r["periods"] == 10 for r in result["episodes"])
    assert result["evaluated"]["kind"] == result["opponent"]["kind"] == "checkpoint"
    assert result["opponent"]["greedy"] is True
    # the recurrent state is reset at episode start: an episode's record does not depend on what came before
    alone = evaluate(AgentTeam(untrained_agent(1)), AgentTeam(untrained_agent(2), greedy=True), episodes=2,
                     seeds=[0], sides="b", env_config=SHORT)
    assert alone["episodes"][1] == result["episodes"][1]


def test_games_played_at_once_give_the_records_of_games_played_one_by_one(monkeypatch):
    """games_at_once plays the same games: each keeps its env seed and its teams' generators, whatever is played
    beside it (sampled actions, so the generators matter; one game more than fits in one round, so the last round
    is a smaller one; both sides checkpoints, so one forward serves both teams of a game)."""
    forwards = []
    real = DynEnvAgent.forward

    def counted(self, landmarks, *args):
        forwards.append(landmarks.mask.shape[0])
        return real(self, landmarks, *args)
    monkeypatch.setattr(DynEnvAgent, "forward", counted)

    def run(at_once, opponent):
        forwards.clear()
        return evaluate(AgentTeam(untrained_agent(1)), opponent, episodes=2, seeds=[5, 6, 7], players_per_team=2,
                        perception="realistic", env_config=SHORT, games_at_once=at_once)
    one_by_one = run(1, "perceiving")
    assert forwards == [2] * 6 * 10                 # a team of two a period, 10 periods, 6 games
    together = run(4, "perceiving")
    assert forwards == [8] * 10 + [4] * 10          # four games, then the two left
    assert together["episodes"] == one_by_one["episodes"]
    assert together["settings"]["games_at_once"] == 4 and "games_at_once" not in one_by_one["settings"]
    both_sides = run(6, AgentTeam(untrained_agent(1), greedy=True))
    assert forwards == [12, 12] * 10                # each network: its six teams of two in one forward
    assert both_sides["episodes"] == run(1, AgentTeam(untrained_agent(1), greedy=True))["episodes"]
    with pytest.raises(ValueError, match="games_at_once"):
        evaluate("random", "random", episodes=1, seeds=[0], games_at_once=0)


def test_random_team_samples_the_continuous_head_space():
    result = evaluate("random", "chaser", episodes=1, seeds=[0], players_per_team=1, perception="none",
                      env_config={"episode_seconds": 2.0, "head_mode": "continuous"})
    assert result["episodes"][0]["periods"] == 4


def test_policy_specs_and_bad_settings():
    assert isinstance(make_team_policy("random"), RandomTeam)
    scripted = make_team_policy("scripted")
    assert isinstance(scripted, ScriptedTeam) and scripted.team == "keeper_and_chasers"
    assert make_team_policy("chaser").team == "chaser"
    with pytest.raises(ValueError, match="does not exist"):
        make_team_policy("no_such_policy.safetensors")
    with pytest.raises(ValueError, match="episodes"):
        evaluate("random", "random", episodes=0, seeds=[0])
    with pytest.raises(ValueError, match="non-negative"):
        evaluate("random", "random", episodes=1, seeds=[-1])
    with pytest.raises(ValueError, match="distinct"):
        evaluate("random", "random", episodes=1, seeds=[1, 1])
    with pytest.raises(ValueError, match="sides"):
        evaluate("random", "random", episodes=1, seeds=[1], sides="c")
    team = RandomTeam()
    with pytest.raises(ValueError, match="two TeamPolicy instances"):
        evaluate(team, team, episodes=1, seeds=[0])


# -- output and CLI ----------------------------------------------------------------------------------------------
def test_json_round_trip(tmp_path):
    result = evaluate("random", "scripted", episodes=1, seeds=[0, 1], perception="none", env_config=SHORT)
    write_json(result, tmp_path / "r.json")
    loaded = load_evaluation(tmp_path / "r.json")
    assert loaded == json.loads(json.dumps(result)) and loaded["format"] == FORMAT
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="not readable JSON"):
        load_evaluation(tmp_path / "bad.json")
    (tmp_path / "other.json").write_text("{}")
    with pytest.raises(ValueError, match=FORMAT):
        load_evaluation(tmp_path / "other.json")


def _exit_code(argv) -> int:
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


@pytest.mark.parametrize("argv", [["missing.safetensors"], ["random", "--opponent", "missing.safetensors"],
                                  ["CORRUPT"], ["random", "--episodes", "0"], ["random", "--episodes", "x"],
                                  ["random", "--perception", "perfect"], ["random", "--seeds", "-3"],
                                  ["random", "--out", "no/such/folder/r.json"], ["random", "--games-at-once", "0"],
                                  ["random", "--scenario", "driving", "--games-at-once", "2"]])
def test_cli_bad_arguments_exit_2_with_one_line(argv, tmp_path, capsys):
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(b"\x00\x01 this is not a policy file")
    argv = [str(corrupt) if a == "CORRUPT" else a for a in argv]
    assert _exit_code(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("dynenv-eval") and err.count("\n") == 1 and "Traceback" not in err


def test_cli_checkpoint_against_itself_and_random_baseline(tmp_path, capsys):
    policy = tmp_path / "agent.safetensors"
    save_policy(untrained_agent(), policy)
    out = tmp_path / "agent.json"
    assert main([str(policy), "--opponent", str(policy), "--episodes", "2", "--seeds", "0", "--episode-seconds",
                 "3", "--players-per-team", "1", "--out", str(out), "--quiet", "--greedy"]) == 0
    result = load_evaluation(out)
    assert result["evaluated"]["sha256"] == result["opponent"]["sha256"] and result["settings"]["greedy"]
    assert "| mean ± sd |" in capsys.readouterr().out
    baseline = tmp_path / "random.json"
    assert main(["random", "--opponent", "scripted", "--episodes", "1", "--seeds", "0", "1", "--perception", "none",
                 "--episode-seconds", "3", "--out", str(baseline), "--quiet"]) == 0
    result = load_evaluation(baseline)
    assert result["evaluated"]["kind"] == "random" and result["opponent"]["team"] == "keeper_and_chasers"
    assert len(result["per_seed"]) == 2


# -- the perceiving team (soccer/perceiving.py) ------------------------------------------------------------------
def test_perceiving_team_beats_random_team_on_either_side():
    """Verified over 50 episodes of 120 s (seeds 100-104, realistic perception): 46 wins, 4 draws, no loss, 1.5
    goals a game for and none against (docs/results.md)."""
    result = evaluate("perceiving", "random", episodes=2, seeds=[0, 1], perception="realistic",
                      env_config={"episode_seconds": 60.0})
    records = result["episodes"]
    assert [r["side"] for r in records] == ["a", "b", "a", "b"]
    assert result["evaluated"]["kind"] == "perceiving"
    assert sum(r["goals_for"] for r in records) > sum(r["goals_against"] for r in records)
    assert result["counts"]["losses"] == 0


def test_perceiving_chasers_team_plays_chasers_in_every_slot_where_perceiving_keeps_goal():
    """The imitation teacher as a team: no goalkeeper, every robot a perceiving chaser; ``perceiving`` keeps a
    goalkeeper in each team's slot 0 (soccer/scripted.py)."""
    from dynenv_ros.soccer.scripted import ChaserPolicy, GoalkeeperPolicy
    env = parallel_env(players_per_team=2, observation="padded", perception="realistic")
    env.reset(seed=0)
    chasers, keeper = make_team_policy("perceiving_chasers"), make_team_policy("perceiving")
    chasers.reset(env, [2, 3], np.random.SeedSequence(0))
    keeper.reset(env, [2, 3], np.random.SeedSequence(0))
    assert [type(p.inner) for p in chasers.policies] == [ChaserPolicy, ChaserPolicy]
    assert [type(p.inner) for p in keeper.policies] == [GoalkeeperPolicy, ChaserPolicy]
    assert [p.team for p in chasers.policies] == [-1, -1]
    result = evaluate("perceiving_chasers", "random", episodes=1, seeds=[0], perception="realistic",
                      env_config={"episode_seconds": 5.0})
    assert result["evaluated"]["kind"] == "perceiving_chasers"


def test_the_pose_estimates_are_stepped_only_for_a_team_that_needs_them_and_change_no_episode(monkeypatch):
    """Localization draws from a generator of its own: switching it on leaves every episode as it was."""
    kw = dict(episodes=2, seeds=[3], perception="realistic", env_config={"episode_seconds": 10.0})
    switched = []
    import dynenv_ros.envs.soccer_observations as observations
    reset = observations.SoccerObservations.reset

    def spy(self, world):
        switched.append(self.localization)
        return reset(self, world)

    monkeypatch.setattr(observations.SoccerObservations, "reset", spy)
    plain = evaluate("scripted", "random", **kw)
    assert switched and not any(switched)
    switched.clear()
    monkeypatch.setattr(ScriptedTeam, "needs_localization", True)
    localized = evaluate("scripted", "random", **kw)
    assert switched and all(switched)
    assert localized["episodes"] == plain["episodes"]


def test_perceiving_team_acts_on_the_estimate_not_the_true_pose(monkeypatch):
    """Every robot's estimate moved 2 m to the side: the team's play changes (it aims from where it believes it
    is), the world and the other team being the same."""
    kw = dict(episodes=1, seeds=[4], perception="realistic", env_config={"episode_seconds": 20.0})
    honest = evaluate("perceiving", "random", **kw)
    from dynenv_ros.soccer.vision import SoccerVision
    true_estimate = SoccerVision.estimate

    def shifted(self):
        return true_estimate.fget(self) + np.array([0.0, 2.0, 0.0])

    monkeypatch.setattr(SoccerVision, "estimate", property(shifted))
    fooled = evaluate("perceiving", "random", **kw)
    assert fooled["episodes"] != honest["episodes"]
