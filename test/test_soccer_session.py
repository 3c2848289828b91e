"""The session's per-frame robot state (RobotFrame), taken from the world at each vision frame: the robot's own
kick, and what the GameController broadcasts to every robot — ball ownership relative to the robot's team, the
seconds left of it, the seconds left in the episode (docs/interfaces.md, DetectionArray)."""
import numpy as np
import pytest

from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.params import load_preset
from dynenv_ros.soccer.actions import Kick
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import TEAM_A, TEAM_B

KICKOFF_OWNERSHIP_S = 10.0      # docs/soccer.md: "ball ownership | kickoff: 10 s"
EPISODE_S = 120.0               # SoccerConfig.episode_seconds default


def _session(kickoff_team: int = TEAM_A) -> SoccerSession:
    config = SoccerConfig.from_mapping({"players_per_team": 2, "falls": {"enabled": False}})
    session = SoccerSession(config, load_preset("none"), seed=0)
    session.reset(seed=0, kickoff_team=kickoff_team)
    return session


def _check_frame(session: SoccerSession, frame, owner: int, owner_seconds: float, game_seconds: float) -> None:
    """Every robot's view of one frame: ``owner`` is the absolute team owning the ball (0 free)."""
    truth = frame.snapshot                 # the world at this vision frame
    teams = [session.world.robots[i].team for i in range(session.config.n_robots)]
    for i, robot in enumerate(frame.robots):
        # the documented rule, from the world's game state ...
        assert robot.ball_owner == truth.ball_owner_team * teams[i]
        assert robot.ball_owner_seconds == pytest.approx(truth.ball_owner_remaining, abs=1e-5)
        assert robot.game_seconds_remaining == pytest.approx(truth.time_remaining, abs=1e-4)
        # ... and the values the rule gives here: own team +1, opponents -1
        assert robot.ball_owner == owner * teams[i]
        assert robot.ball_owner_seconds == pytest.approx(owner_seconds, abs=1e-4)
        assert robot.game_seconds_remaining == pytest.approx(game_seconds, abs=1e-4)
        # SoccerVision.game_controller holds the same, columns [relation, ownership seconds, game seconds]
        row = session.vision.game_controller[frame.frame_index, i]
        assert row.tolist() == [robot.ball_owner, robot.ball_owner_seconds, robot.game_seconds_remaining]


@pytest.mark.parametrize("kicking_team", [TEAM_A, TEAM_B])
def test_kickoff_ownership_and_game_clock_per_frame_relative_to_each_team(kicking_team):
    session = _session(kicking_team)
    initial = session.initial()
    controller = session.vision.game_controller
    assert controller.shape == (5, 4, 3) and controller.dtype == np.float32
    for frame in initial.frames:             # period 0: every frame shows the reset state
        _check_frame(session, frame, kicking_team, KICKOFF_OWNERSHIP_S, EPISODE_S)
    kicking = [r.team == kicking_team for r in session.world.robots]
    assert [r.ball_owner for r in initial.frames[0].robots] == [1 if k else -1 for k in kicking]
    assert sorted(set(kicking)) == [False, True]        # both teams are looked at
    tick_s = session.config.rates.tick_seconds
    freed = False
    for _ in range(22):                      # nobody acts; ownership runs out after 10 s (20 periods)
        for frame in session.step().frames:
            elapsed = frame.tick * tick_s
            if elapsed < KICKOFF_OWNERSHIP_S - 1e-6:
                _check_frame(session, frame, kicking_team, KICKOFF_OWNERSHIP_S - elapsed, EPISODE_S - elapsed)
            else:                            # expired: a free ball, 0 s of ownership, for everyone
                _check_frame(session, frame, 0, 0.0, EPISODE_S - elapsed)
                freed = True
    assert freed


def test_self_kicking_is_the_robots_own_kick_for_its_periods():
    session = _session()
    assert not any(r.kicking for f in session.initial().frames for r in f.robots)
    kicker = 1
    ok, reason = session.submit(kicker, session.episode_id, session.period, 0, 0, int(Kick.RIGHT_FOOT), 0.0)
    assert ok, reason
    kick_periods = session.config.kick.periods
    seen = []
    for _ in range(kick_periods + 1):
        period = session.step()
        seen.append([[r.kicking for r in f.robots] for f in period.frames])
    expected_robots = [i == kicker for i in range(session.config.n_robots)]
    for p, frames in enumerate(seen):
        for robots in frames:
            assert robots == (expected_robots if p < kick_periods else [False] * len(robots))


def test_answers_after_the_end_of_an_episode_are_ignored_not_accepted():
    """Only actions a period ran count as accepted (per robot too): that is what the main job expects the recorder
    to hold. The answers to an episode's last frames arrive after it finished; no period will run them."""
    config = SoccerConfig.from_mapping({"players_per_team": 1, "episode_seconds": 1.0})
    session = SoccerSession(config, load_preset("none"), seed=0)
    session.reset(seed=0)
    for _ in range(2):
        assert session.submit(0, session.episode_id, session.period, 0, 0, 0, 0.0)[0]
        session.step()
    assert session.finished
    accepted, reason = session.submit(0, session.episode_id, session.period, 0, 0, 0, 0.0)
    assert not accepted and reason.startswith("ignored")
    assert session.counts["accepted"] == 2 and session.accepted_per_robot == {0: 2}
    assert session.counts["ignored_after_episode_end"] == 1
    accepted, reason = session.submit(0, session.episode_id, session.period + 3, 0, 0, 0, 0.0)
    assert not accepted and reason.startswith("early")          # anything else is still refused for its reason
