"""The simulator node's game without ROS (``envs/sim_game.py``, ``envs/action_gate.py``): what goes out in which
order, when a period runs, how episodes follow each other in sim time, and which actions the gate lets through.

The numbers are docs/ros_graph.md's: soccer runs 100 Hz physics, a vision frame every 10 ticks and a motion period
of 50 ticks (5 frames); period 0 is the reset state, every frame of it at the same instant; one vision period
separates episodes in sim time; ``/sim/step`` runs at most 100 periods per call. Actions are dynenv_msgs/Action
messages, which the game reads by attribute."""
from __future__ import annotations

import pytest
from dynenv_msgs.msg import Action

from dynenv_ros.envs.action_gate import ActionGate
from dynenv_ros.envs.sim_game import SimGame
from dynenv_ros.scenarios import SOCCER
from dynenv_ros.perception.params import load_preset
from dynenv_ros.security.action_auth import GameSecrets, action_digest, tag_action
from dynenv_ros.soccer.config import SoccerConfig

NAMES = ["team_a_0", "team_b_0"]
TOPICS = [f"/game_1/{n}/action" for n in NAMES]          # fully qualified: what MACs and digests are bound to
VISION_TICKS, PERIOD_TICKS, FRAMES = 10, 50, 5


class Sent:
    """The game's outlet for these tests: what it was told to send, in order."""

    def __init__(self) -> None:
        self.log: list[tuple] = []

    def frame(self, output, k, poses, tick):
        self.log.append(("frame", output.episode_id, output.motion_period, k, tick))

    def feedback(self, output, digests, tick):
        self.log.append(("feedback", output.episode_id, output.motion_period, dict(digests), tick))

    def episode_started(self, episode, tick):
        self.log.append(("episode", episode, tick))

    def period_ran(self, output):
        self.log.append(("ran", output.episode_id, output.motion_period))

    def announce(self, text, tick):
        self.log.append(("announce", text))

    def finish(self):
        self.log.append(("finish",))


def _game(mode="stepped", episode_seconds=120.0, auto_reset=True, exit_when_finished=False, secrets=None):
    config = SoccerConfig.from_mapping({"players_per_team": 1, "episode_seconds": episode_seconds,
                                        "falls": {"enabled": False}})
    session = SOCCER.make_session(config, load_preset("none"), 3, "none", None, False)
    gate = ActionGate(session, NAMES, TOPICS, [f"/{n}/action" for n in NAMES], secrets, SOCCER.action_fields)
    sent = Sent()
    game = SimGame(session, gate, sent, "robocup", mode, 3, False, auto_reset, exit_when_finished)
    return game, sent


def _action(robot, period, episode=1, walk=Action.WALK_FORWARD):
    return Action(robot_id=robot, episode_id=episode, motion_period=period, walk=walk)


def test_period_zero_goes_out_at_start_and_a_period_runs_once_every_robot_has_acted():
    game, sent = _game()
    game.start(3)
    assert sent.log == ([("episode", 1, 0)] + [("frame", 1, 0, k, 0) for k in range(FRAMES)]
                        + [("feedback", 1, 0, {}, 0)])                  # the reset state, one instant
    sent.log.clear()
    first = _action(0, 1)
    assert game.gate.screen(0, first) == ("", "")
    game.admit(0, first)
    assert sent.log == [] and game.periods_run == 0                    # team_b_0 has not acted yet
    second = _action(1, 1, walk=Action.WALK_BACKWARD)
    game.admit(1, second)
    ticks = [VISION_TICKS * (k + 1) for k in range(FRAMES)]
    digests = {0: action_digest(first, TOPICS[0]), 1: action_digest(second, TOPICS[1])}
    assert sent.log == ([("ran", 1, 1)] + [("frame", 1, 1, k, t) for k, t in enumerate(ticks)]
                        + [("feedback", 1, 1, digests, PERIOD_TICKS)])
    assert game.periods_run == 1 and game.frames_published == 2 * FRAMES and game.session.period == 2


def test_episodes_follow_each_other_one_vision_period_apart_in_sim_time():
    game, sent = _game(episode_seconds=1.0)                            # two motion periods of 0.5 s
    game.start(3)
    assert game.step_request(0) == (True, "stepped") and game.step_request(0) == (True, "stepped")
    end = 2 * PERIOD_TICKS
    restart = end + VISION_TICKS
    assert ("feedback", 1, 2, {}, end) in sent.log
    assert sent.log[sent.log.index(("feedback", 1, 2, {}, end)) + 1:] == (
        [("episode", 2, restart)] + [("frame", 2, 0, k, restart) for k in range(FRAMES)]
        + [("feedback", 2, 0, {}, restart)])
    assert game.episodes_started == 2 and game.session.world.tick == 0 and game.now_tick() == restart


def test_without_auto_reset_the_last_episode_finishes_the_game_and_further_steps_are_refused():
    game, sent = _game(episode_seconds=1.0, auto_reset=False, exit_when_finished=True)
    game.start(3)
    assert game.step_request(2 * PERIOD_TICKS) == (False, "the episode has finished; call /sim/reset")
    assert sent.log[-2:] == [("feedback", 1, 2, {}, 2 * PERIOD_TICKS), ("finish",)]
    assert game.step_request(0) == (False, "the episode has finished; call /sim/reset") and game.periods_run == 2
    assert game.reset_request("kickoff_team: b", True, 11) == (True, "episode 2 started")
    assert game.session.world.state.kickoff_team == -1 and sent.log[-FRAMES - 2] == ("episode", 2, 110)


@pytest.mark.parametrize("ticks,message", [(7, "multiple of the motion period (50)"),
                                           (101 * PERIOD_TICKS, "one call runs at most 100 (5000 ticks)")])
def test_step_requests_are_bounded_and_whole_periods(ticks, message):
    game, _ = _game()
    assert game.step_request(0) == (False, "not started yet: waiting for subscribers (wait_for_subscribers & co.)")
    game.start(3)
    success, reason = game.step_request(ticks)
    assert not success and message in reason and game.periods_run == 0


@pytest.mark.parametrize("options,message", [("kickoff_team: c", "kickoff_team"), ("colour: red", "unknown reset"),
                                             ("[1, 2]", "must be a mapping"), ("x" * 4097, "at most 4096")])
def test_bad_reset_options_are_refused_with_the_reason_and_change_nothing(options, message):
    game, sent = _game()
    game.start(3)
    before = list(sent.log)
    success, reason = game.reset_request(options, False, 0)
    assert not success and reason.startswith("reset refused:") and message in reason
    assert sent.log == before and game.episodes_started == 1


def test_a_reset_starts_a_game_still_waiting_for_its_readers():
    game, sent = _game()
    assert game.reset_request("", True, 5) == (True, "episode 1 started")
    assert game.started and sent.log[0] == ("episode", 1, 0)


def test_real_time_sends_one_frame_per_tick_and_runs_the_next_period_when_the_last_went_out():
    game, sent = _game(mode="realtime")
    game.start(3)
    assert sent.log == [("episode", 1, 0)]                             # period 0 waits for its instants
    for _ in range(FRAMES):
        game.realtime_tick()
    assert sent.log[1:] == [("frame", 1, 0, k, 0) for k in range(FRAMES)] + [("feedback", 1, 0, {}, 0)]
    game.realtime_tick()
    assert sent.log[-2:] == [("ran", 1, 1), ("frame", 1, 1, 0, VISION_TICKS)]
    assert game.session.counts["missing"] == 2                          # nobody acted: the missing rule applied


def test_the_gate_refuses_with_reasons_and_summarises_refusals_once():
    game, _ = _game()
    game.start(3)
    gate = game.gate
    assert gate.screen(0, _action(1, 1)) == ("rejected_unknown_robot",
                                             "unknown_robot: robot_id 1 on /team_a_0/action (expected 0)")
    key, reason = gate.screen(1, _action(1, 2))
    assert key == "rejected_early" and reason.startswith("team_b_0: early")
    gate.count_refusals({"rejected_early": 2, "ignored_after_episode_end": 1}, reason)
    assert game.session.counts["rejected_early"] == 2 and game.session.counts["ignored_after_episode_end"] == 1
    assert gate.refusal_summary() == f"actions refused since the last report: 2 early; last: {reason}"
    assert gate.refusal_summary() == ""                                # said once


def test_with_secrets_only_a_teams_own_fresh_action_runs():
    team_a, team_b = b"a" * 32, b"b" * 32
    game, sent = _game(secrets=GameSecrets({"team_a": team_a, "team_b": team_b}, b"s" * 32))
    game.start(3)
    gate = game.gate
    unsigned = _action(0, 1)
    assert gate.screen(0, unsigned)[0] == "rejected_mac_missing"
    forged = _action(0, 1)
    forged.mac = tag_action(forged, TOPICS[0], team_b)                 # the other team's secret
    assert gate.screen(0, forged)[0] == "rejected_mac_invalid"
    signed = _action(0, 1)
    signed.mac = tag_action(signed, TOPICS[0], team_a)
    assert gate.screen(0, signed) == ("", "")
    game.admit(0, signed)
    assert gate.screen(0, signed)[0] == "rejected_replayed"             # its nonce is used now
    other = _action(1, 1)
    other.mac = tag_action(other, TOPICS[1], team_b)
    game.admit(1, other)
    assert sent.log[-1] == ("feedback", 1, 1, {0: action_digest(signed, TOPICS[0]),
                                               1: action_digest(other, TOPICS[1])}, PERIOD_TICKS)
