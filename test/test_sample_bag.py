"""The sample bag in bags/ is what its README says: 30 s of a 2v2 game, every simulator topic, sim-time stamps,
chunk checksums; and a bag recorded before the checksums and the GameController fields still reads."""
import shutil
from pathlib import Path

import pytest

from dynenv_ros.bags.inspect import bag_info, echo, export, render
from dynenv_ros.bags.inspect import main as bag_main
from dynenv_ros.bags.mcap import scan

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "sample_2v2_realistic_30s"
OLD_BAG = REPO / "test" / "data" / "bag_before_checksums_2v2_30s"     # the sample bag of before 27 Nov 2026


def test_sample_bag_holds_a_whole_30_s_game_at_the_simulator_rates():
    info = bag_info(BAG)
    topics = {t["name"]: t for t in info["topics"]}
    assert info["duration_s"] == pytest.approx(30.0)
    for robot in ("team_a_0", "team_a_1", "team_b_0", "team_b_1"):
        assert topics[f"/{robot}/detections"]["count"] == 305          # 5 frames of period 0 + 60 periods x 5
        assert topics[f"/{robot}/feedback"]["count"] == 61
        assert topics[f"/{robot}/detections"]["rate_hz"] == pytest.approx(10.0, rel=0.02)
        assert topics[f"/{robot}/pose_estimate"]["count"] == 305     # self-localization, one per frame
    assert topics["/world_state"]["count"] == 305


def test_sample_bag_is_current_and_a_flipped_byte_in_it_is_found(tmp_path, capsys):
    """Recorded with chunk CRCs: one flipped byte inside a chunk is refused (exit 2), not read as data."""
    first = next(iter(echo(BAG, "/team_b_0/detections", limit=1)))["message"]
    assert {"self_kicking", "ball_owner", "ball_owner_seconds", "game_seconds_remaining"} <= set(first)
    copy = tmp_path / "bag"
    shutil.copytree(BAG, copy)
    data = bytearray((copy / "bag.mcap").read_bytes())
    chunk = scan(copy / "bag.mcap").chunks[2]
    data[chunk.start + chunk.length // 2] ^= 0xFF         # a message's bytes, in the middle of the third chunk
    (copy / "bag.mcap").write_bytes(bytes(data))
    assert bag_main(["info", str(copy)]) == 2
    assert "CRC" in capsys.readouterr().err


def test_sample_bag_decodes_and_replays(tmp_path):
    feedback = list(echo(BAG, "/team_a_0/feedback", limit=2))
    assert [f["message"]["motion_period"] for f in feedback] == [0, 1]
    frames = render(BAG, tmp_path / "replay.gif", robot="team_a_0", stride=50, pixels_per_metre=10)
    assert frames == 7 and (tmp_path / "replay.gif").stat().st_size > 0


def test_a_bag_recorded_before_detection_arrays_carried_the_game_controller_still_reads(tmp_path):
    """The old bag embeds the DetectionArray definition it was recorded with (no self_kicking, ball_owner,
    ball_owner_seconds, game_seconds_remaining): it decodes with that one, and export leaves those columns out."""
    first = next(iter(echo(OLD_BAG, "/team_b_0/detections", limit=1)))["message"]
    assert first["header"]["frame_id"] == "team_b_0/camera" and "self_penalized" in first
    assert not {"self_kicking", "ball_owner", "ball_owner_seconds", "game_seconds_remaining"} & set(first)
    written = export(OLD_BAG, tmp_path, fmt="csv")
    assert written["detections.csv"] > 0
    header = (tmp_path / "detections.csv").read_text().splitlines()[0].split(",")
    assert "self_penalized" in header and "ball_owner" not in header and "self_kicking" not in header
