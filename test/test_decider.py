"""The policy node's decider without ROS (policy_node/decider.py): plain objects as frames, an untrained network, the
node's rules for when a period is ready and which period each action is for (docs/deploy.md, "Slow policies")."""
from __future__ import annotations

from collections import Counter
from types import SimpleNamespace

import numpy as np
import torch

from dynenv_ros.scenarios import SOCCER
from policy_node.batch_policy import BatchPolicy
from policy_node.decider import Decider
from policy_node.policy_files import untrained

ROBOTS = ["team_a_0", "team_b_0"]
FRAMES = 5
MS = 1_000_000


class Said:
    """The node's log lines (the decider logs through whatever logger the node gives it)."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def error(self, message: str, **options) -> None:
        self.lines.append(message)

    info = error


def _frame(episode: int, period: int, index: int, stamp_ns: int = 0, frames: int = FRAMES):
    """A DetectionArray's fields as a plain object: the core reads messages by attribute."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return SimpleNamespace(episode_id=episode, motion_period=period, frame_index=index, frames_per_period=frames,
                           head_yaw=0.0, self_fallen=False, self_penalized=False, self_kicking=False, detections=[],
                           header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec)))


def _empty_like(like, index: int, stamp_ns: int):
    return _frame(like.episode_id, like.motion_period, index, stamp_ns, like.frames_per_period)


def _decider(clock=lambda: 0, deadline_ns=None, greedy=True):
    counts, said = Counter(), Said()
    batch = BatchPolicy(ROBOTS, scenario=SOCCER, settings=SOCCER.game_settings(1, "discrete"), seed=3,
                        greedy=greedy,
                        pose_max_age=0.5, counts=counts, log=said, take_estimates=lambda: None,
                        empty_period=lambda frames: [_frame(0, 0, k, 0, frames) for k in range(frames)])
    decider = Decider(ROBOTS, batch, counts, said, deadline_ns, clock, _empty_like)
    policy = untrained(SOCCER, action_mode="discrete", seed=3)
    decider.check(policy)             # the trial decision every policy passes before it acts
    batch.policy = policy
    return decider, counts, said


def test_one_decision_once_every_robot_has_a_period_each_action_for_a_period_not_yet_started():
    decider, counts, said = _decider()
    sent = []
    for k in range(FRAMES):
        assert decider.store("team_a_0", _frame(1, 0, k)) == ""
    assert not decider.decide(lambda: None, sent.append) and not sent         # team_b_0 has no period yet
    for k in range(FRAMES):
        decider.store("team_b_0", _frame(1, 0, k))
    # while the network runs, team_a_0's first frame of period 1 arrives: period 1 has started for it
    assert decider.decide(lambda: decider.store("team_a_0", _frame(1, 1, 0)), sent.append)
    assert [(o.name, o.target) for o in sent] == [("team_a_0", 2), ("team_b_0", 1)]
    assert all(o.learning is not None and np.isfinite(o.learning).all() for o in sent)
    assert counts["decisions"] == 1 and counts["actions_delayed"] == 1 and counts["frames_received"] == 11
    assert all(m.state is not None and m.addressed == o.target for m, o in zip(decider.memories(), sent))
    assert not said.lines


def test_a_period_of_the_previous_episode_is_dropped_while_another_robot_starts_the_next():
    decider, counts, _ = _decider()
    for k in range(FRAMES):
        decider.store("team_a_0", _frame(1, 7, k))
        decider.store("team_b_0", _frame(2, 0, k))
    sent = []
    assert not decider.decide(lambda: None, sent.append) and not sent
    assert counts["periods_dropped"] == 1 and decider.memory["team_a_0"].ready is None
    for k in range(FRAMES):
        decider.store("team_a_0", _frame(2, 0, k))
    assert decider.decide(lambda: None, sent.append) and [o.target for o in sent] == [1, 1]


def test_a_malformed_frame_is_refused_with_the_reason():
    decider, counts, _ = _decider()
    assert decider.store("team_a_0", _frame(1, 0, 5)) == "frame_index 5 not below frames_per_period 5"
    assert counts["frames_malformed"] == 1 and not decider.memory["team_a_0"].frames


def test_an_overdue_period_is_acted_on_with_its_missing_frames_empty():
    """Frames 100 ms apart: frame 2's arrival says the last (4) is due 200 ms later; 50 ms past that, with
    decision_deadline 0.05 s, the period is closed with frames 3 and 4 empty (partial_periods)."""
    now = [10_000 * MS]
    decider, counts, _ = _decider(clock=lambda: now[0], deadline_ns=50 * MS)
    for robot in ROBOTS:
        for k in range(3):
            decider.store(robot, _frame(1, 0, k, stamp_ns=k * 100 * MS))
    sent = []
    now[0] += 249 * MS
    decider.close_overdue()
    assert not decider.decide(lambda: None, sent.append)                      # 1 ms before the deadline
    now[0] += 1 * MS
    decider.close_overdue()
    assert decider.decide(lambda: None, sent.append) and len(sent) == 2
    assert counts["frames_missing"] == 4 and counts["periods_partial"] == 2
    last = decider.memory["team_a_0"].last
    assert [f.frame_index for f in last] == list(range(FRAMES)) and not last[4].detections
    assert last[4].header.stamp.nanosec == 400 * MS


def test_sampled_decisions_repeat_for_the_same_seed_and_period():
    """A sampling generator per (node seed, episode, period), not torch's global one: two deciders given the same
    frames act alike, whatever else drew from the global generator in between."""
    actions = []
    for draws in (0, 5):
        decider, _, _ = _decider(greedy=False)
        torch.rand(draws)
        sent = []
        for robot in ROBOTS:
            for k in range(FRAMES):
                decider.store(robot, _frame(4, 9, k))
        assert decider.decide(lambda: None, sent.append)
        actions.append([(o.action, o.learning) for o in sent])
    assert actions[0] == actions[1] and len(actions[0]) == 2


# -- the pose estimate a decision waits for (batch_policy.BatchPolicy.pose_rows, docs/deploy.md) ------------------
def _estimate(x: float, stamp_ns: int):
    """A PoseWithCovarianceStamped's fields as a plain object: x metres ahead, facing along x, variances 0.01."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    covariance = [0.0] * 36
    covariance[0] = covariance[7] = covariance[35] = 0.01
    return SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=nanosec)),
                           pose=SimpleNamespace(pose=SimpleNamespace(position=SimpleNamespace(x=x, y=0.0, z=0.0),
                                                                     orientation=SimpleNamespace(x=0.0, y=0.0, z=0.0,
                                                                                                 w=1.0)),
                                                covariance=covariance))


def _pose_batch(arrivals: dict[int, list[tuple[str, object]]]):
    """A BatchPolicy whose ``take_estimates`` files, at its n-th call, the estimates ``arrivals[n]`` lists (what
    DDS would have delivered by then); returns it, its counts and the calls made."""
    counts, calls = Counter(), []

    def take() -> None:
        calls.append(len(calls))
        for name, msg in arrivals.get(len(calls) - 1, []):
            batch.pose_histories[name].add(msg)

    batch = BatchPolicy(ROBOTS, scenario=SOCCER, settings=SOCCER.game_settings(1, "discrete"), seed=3, greedy=True,
                        pose_max_age=0.5, counts=counts, log=Said(), take_estimates=take,
                        empty_period=lambda frames: [])
    return batch, counts, calls


def _periods(last_ns: int):
    """Both robots' periods of five frames 0.1 s apart, the last at ``last_ns``."""
    return [[_frame(1, 3, k, last_ns - (FRAMES - 1 - k) * 100 * MS) for k in range(FRAMES)] for _ in ROBOTS]


def test_an_estimate_still_on_its_way_is_waited_for_and_used():
    """The frame came before its estimate (another topic): the robots' estimates of the frame before are within
    pose_max_age, so the decision takes what arrives until the frame's own are in, and uses those (x = 2.0 m, team
    A's frame; team B's turned by π: x = −2.0)."""
    before = [(name, _estimate(1.0, 400 * MS)) for name in ROBOTS]
    batch, counts, calls = _pose_batch({0: before, 3: [(name, _estimate(2.0, 500 * MS)) for name in ROBOTS]})
    rows = batch.pose_rows(_periods(500 * MS))
    assert len(calls) == 4 and counts["pose_used"] == 2 and counts["pose_late"] == 0
    assert rows[:, 0].tolist() == [2.0, -2.0]


def test_the_first_period_waits_for_one_estimate_a_frame_of_its_repeated_instant():
    """The simulator's first period repeats one instant in all five frames, one estimate each: the decision waits
    for the fifth (x = 5.0 m), not the first of that stamp."""
    arrivals = {k: [(name, _estimate(float(k + 1), 0)) for name in ROBOTS] for k in range(FRAMES)}
    batch, counts, calls = _pose_batch(arrivals)
    rows = batch.pose_rows([[_frame(1, 0, k, 0) for k in range(FRAMES)] for _ in ROBOTS])
    assert len(calls) == FRAMES and rows[:, 0].tolist() == [5.0, -5.0] and counts["pose_late"] == 0


def test_a_wait_ends_without_the_estimate_and_no_estimator_means_no_wait():
    """An estimate that never comes: the decision gives up (counted pose_late) and uses the one before, still
    within pose_max_age. No estimate ever, or only a stale one: nothing to wait for (one take), the row is lost."""
    batch, counts, calls = _pose_batch({0: [(name, _estimate(1.0, 400 * MS)) for name in ROBOTS]})
    rows = batch.pose_rows(_periods(500 * MS))
    assert counts["pose_late"] == 1 and counts["pose_used"] == 2 and len(calls) > 1
    assert rows[:, 0].tolist() == [1.0, -1.0]
    for arrivals in ({}, {0: [(name, _estimate(1.0, 0)) for name in ROBOTS]}):        # none; 0.5 s + 1 ns old
        batch, counts, calls = _pose_batch(arrivals)
        batch.pose_rows(_periods(500 * MS + 1))
        assert len(calls) == 1 and counts["pose_late"] == 0
        assert counts["pose_missing"] + counts["pose_stale"] == 2
