"""dynenv-bench flood's phase figures (benchmarks/flood.py): the simulator's counters are read from the diagnostics
message before a phase to the first one after it, so that a phase shorter than the diagnostics period (about a
second) still has both ends; with fewer than two messages the benchmark says so instead of failing on an index."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from benchmarks.flood import phase_figures


def _counters(periods: int, accepted: int, rejected: int, frames_per_s: float) -> dict[str, str]:
    """A diagnostics message's values as the simulator publishes them: strings."""
    return {"periods_run": str(periods), "accepted": str(accepted), "rejected_stale": str(rejected),
            "vision_frames_per_s": str(frames_per_s)}


def test_a_phase_without_a_message_of_its_own_is_counted_from_its_neighbours() -> None:
    # messages at t = 10 and t = 11.5; the phase runs from 10.2 to 11.2 and holds none of them
    probe = SimpleNamespace(diagnostics=[(10.0, _counters(20, 36, 5, 10.0)), (11.5, _counters(23, 42, 9, 9.0)),
                                         (12.5, _counters(25, 46, 9, 8.0))])
    figures = phase_figures(probe, 10.2, 11.2, [1.0, 2.0, 3.0], sim_cpu_s=0.5)
    assert figures["periods"] == 3                        # 23 - 20: the message before and the first after
    assert figures["accepted_share"] == round(6 / (2 * 3), 3)
    assert figures["refused"] == 4                        # 9 - 5
    assert figures["frames_per_s"] == 9.5                 # no message of its own: the median of the two ends
    assert figures["service_ms_median"] == 2.0
    assert figures["sim_cpu_share_of_one_core"] == 0.5


def test_a_phase_with_messages_of_its_own_takes_its_frame_rate_from_them() -> None:
    probe = SimpleNamespace(diagnostics=[(0.0, _counters(0, 0, 0, 1.0)), (1.0, _counters(2, 4, 0, 10.0)),
                                         (2.0, _counters(4, 8, 0, 10.0)), (3.5, _counters(7, 14, 0, 3.0))])
    figures = phase_figures(probe, 0.5, 3.0, [1.0], sim_cpu_s=0.25)
    assert figures["periods"] == 7 and figures["accepted_share"] == 1.0
    assert figures["frames_per_s"] == 10.0                # the start-up and later messages do not count
    assert figures["sim_cpu_share_of_one_core"] == 0.1    # 0.25 s over 2.5 s


def test_fewer_than_two_messages_around_a_phase_is_a_clear_error() -> None:
    probe = SimpleNamespace(diagnostics=[(5.0, _counters(1, 2, 0, 10.0)), (6.0, {"frames": "3"})])
    with pytest.raises(RuntimeError, match="1 diagnostics message"):
        phase_figures(probe, 5.5, 6.5, [1.0], sim_cpu_s=0.1)
