"""The sample bag in bags/ is what its README says: 30 s of a 2v2 game, every simulator topic, sim-time stamps."""
from pathlib import Path

import pytest

from dynenv_ros.bags.inspect import bag_info, echo, export, render

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


def test_sample_bag_recorded_before_detection_arrays_carried_the_game_controller_still_reads(tmp_path):
    """The bag embeds the DetectionArray definition it was recorded with (no self_kicking, ball_owner,
    ball_owner_seconds, game_seconds_remaining): it decodes with that one, and export leaves those columns out."""
    first = next(iter(echo(BAG, "/team_b_0/detections", limit=1)))["message"]
    assert first["header"]["frame_id"] == "team_b_0/camera" and "self_penalized" in first
    assert not {"self_kicking", "ball_owner", "ball_owner_seconds", "game_seconds_remaining"} & set(first)
    written = export(BAG, tmp_path, fmt="csv")
    assert written["detections.csv"] > 0
    header = (tmp_path / "detections.csv").read_text().splitlines()[0].split(",")
    assert "self_penalized" in header and "ball_owner" not in header and "self_kicking" not in header
