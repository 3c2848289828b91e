"""Experience assembled from a driving game's messages (learning/messages/assembly.py with the driving scenario): each
car's steps hold the action its agent chose (discrete indices, or the normalised continuous command on its bounds),
the behaviour log-probability, value, reward and the car's own episode end; nothing of a car's periods after its own
end is learnt; disorder changes nothing; late, duplicate, lost and malformed messages are counted."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.learning.messages.assembly import ExperienceAssembler
from dynenv_ros.learning.messages.scenarios import DrivingExperience
from experience_game import W, play_driving, shuffled_in_windows
from test_messages_assembly import _feed

T = 4
CARS = ("car_0", "car_1")
BRAKE = (0.0, 1.0, 0.0)          # what a car does before its first action (the policy node's previous action)


@pytest.fixture(scope="module", params=["discrete", "continuous"])
def game(request):
    return play_driving(request.param)        # 2 episodes of 40 periods; car 0 crashes at period 20 of each


def _assembler(game, **kwargs) -> ExperienceAssembler:
    return ExperienceAssembler(T, DrivingExperience(DrivingConfig(n_cars=2, action_mode=game.action_mode)), **kwargs)


def _ends(game) -> dict[tuple[str, int], int]:
    """(car, episode) → the first period whose feedback ended the car's episode (terminated or truncated)."""
    out: dict[tuple[str, int], int] = {}
    for (car, episode, period), (terminated, truncated) in game.ends.items():
        if terminated or truncated:
            out[(car, episode)] = min(period, out.get((car, episode), period))
    return out


def _steps(game, car):
    """The (episode, period) of every observation the car acted in while its own episode lasted, in play order."""
    ends = _ends(game)
    return [(m.episode_id, m.motion_period) for kind, name, m in game.messages
            if kind == "frame" and name == car and m.motion_period < ends[(car, m.episode_id)]]


def _dead_messages(game, car) -> int:
    """The car's messages about periods after its own episode ended (an action is about the period before the one
    it is addressed to)."""
    ends = _ends(game)
    count = 0
    for kind, name, m in game.messages:
        if name == car:
            period = m.motion_period - 1 if kind == "action" else m.motion_period
            count += period > ends[(car, m.episode_id)]
    return count


def _mine(sequences, car):
    return sorted((s for s in sequences if s.stream == ("game", car)), key=lambda s: s.index)


def test_each_cars_steps_are_what_it_chose_and_end_with_its_own_episode(game):
    ends = _ends(game)
    assert {ends[("car_0", e)] for e in (1, 2)} == {20} and {ends[("car_1", e)] for e in (1, 2)} == {40}
    assert all(game.ends[("car_0", e, 20)] == (True, False) for e in (1, 2))     # car 0 crashed: terminated
    assert all(game.ends[("car_1", e, 40)] == (False, True) for e in (1, 2))     # car 1 hit the time limit
    assembler = _assembler(game, patience=3)       # car 0 waits 20 dead periods for the next episode: no cut
    sequences = _feed(assembler, game.messages)
    counts = assembler.counts
    assert counts["missing"] == 0 and counts["cuts"] == 0 and counts["malformed"] == 0 and counts["late"] == 0
    assert counts["after_end"] == _dead_messages(game, "car_0") > 0
    for car in CARS:
        steps = _steps(game, car)
        mine = _mine(sequences, car)
        # a sequence also needs the observation after its last step: none after the last episode's last step
        assert len(mine) == (len(steps) - 1) // T
        for n, sequence in enumerate(mine):
            assert sequence.index == n and sequence.continues == (n > 0)
            assert sequence.actions.dtype == (np.int64 if game.action_mode == "discrete" else np.float32)
            assert sequence.can_act.all()
            for t in range(T):
                episode, period = steps[n * T + t]
                sent = game.actions[(car, episode, period + 1)]
                chosen = game.chosen[(car, episode, period + 1)]
                if car == "car_0" or game.action_mode == "discrete":
                    assert tuple(sequence.actions[t].tolist()) == chosen      # exactly, on the bounds too
                else:
                    assert sequence.actions[t] == pytest.approx(chosen, abs=1e-6)
                assert sequence.log_probs[t] == pytest.approx(sent.log_prob, abs=1e-6)
                assert sequence.values[t] == pytest.approx(sent.value, abs=1e-6)
                assert sequence.versions[t] == 3
                assert sequence.rewards[t] == pytest.approx(game.rewards[(car, episode, period + 1)], abs=1e-5)
                terminated, truncated = game.ends[(car, episode, period + 1)]
                assert sequence.episode_end[t] == (terminated or truncated)
                assert sequence.truncated[t] == (truncated and not terminated)
                final = game.actions[(car, episode, period + 2)].value if truncated else 0.0
                assert sequence.final_values[t] == pytest.approx(final, abs=1e-6)
                assert sequence.starts[t] == (period == 0)
                before = game.actions.get((car, episode, period))
                previous = BRAKE if period == 0 else (before.throttle, before.brake, before.steering)
                assert sequence.obs["previous_action"][t] == pytest.approx(previous, abs=1e-6)
                assert sequence.obs["game"][t][0] == pytest.approx(game.seconds[(car, episode, period)], abs=1e-5)
            for episode, period in sequence.keys:          # no observation after the car's own end
                assert period < ends[(car, episode)]
    crashes = sum(int((s.episode_end & ~s.truncated).sum()) for s in _mine(sequences, "car_0"))
    assert crashes == 1          # the 2nd episode's crash is the last step, whose sequence never completes


def test_disorder_within_the_patience_window_changes_nothing(game):
    in_order = _assembler(game)
    expected = _feed(in_order, game.messages)
    shuffled = shuffled_in_windows(game.messages, 9, seed=5)     # 9 messages: one and a half periods of 2 cars
    assembler = _assembler(game)
    out = _feed(assembler, shuffled)
    assert assembler.counts["out_of_order"] > 0 and assembler.counts["missing"] == 0
    assert assembler.counts["after_end"] == in_order.counts["after_end"]
    assert len(out) == len(expected)
    expected, out = (sorted(q, key=lambda s: (s.stream, s.index)) for q in (expected, out))
    for a, b in zip(expected, out):
        assert a.stream == b.stream and a.keys == b.keys
        for name in ("actions", "log_probs", "values", "rewards", "episode_end", "truncated", "starts"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        for key in a.obs:
            assert np.array_equal(a.obs[key], b.obs[key]), key


def test_a_trainer_joining_after_a_crash_learns_none_of_the_dead_periods(game):
    """A stream that starts (or restarts after a cut) inside a car's dead periods must not take them for steps:
    their frames, answers and the next period's feedback look like a last step's, only their own feedback says the
    car's episode is over — and on the wire it may come late (each message kind is a topic of its own): here after
    the next episode has begun."""
    start = next(i for i, (kind, name, m) in enumerate(game.messages)
                 if kind == "frame" and m.episode_id == 1 and m.motion_period == 39)
    messages = game.messages[start:]
    own = next(i for i, (kind, car, m) in enumerate(messages) if kind == "feedback" and car == "car_0")
    feedback = messages.pop(own)
    assert (feedback[2].episode_id, feedback[2].motion_period) == (1, 39) and feedback[2].terminated
    next_episode = next(i for i, (kind, car, m) in enumerate(messages) if kind == "frame" and m.episode_id == 2)
    messages.insert(next_episode + 2, feedback)            # after both cars' first frame of episode 2
    assembler = _assembler(game)
    out = _feed(assembler, messages)
    mine = _mine(out, "car_0")
    assert mine and mine[0].keys[0] == (2, 0) and mine[0].starts[0]
    assert all(key[0] == 2 and key[1] < 20 for s in mine for key in s.keys)
    assert assembler.counts["missing"] == 0 and assembler.counts["after_end"] > 0
    assert _mine(out, "car_1")[0].keys[0] == (1, 39)      # the car still driving is learnt from where it was joined


def test_commands_off_the_discrete_grid_are_taken_to_the_nearest_and_counted():
    game = play_driving("discrete")
    messages = []
    for kind, car, msg in game.messages:
        if kind == "action" and car == "car_1":        # a policy whose commands are a little off the nine
            msg = copy.deepcopy(msg)
            msg.throttle, msg.steering = 0.98 * msg.throttle, 0.97 * msg.steering
            msg.brake = 0.97 if msg.brake == 1.0 else 0.02
        messages.append((kind, car, msg))
    assembler = _assembler(game)
    out = _feed(assembler, messages)
    steps = _steps(game, "car_1")
    mine = _mine(out, "car_1")
    for n, sequence in enumerate(mine):
        for t in range(T):
            episode, period = steps[n * T + t]
            assert tuple(sequence.actions[t].tolist()) == game.chosen[("car_1", episode, period + 1)]
    assert assembler.counts["actions_rounded"] == T * len(mine) > 0
    assert assembler.counts["malformed"] == 0


def test_late_duplicate_lost_and_malformed_messages_are_counted_and_cut_cleanly():
    game = play_driving("discrete")
    messages = list(game.messages)
    duplicated = [m for m in messages if m[0] in ("action", "feedback") and m[1] == "car_1"][:6]
    lost_at = next(i for i, (kind, car, m) in enumerate(messages)
                   if kind == "frame" and car == "car_1" and m.episode_id == 2 and m.motion_period == 10)
    lost = messages.pop(lost_at)[2]
    action = next(m for kind, car, m in messages if kind == "action" and car == "car_0")
    frame = next(m for kind, car, m in messages if kind == "frame" and car == "car_0")
    feedback = next(m for kind, car, m in messages if kind == "feedback" and car == "car_0")
    bad = []
    for message, changes in ((action, {"throttle": 1.5}), (action, {"brake": -0.2}), (action, {"steering": 2 * W}),
                             (action, {"throttle": math.nan}), (action, {"log_prob": math.nan}), (action, {"log_prob": 0.5}),
                             (action, {"value": math.inf}), (action, {"robot_id": 1}), (action, {"motion_period": 0}),
                             (frame, {"frames_per_period": 5}), (frame, {"frame_index": 1}), (frame, {"robot_id": 7}),
                             (feedback, {"reward_auxiliary": math.nan}), (feedback, {"robot_id": 1})):
        evil = copy.deepcopy(message)
        for key, value in changes.items():
            setattr(evil, key, value)
        kind = {id(action): "action", id(frame): "frame", id(feedback): "feedback"}[id(message)]
        bad.append((kind, "car_0", evil))
    bad.append(("frame", "team_a_0", frame))          # a soccer robot's name: not a car of this game
    assembler = _assembler(game, patience=3)
    out = _feed(assembler, bad + messages + duplicated)
    counts = assembler.counts
    assert counts["malformed"] == len(bad) - 1 and counts["unknown_robot"] == 1
    assert counts["duplicate"] + counts["late"] == len(duplicated)
    assert counts["missing"] == 1 and counts["cuts"] == 1
    car_1 = _mine(out, "car_1")
    assert all((lost.episode_id, lost.motion_period) not in s.keys for s in car_1)
    assert len([s for s in car_1 if not s.continues and s.index > 0]) == 1      # restarted once, after the loss
    assert len(_mine(out, "car_0")) == (len(_steps(game, "car_0")) - 1) // T     # car 0's experience is intact


def test_a_driving_assembler_refuses_targets():
    with pytest.raises(ValueError, match="no self-supervised targets"):
        ExperienceAssembler(T, DrivingExperience(DrivingConfig(n_cars=2)), with_targets=True)


def test_a_continuous_actions_log_density_may_exceed_zero():
    """A clipped Gaussian's log-density is above 0 where its spread is below ≈ 0.4 (the brake starts at 0.2): such an
    answer is learnt as it is, while a discrete answer's log-probability above 0 is malformed (the test above)."""
    game = play_driving("continuous")
    for kind, _, message in game.messages:
        if kind == "action":
            message.log_prob = 1.25
    assembler = _assembler(game, patience=3)
    sequences = _feed(assembler, game.messages)
    assert assembler.counts["malformed"] == 0 and sequences
    assert all(np.all(sequence.log_probs == np.float32(1.25)) for sequence in sequences)
