"""Issue 27 items 2 and 3, in process and as the attacker: the trainer learns the action the simulator ran — the one
``StepFeedback.action_digest`` names — whatever forged rivals reached it first, refuses messages far ahead of the
game, and with secrets refuses actions and feedback without a valid MAC (``learning.messages.assembly``)."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from dynenv_ros.learning.messages.assembly import MAX_CANDIDATES, ExperienceAssembler
from dynenv_ros.learning.messages.scenarios import SoccerExperience
from dynenv_ros.security import action_auth as auth
from experience_game import HEAD_MAX, HEAD_UNITS, play

T = 4
ROBOT = "team_a_0"
SOURCE = "game"


def _topic(robot: str, kind: str) -> str:
    return ExperienceAssembler.topic(SOURCE, robot, kind)


@pytest.fixture(scope="module")
def game():
    return play(episodes=3, players=1, seed=0, episode_seconds=3.0)


def _with_digests(game, secrets: auth.GameSecrets | None = None, drop_digest: tuple | None = None) -> list:
    """The game's messages as a simulator of issue 27 sends them: each feedback names the action its period ran
    (``drop_digest``: the (robot, episode, period) whose robot acted by default); with ``secrets`` every action
    carries its team's MAC and every feedback the simulator's."""
    out = []
    for kind, robot, msg in game.messages:
        if kind == "feedback":
            msg = copy.deepcopy(msg)
            key = (robot, msg.episode_id, msg.motion_period)
            ran = game.actions.get(key)
            if ran is not None and key != drop_digest:
                msg.action_digest = auth.action_digest(ran, _topic(robot, "action"))
            if secrets is not None:
                msg.mac = auth.tag_feedback(msg, _topic(robot, "feedback"), secrets.simulator)
        elif kind == "action" and secrets is not None:
            msg = copy.deepcopy(msg)
            msg.mac = auth.tag_action(msg, _topic(robot, "action"), secrets.for_agent(robot))
        out.append((kind, robot, msg))
    return out


def _feed(messages, frames, **kwargs):
    assembler = ExperienceAssembler(T, SoccerExperience(1, frames, HEAD_MAX, HEAD_UNITS), **kwargs)
    for kind, robot, msg in messages:
        {"frame": assembler.add_frame, "action": assembler.add_action,
         "feedback": assembler.add_feedback}.get(kind, lambda *a: None)(SOURCE, robot, msg)
    return assembler, [s for s in assembler.take() if s.stream == (SOURCE, ROBOT)]


def _real(game):
    return {(m.episode_id, m.motion_period - 1): m for k, r, m in game.messages if k == "action" and r == ROBOT}


def _assert_learnt_from_real(sequences, game, some: bool = True):
    real = _real(game)
    assert sequences or not some
    for sequence in sequences:
        for t, key in enumerate(sequence.keys[:-1]):
            assert sequence.log_probs[t] == np.float32(real[key].log_prob)
            assert sequence.values[t] == np.float32(real[key].value)
        assert np.isfinite(sequence.values).all() and np.isfinite(sequence.rewards).all()


def _evil(real, **fields):
    evil = copy.deepcopy(real)
    evil.walk, evil.log_prob, evil.value = (real.walk + 1) % 5, -0.25, 9.0
    for name, value in fields.items():
        setattr(evil, name, value)
    return evil


def _insert_rivals(messages, where: str, count: int = 1, **fields):
    """A forged rival of each of ROBOT's real answers: ``before_frames`` (for a period that has not run yet),
    ``before`` (right before the real one) or ``after`` it."""
    out, forged = [], 0
    by_period = {(m.episode_id, m.motion_period): m for k, r, m in messages if k == "action" and r == ROBOT}
    for kind, robot, msg in messages:
        if where == "before_frames" and kind == "frame" and robot == ROBOT and msg.frame_index == 0:
            real = by_period.get((msg.episode_id, msg.motion_period + 1))
            if real is not None:
                for n in range(count):
                    out.append(("action", ROBOT, _evil(real, head_yaw_delta=0.0 if n % 2 else real.head_yaw_delta,
                                                       value=float(n), **fields)))
                    forged += 1
        if where == "before" and kind == "action" and robot == ROBOT:
            out.append(("action", ROBOT, _evil(msg, **fields)))
            forged += 1
        out.append((kind, robot, msg))
        if where == "after" and kind == "action" and robot == ROBOT:
            out.append(("action", ROBOT, _evil(msg, **fields)))
            forged += 1
    return out, forged


def test_the_step_is_the_action_the_feedback_names_whatever_arrived_first(game):
    clean, baseline = _feed(_with_digests(game), game.frames)
    assert baseline and clean.counts["missing"] == 0 and clean.counts["cuts"] == 0
    for where in ("before_frames", "before", "after"):
        messages, forged = _insert_rivals(_with_digests(game), where)
        assembler, sequences = _feed(messages, game.frames)
        counts = assembler.counts
        assert forged > 0 and counts["rival_answers"] == forged, (where, counts)
        assert counts["contested_cuts"] == 0 and counts["cuts"] == 0, (where, counts)
        assert len(sequences) == len(baseline), (where, counts)          # nothing lost: every step resolved
        _assert_learnt_from_real(sequences, game)
        # the final observations' answers never run: their rivals stay unresolved, the others are resolved
        assert 0 < counts["rivals_resolved"] <= forged


def test_without_digests_a_rival_after_the_real_answer_still_costs_the_step(game):
    """Feedback of a simulator from before issue 27 keeps the older rule (documented): no step from a guess."""
    messages, _ = _insert_rivals(game.messages, "after")
    assembler, sequences = _feed(messages, game.frames)
    assert assembler.counts["contested_cuts"] > 0 and not sequences


def test_a_named_action_that_never_arrived_cuts_the_step_and_nothing_forged_is_learnt(game):
    messages = []
    lost = None
    for kind, robot, msg in _with_digests(game):
        if kind == "action" and robot == ROBOT and msg.episode_id == 1 and msg.motion_period == 3:
            lost = msg
            messages.append(("action", ROBOT, _evil(msg)))       # the forged one arrives, the real one is lost
            continue
        messages.append((kind, robot, msg))
    assert lost is not None
    assembler, sequences = _feed(messages, game.frames)
    assert assembler.counts["unmatched_action"] == 1 and assembler.counts["cuts"] >= 1
    assert "the answer its feedback names" in assembler.last_missing
    assert all(-0.25 not in s.log_probs for s in sequences)
    _assert_learnt_from_real(sequences, game)


def test_a_period_the_robot_played_by_default_is_no_step(game):
    assembler, sequences = _feed(_with_digests(game, drop_digest=(ROBOT, 1, 3)), game.frames)
    assert assembler.counts["not_executed"] == 1
    assert all((1, 2) not in s.keys[:-1] for s in sequences)          # the answer to period 2 was not run
    _assert_learnt_from_real(sequences, game)


def test_more_rivals_than_kept_lose_the_step_but_never_teach_the_forgery(game):
    messages, forged = _insert_rivals(_with_digests(game), "before_frames", count=MAX_CANDIDATES)
    assembler, sequences = _feed(messages, game.frames)
    assert assembler.counts["candidates_full"] > 0 and assembler.counts["unmatched_action"] > 0
    for sequence in sequences:
        assert -0.25 not in sequence.log_probs
    _assert_learnt_from_real(sequences, game, some=False)       # a flood that fills every slot is a denial of service


def test_far_future_actions_and_feedback_are_refused_and_evict_nothing(game):
    messages = []
    for kind, robot, msg in _with_digests(game):
        messages.append((kind, robot, msg))
        if kind == "frame" and robot == ROBOT and msg.frame_index == 0:
            for ahead in (20, 500, 10_000):                  # would fill the bounded slots and push out real ones
                messages.append(("action", ROBOT, _evil(game.actions[(ROBOT, 1, 1)], episode_id=msg.episode_id,
                                                        motion_period=msg.motion_period + ahead)))
                feedback = copy.deepcopy(next(m for k, r, m in game.messages if k == "feedback" and r == ROBOT))
                feedback.episode_id, feedback.motion_period = msg.episode_id + 2, ahead
                messages.append(("feedback", ROBOT, feedback))
    assembler, sequences = _feed(messages, game.frames, max_slots=64)
    clean, baseline = _feed(_with_digests(game), game.frames)
    counts = assembler.counts
    assert counts["beyond_horizon"] > 0 and "ahead of its frames" in assembler.last_refused
    assert counts["missing"] == 0 and len(sequences) == len(baseline)
    _assert_learnt_from_real(sequences, game)


def test_with_secrets_forged_actions_and_feedback_are_refused_and_counted(game, tmp_path):
    auth.write_game_secrets(tmp_path / "secrets", ["team_a_0", "team_b_0"])
    secrets = auth.load_game_secrets(tmp_path / "secrets", ["team_a_0", "team_b_0"], simulator=True)
    team_b = auth.load_secret(tmp_path / "secrets" / "team_b.secret")
    genuine = _with_digests(game, secrets)
    messages, counts_expected = [], {"action_mac_missing": 0, "action_mac_invalid": 0, "feedback_mac_invalid": 0,
                                     "feedback_mac_missing": 0}
    for kind, robot, msg in genuine:
        if kind == "action" and robot == ROBOT:
            no_mac = _evil(msg, mac=b"")
            other_team = _evil(msg)
            other_team.mac = auth.tag_action(other_team, _topic(ROBOT, "action"), team_b)
            altered = copy.deepcopy(msg)
            altered.log_prob = -0.25                          # the real MAC on altered content
            messages += [("action", ROBOT, no_mac), ("action", ROBOT, other_team), ("action", ROBOT, altered)]
            counts_expected["action_mac_missing"] += 1
            counts_expected["action_mac_invalid"] += 2
        if kind == "feedback" and robot == ROBOT:
            forged = copy.deepcopy(msg)
            forged.reward_primary, forged.mac = 0.5, b""
            reused = copy.deepcopy(msg)
            reused.reward_auxiliary = 0.5                     # the real MAC on altered rewards
            messages += [("feedback", ROBOT, forged), ("feedback", ROBOT, reused)]
            counts_expected["feedback_mac_missing"] += 1
            counts_expected["feedback_mac_invalid"] += 1
        messages.append((kind, robot, msg))
    assembler, sequences = _feed(messages, game.frames, secrets=secrets)
    clean, baseline = _feed(genuine, game.frames, secrets=secrets)
    for key, value in counts_expected.items():
        assert assembler.counts[key] == value > 0, (key, assembler.counts)
    assert assembler.counts["rival_answers"] == 0 and assembler.counts["duplicate"] == 0
    assert len(sequences) == len(baseline) > 0 and clean.counts["action_mac_invalid"] == 0
    _assert_learnt_from_real(sequences, game)
    for sequence in sequences:
        assert 0.5 not in sequence.reward_terms
