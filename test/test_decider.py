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
