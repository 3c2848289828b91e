"""The sample bag in bags/ is what its README says: 30 s of a 2v2 game, every simulator topic, sim-time stamps."""
from pathlib import Path

import pytest

from dynenv_ros.bags.inspect import bag_info, echo, render

BAG = Path(__file__).resolve().parents[1] / "bags" / "sample_2v2_realistic_30s"


def test_sample_bag_holds_a_whole_30_s_game_at_the_simulator_rates():
    info = bag_info(BAG)
    topics = {t["name"]: t for t in info["topics"]}
    assert info["duration_s"] == pytest.approx(30.0)
    for robot in ("team_a_0", "team_a_1", "team_b_0", "team_b_1"):
        assert topics[f"/{robot}/detections"]["count"] == 305          # 5 frames of period 0 + 60 periods x 5
        assert topics[f"/{robot}/feedback"]["count"] == 61
        assert topics[f"/{robot}/detections"]["rate_hz"] == pytest.approx(10.0, rel=0.02)
    assert topics["/world_state"]["count"] == 305


def test_sample_bag_decodes_and_replays(tmp_path):
    feedback = list(echo(BAG, "/team_a_0/feedback", limit=2))
    assert [f["message"]["motion_period"] for f in feedback] == [0, 1]
    frames = render(BAG, tmp_path / "replay.gif", robot="team_a_0", stride=50, pixels_per_metre=10)
    assert frames == 7 and (tmp_path / "replay.gif").stat().st_size > 0
