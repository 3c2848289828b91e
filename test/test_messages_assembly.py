"""Experience assembled from messages (learning/messages/assembly.py) is the game that was played: every step's action,
behaviour log-probability, value, reward, episode end and bootstrap value are those sent and received, in order;
disorder, duplicates, losses and hostile messages are counted and never crash it."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from dynenv_ros.learning.messages.assembly import ExperienceAssembler, batch
from dynenv_ros.learning.messages.scenarios import SoccerExperience
from experience_game import HEAD_MAX, HEAD_UNITS, play, shuffled_in_windows

T = 4


def _assembler(game, steps=T, **kwargs) -> ExperienceAssembler:
    return ExperienceAssembler(steps, SoccerExperience(game.players, game.frames, HEAD_MAX, HEAD_UNITS), **kwargs)


def _feed(assembler, messages, source="game"):
    for kind, robot, msg in messages:
        if kind == "frame":
            assembler.add_frame(source, robot, msg)
        elif kind == "action":
            assembler.add_action(source, robot, msg)
        elif kind == "feedback":
            assembler.add_feedback(source, robot, msg)
        else:
            assembler.add_world_state(source, msg)
    return assembler.take()


@pytest.fixture(scope="module")
def game():
    return play(episodes=3, players=1, seed=0, episode_seconds=3.0)     # 6 periods per episode


def _episode_periods(game, robot):
    """The (episode, period) of every observation of ``robot``, in the order played."""
    seen = []
    for kind, name, msg in game.messages:
        if kind == "frame" and name == robot and msg.frame_index == 0:
            seen.append((msg.episode_id, msg.motion_period))
    return seen


def test_sequences_hold_what_was_sent_and_what_the_game_answered(game):
    sequences = _feed(_assembler(game), game.messages)
    robot = "team_a_0"
    mine = [s for s in sequences if s.stream == ("game", robot)]
    # 3 episodes of 6 periods: observations 0..5 of each act (period 6 is the ignored final one): 18 steps, so
    # 4 sequences of 4 steps; the 2 steps left wait for more.
    assert len(mine) == 18 // T
    observations = [k for k in _episode_periods(game, robot) if not game.ends.get(k, (False, False))[0]
                    and not game.ends.get(k, (False, False))[1]]
    assert len(observations) == 18
    for n, sequence in enumerate(mine):
        assert sequence.index == n and sequence.continues == (n > 0)
        for t in range(T):
            episode, period = observations[n * T + t]
            sent = game.actions[(robot, episode, period + 1)]
            head_index = round(sent.head_yaw_delta / (HEAD_MAX / HEAD_UNITS)) + HEAD_UNITS
            assert tuple(sequence.actions[t]) == (sent.walk, sent.turn, sent.kick, head_index)
            assert sequence.log_probs[t] == pytest.approx(sent.log_prob, abs=1e-6)
            assert sequence.values[t] == pytest.approx(sent.value, abs=1e-6)
            assert sequence.versions[t] == 5
            assert sequence.rewards[t] == pytest.approx(game.rewards[(robot, episode, period + 1)], abs=1e-5)
            terminated, truncated = game.ends[(episode, period + 1)]
            assert sequence.episode_end[t] == (terminated or truncated)
            assert sequence.truncated[t] == (truncated and not terminated)
            final = game.actions[(robot, episode, period + 2)].value if truncated else 0.0
            assert sequence.final_values[t] == pytest.approx(final, abs=1e-6)
            assert sequence.starts[t] == (period == 0)
            # what the observation shows: the previous action in rad (none after a reset)
            previous = (0.0, 0.0, 0.0, 0.0) if period == 0 else (
                lambda a: (a.walk, a.turn, a.kick, a.head_yaw_delta))(game.actions[(robot, episode, period)])
            assert sequence.obs["previous_action"][t] == pytest.approx(previous, abs=1e-6)
        episode, period = observations[n * T + T]
        assert sequence.values[T] == pytest.approx(game.actions[(robot, episode, period + 1)].value, abs=1e-6)
    assert sum(sequence.episode_end.sum() for sequence in mine) == 2     # the 3rd episode's end is not out yet
    arrays = batch(mine)
    assert arrays["actions"].shape == (T, len(mine), 4) and arrays["obs"]["game"].shape == (T + 1, len(mine), 3)


def test_targets_come_from_the_ground_truth_of_each_observations_last_frame(game):
    sequences = _feed(_assembler(game, with_targets=True), game.messages)
    observations = [k for k in _episode_periods(game, "team_b_0")]
    sequence = next(s for s in sequences if s.stream == ("game", "team_b_0"))
    for t in range(T + 1):
        truth = game.truth[observations[t]]
        me = next(o for o in truth.objects if o.id == 1)
        ball = next(o for o in truth.objects if o.id == 2)
        # team B's frame is the field frame turned by π (envs/learning_targets.py): positions negated
        assert sequence.targets["pose"][t][:2] == pytest.approx((-me.x, -me.y), abs=1e-5)
        assert sequence.targets["ball"][t][:2] == pytest.approx((-ball.x, -ball.y), abs=1e-5)
        gaze = me.yaw + me.head_yaw + math.pi
        assert sequence.targets["pose"][t][2:4] == pytest.approx((math.cos(gaze), math.sin(gaze)), abs=1e-5)


def test_disorder_within_the_patience_window_changes_nothing(game):
    in_order = _feed(_assembler(game), game.messages)
    shuffled = shuffled_in_windows(game.messages, 12, seed=3)    # windows of 12 messages (< 1 period of 2 robots)
    assembler = _assembler(game)
    out = _feed(assembler, shuffled)
    assert assembler.counts["out_of_order"] > 0 and assembler.counts["missing"] == 0
    assert len(out) == len(in_order)
    for a, b in zip(sorted(in_order, key=lambda s: (s.stream, s.index)), sorted(out, key=lambda s: (s.stream, s.index))):
        assert a.stream == b.stream
        for name in ("actions", "log_probs", "values", "rewards", "episode_end", "starts"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        for key in a.obs:
            assert np.array_equal(a.obs[key], b.obs[key]), key


def test_duplicates_late_messages_and_a_lost_frame_are_counted_and_cut_cleanly(game):
    messages = list(game.messages)
    duplicated = [m for m in messages if m[0] in ("action", "feedback")][:5]
    lost_at = next(i for i, m in enumerate(messages)
                   if m[0] == "frame" and m[1] == "team_a_0" and m[2].motion_period == 3 and m[2].episode_id == 2)
    lost = messages.pop(lost_at)[2]
    messages += duplicated                              # duplicates arriving long after: late or duplicate
    assembler = _assembler(game, patience=3)
    out = _feed(assembler, messages)
    counts = assembler.counts
    assert counts["duplicate"] + counts["late"] == len(duplicated)
    assert counts["missing"] == 1 and counts["cuts"] == 1
    mine = [s for s in out if s.stream == ("game", "team_a_0")]
    for sequence in mine:                               # no step uses the incomplete observation
        assert (lost.episode_id, lost.motion_period) not in sequence.keys
    restarted = [s for s in mine if not s.continues and s.index > 0]
    assert len(restarted) == 1 and restarted[0].starts[0]
    other = [s for s in out if s.stream == ("game", "team_b_0")]
    assert len(other) == 18 // T                        # the other robot's experience is untouched


def test_hostile_and_foreign_messages_are_dropped_and_counted(game):
    assembler = _assembler(game)
    bad = []
    action = next(m for k, _, m in game.messages if k == "action")
    for change in ({"log_prob": float("nan")}, {"value": float("inf")}, {"walk": 9}, {"kick": 200},
                   {"head_yaw_delta": 3.0}, {"head_yaw_delta": float("nan")}, {"robot_id": 1}, {"motion_period": 0},
                   {"log_prob": 5.0}):
        evil = copy.deepcopy(action)
        for key, value in change.items():
            setattr(evil, key, value)
        bad.append(("action", "team_a_0", evil))
    frame = next(m for k, _, m in game.messages if k == "frame")
    for change in ({"frames_per_period": 0}, {"frame_index": 9}, {"frames_per_period": 3}, {"robot_id": 7}):
        evil = copy.deepcopy(frame)
        for key, value in change.items():
            setattr(evil, key, value)
        bad.append(("frame", "team_a_0", evil))
    feedback = next(m for k, _, m in game.messages if k == "feedback")
    evil = copy.deepcopy(feedback)
    evil.reward_rule = float("nan")
    bad.append(("feedback", "team_a_0", evil))
    bad.append(("frame", "team_c_9", frame))
    _feed(assembler, bad)
    assert assembler.counts["malformed"] == len(bad) - 1 and assembler.counts["unknown_robot"] == 1
    out = _feed(assembler, game.messages)              # and the good experience after it is intact
    assert len([s for s in out if s.stream == ("game", "team_a_0")]) == 18 // T


def test_answers_without_learning_fields_are_not_learnt_from(game):
    messages = []
    for kind, robot, msg in game.messages:
        if kind == "action" and robot == "team_b_0":
            msg = copy.deepcopy(msg)
            msg.policy_version, msg.log_prob, msg.value = 0, 0.0, 0.0        # a scripted or foreign policy
        messages.append((kind, robot, msg))
    assembler = _assembler(game)
    out = _feed(assembler, messages)
    assert {s.stream[1] for s in out} == {"team_a_0"}
    assert assembler.counts["not_learning"] == 18          # every observation it answered, once
    assert assembler.counts["missing"] == 0


def test_only_the_robots_that_learn_are_kept(game):
    out = _feed(_assembler(game, learns=lambda name: name.startswith("team_b")), game.messages)
    assert {s.stream[1] for s in out} == {"team_b_0"}


def test_several_games_are_kept_apart(game):
    assembler = _assembler(game)
    out = _feed(assembler, game.messages, source="/game_1") + _feed(assembler, game.messages, source="/game_2")
    assert sorted({s.stream for s in out}) == [(g, r) for g in ("/game_1", "/game_2") for r in ("team_a_0", "team_b_0")]
    assert assembler.counts["late"] == 0 and assembler.counts["duplicate"] == 0


def test_a_writers_history_older_than_the_first_frames_is_not_counted_missing(game):
    """A trainer that joins late receives each policy's last actions (transient local) before any frame: they are
    dropped as ``before_start``, and the stream starts at its first observed period."""
    start = next(i for i, (kind, _, msg) in enumerate(game.messages) if kind == "frame" and msg.episode_id == 2)
    history = [m for m in game.messages[:start] if m[0] == "action" and m[1] == "team_a_0"][-3:]
    assembler = _assembler(game)
    out = _feed(assembler, history + game.messages[start:])
    assert assembler.counts["missing"] == 0 and assembler.counts["before_start"] == 3
    # episodes 2 and 3: 12 steps; the third sequence would need the observation after the last one (no episode 4)
    assert len([s for s in out if s.stream == ("game", "team_a_0")]) == 2
