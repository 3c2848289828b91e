"""Acting on a period by its deadline (policy_node/partial_periods.py, policy_node/periods.py): the frame interval
learnt from the stamps, when a period is due, how missing frames are filled, and how a newer period's frame closes
an incomplete one."""
from __future__ import annotations

from collections import Counter
from types import SimpleNamespace

import pytest

from policy_node.partial_periods import FrameInterval, due_ns, fill
from policy_node.periods import PeriodMemory, close_period, file_frame

MS = 1_000_000


def _frame(period: int, index: int, stamp_ns: int, frames: int = 5, head_yaw: float = 0.0, detections=("d",)):
    stamp = SimpleNamespace(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), episode_id=1, motion_period=period,
                           frame_index=index, frames_per_period=frames, head_yaw=head_yaw,
                           detections=list(detections))


def _empty(like, index, stamp_ns):
    return _frame(like.motion_period, index, stamp_ns, like.frames_per_period, like.head_yaw, detections=())


def test_the_interval_is_the_median_over_consecutive_frames_across_drops():
    interval = FrameInterval()
    assert interval.ns is None
    jitter = [0, 6, -6, 3, -2, 5, -5, 0, 1, -1]
    for n in range(10):
        if n == 4:
            continue                                        # a dropped frame: a gap of two slots
        interval.observe("a", _frame(n // 5, n % 5, 10**9 + n * 100 * MS + jitter[n] * MS))
    assert abs(interval.ns - 100 * MS) <= 3 * MS


def test_due_counts_the_slots_still_to_come():
    assert due_ns(1000, 1, 5, 100) == 1300
    assert due_ns(1000, 4, 5, 100) == 1000


def test_a_missing_frame_is_the_nearest_earlier_frame_seen_empty_at_its_slots_stamp():
    frames = {1: _frame(3, 1, 2100 * MS, head_yaw=0.2), 3: _frame(3, 3, 2300 * MS, head_yaw=0.4)}
    period, missing = fill(frames, 5, 100 * MS, _empty)
    assert missing == 3 and [f.frame_index for f in period] == [0, 1, 2, 3, 4]
    assert period[1] is frames[1] and period[3] is frames[3]
    assert [f.detections for f in period] == [[], ["d"], [], ["d"], []]
    assert [f.head_yaw for f in period] == [0.2, 0.2, 0.2, 0.4, 0.4]     # frame 0 from the one after it
    assert [f.header.stamp.nanosec // MS for f in period] == [0, 100, 200, 300, 400]
    assert [f.header.stamp.sec for f in period] == [2] * 5
    with pytest.raises(ValueError):
        fill({}, 5, 100 * MS, _empty)


def test_a_newer_periods_frame_closes_an_incomplete_period_when_partial_periods_are_on():
    counts: Counter[str] = Counter()

    def close(frames):
        period, missing = fill(frames, 5, 100 * MS, _empty)
        counts["frames_missing"] += missing
        return period

    memory = PeriodMemory()
    for k in (0, 1, 3):
        file_frame(memory, _frame(7, k, (35 + k) * 100 * MS), counts, close)
    file_frame(memory, _frame(7, 1, 3610 * MS), counts, close)              # a duplicate: the first is kept
    assert memory.ready is None and sorted(memory.frames) == [0, 1, 3]
    file_frame(memory, _frame(8, 0, 4000 * MS), counts, close)              # period 8 starts: 7 is acted on
    assert [len(f.detections) for f in memory.ready] == [1, 1, 0, 1, 0]
    assert memory.period == 8 and list(memory.frames) == [0]
    assert counts == {"frames_duplicate": 1, "periods_partial": 1, "frames_missing": 2}
    memory.decided, memory.ready = 7, None
    file_frame(memory, _frame(7, 4, 3900 * MS), counts, close)              # late: its period was acted on
    assert counts["frames_stale"] == 1


def test_without_partial_periods_an_incomplete_period_is_dropped_as_before():
    counts: Counter[str] = Counter()
    memory = PeriodMemory()
    file_frame(memory, _frame(7, 0, 3500 * MS), counts)
    file_frame(memory, _frame(8, 0, 4000 * MS), counts)
    assert memory.ready is None and counts == {"periods_dropped": 1}


def test_closing_at_the_deadline_makes_the_collected_frames_ready():
    counts: Counter[str] = Counter()
    memory = PeriodMemory()
    file_frame(memory, _frame(2, 0, 1000 * MS), counts)
    memory.due = 1400 * MS
    close_period(memory, counts, lambda frames: fill(frames, 5, 100 * MS, _empty)[0])
    assert len(memory.ready) == 5 and memory.frames == {} and memory.due is None
    assert counts == {"periods_partial": 1}


def test_the_network_sees_a_missing_frame_as_a_frame_with_nothing_in_it():
    """The policy node's filler (``node_inputs.empty_like``) packed as the network gets it: no detection rows (masks 0), the
    robot's own state carried over, as in a simulated frame whose detections were all missed."""
    from dynenv_msgs.msg import Detection, DetectionArray
    from geometry_msgs.msg import Point

    from dynenv_ros.envs.detection_messages import pack_messages
    from policy_node.node_inputs import empty_like

    def frame(index: int) -> DetectionArray:
        msg = DetectionArray(episode_id=1, motion_period=3, frame_index=index, frames_per_period=5, head_yaw=0.3,
                             self_fallen=True, game_seconds_remaining=100.0 - index,
                             detections=[Detection(class_id=1, position=Point(x=1.0, y=0.0), confidence=0.9,
                                                   size_x=0.1, size_y=0.1, yaw=float("nan"))])
        msg.header.stamp.sec, msg.header.stamp.nanosec = 2, index * 100 * MS
        return msg

    period, missing = fill({0: frame(0), 1: frame(1), 3: frame(3)}, 5, 100 * MS, empty_like)
    assert missing == 2 and period[4].header.stamp.nanosec == 400 * MS and period[4].motion_period == 3
    observation, _ = pack_messages([period], [(0, 0, 0, 0.0)])
    assert observation["object_mask"][0].sum(axis=-1).tolist() == [1, 1, 0, 1, 0]
    assert observation["landmark_mask"][0].sum() == 0
    assert observation["proprioception"][0, :, 0].tolist() == pytest.approx([0.3] * 5)     # head yaw carried
    assert observation["proprioception"][0, :, 1].tolist() == [1.0] * 5                     # fallen carried
    assert observation["game"][0, 2] == pytest.approx(97.0)       # the last frame: frame 3's values carried
