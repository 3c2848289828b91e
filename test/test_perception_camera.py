"""Image observation mode: pinhole geometry of the NAO cameras and what lands in which segmentation channel.

Expected pixels are computed here from angles (depression below the horizon minus the camera pitch), not with the
module's own projection, so a wrong sign, axis or scale in the module shows up as a failure.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception import detections as det
from dynenv_ros.perception.camera import (NAO_BOTTOM, NAO_TOP, CameraModel, ImageConfig, project_points,
                                          render_segmentation)
from detection_rows import rows

FULL = ImageConfig(640, 480)
BALL, ROBOT, POST, LINES = 0, 1, 2, 3          # channel inside a camera's block
TOP, BOTTOM = 0, 4                             # first channel of each camera's block
F = 543.6                                      # px at 640x480
CX, CY = 319.5, 239.5



def ball(x: float, y: float, diameter: float = 0.1) -> dict:
    return {"class_id": ObjectClass.BALL, "x": x, "y": y, "size_x": diameter}


def line(x0: float, y0: float, x1: float, y1: float) -> dict:
    return {"class_id": ObjectClass.FIELD_LINE, "x": (x0 + x1) / 2, "y": (y0 + y1) / 2,
            "line_start_x": x0, "line_start_y": y0, "line_end_x": x1, "line_end_y": y1}


def expected_pixel(camera: CameraModel, x: float, z: float) -> tuple[float, float, float]:
    """(u, v, depth) at 640x480 of a point straight ahead (y = 0) at distance x and height z, from angles."""
    dx, dz = x - camera.forward_offset, camera.height - z
    below_axis = math.atan2(dz, dx) - camera.pitch           # angle under the optical axis
    return CX, CY + F * math.tan(below_axis), math.hypot(dx, dz) * math.cos(below_axis)


def set_pixels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rr, cc = np.nonzero(mask)
    return rr, cc


def only_channels(img: np.ndarray, *channels: int) -> None:
    for ch in range(img.shape[0]):
        assert img[ch].any() == (ch in channels), f"channel {ch}"


def test_output_is_uint8_0_1_with_four_channels_per_camera() -> None:
    frame = rows(ball(0.5, 0.0), ball(2.0, 0.5), {"class_id": ObjectClass.ROBOT, "x": 2.0, "y": -0.4},
                 {"class_id": ObjectClass.GOALPOST, "x": 4.0, "y": 0.8, "size_x": 0.1},
                 {"class_id": ObjectClass.PENALTY_CROSS, "x": 0.4, "y": 0.1},
                 {"class_id": ObjectClass.LINE_CROSSING, "x": 1.5, "y": -0.5}, line(0.3, -2, 0.3, 2),
                 {"class_id": ObjectClass.CENTER_CIRCLE, "x": 2.5, "y": 0.0, "size_x": 1.5})
    img = render_segmentation(frame, ImageConfig(160, 120))
    assert img.shape == (8, 120, 160) and img.dtype == np.uint8
    assert set(np.unique(img)) == {0, 1}
    bottom_only = render_segmentation(frame, ImageConfig(160, 120), cameras=(NAO_BOTTOM,))
    np.testing.assert_array_equal(bottom_only, img[4:])


def test_ball_ahead_lands_where_the_pinhole_formula_says_in_the_bottom_camera() -> None:
    u, v, depth = expected_pixel(NAO_BOTTOM, 0.5, 0.05)
    img = render_segmentation(rows(ball(0.5, 0.0)), FULL)
    only_channels(img, BOTTOM + BALL)
    mask = img[BOTTOM + BALL]
    assert mask[round(v), round(u)] == 1
    rr, cc = set_pixels(mask)
    assert abs(cc.mean() - u) < 0.6 and abs(rr.mean() - v) < 0.6
    radius = F * 0.05 / depth                                # disc radius f·r/depth
    assert math.pi * radius ** 2 <= len(rr) <= math.pi * (radius + 1) ** 2


def test_ball_at_one_metre_is_in_the_top_camera_and_above_the_bottom_cameras_view() -> None:
    u, v, _ = expected_pixel(NAO_TOP, 1.0, 0.05)
    img = render_segmentation(rows(ball(1.0, 0.0)), FULL)
    only_channels(img, TOP + BALL)
    assert img[TOP + BALL, round(v), round(u)] == 1
    rr, cc = set_pixels(img[TOP + BALL])
    assert abs(cc.mean() - u) < 0.6 and abs(rr.mean() - v) < 0.6
    # Why the bottom camera misses it: the ball's lowest point is higher than the bottom camera's upper image edge.
    top_edge = NAO_BOTTOM.pitch - math.atan(CY / F)
    lowest = math.atan2(NAO_BOTTOM.height, 1.0 - NAO_BOTTOM.forward_offset)
    assert lowest < top_edge


def test_ball_behind_the_camera_draws_nothing() -> None:
    img = render_segmentation(rows(ball(-1.0, 0.0)), FULL)
    assert not img.any()


@pytest.mark.parametrize("y, left", [(1.0, True), (-1.0, False)])
def test_ball_to_the_left_shows_in_the_left_half(y: float, left: bool) -> None:
    img = render_segmentation(rows(ball(2.0, y)), FULL)
    only_channels(img, TOP + BALL)
    _, cc = set_pixels(img[TOP + BALL])
    assert (cc < FULL.width / 2).all() if left else (cc >= FULL.width / 2).all()


def test_goalpost_is_an_upright_bar_centred_on_the_middle_column() -> None:
    img = render_segmentation(rows({"class_id": ObjectClass.GOALPOST, "x": 3.0, "y": 0.0, "size_x": 0.1}), FULL)
    only_channels(img, TOP + POST)
    rr, cc = set_pixels(img[TOP + POST])
    height, width = np.ptp(rr) + 1, np.ptp(cc) + 1
    assert height > 4 * width
    assert abs(cc.mean() - (FULL.width / 2 - 0.5)) < 0.5
    _, v_foot, _ = expected_pixel(NAO_TOP, 3.0, 0.0)
    _, v_top, _ = expected_pixel(NAO_TOP, 3.0, 0.8)
    assert abs(rr.min() - v_top) <= 1 and abs(rr.max() - v_foot) <= 1


def test_robot_is_drawn_as_a_standing_nao() -> None:
    img = render_segmentation(rows({"class_id": ObjectClass.ROBOT, "x": 2.0, "y": 0.0, "size_x": 0.2}), FULL)
    only_channels(img, TOP + ROBOT)
    rr, cc = set_pixels(img[TOP + ROBOT])
    _, v_foot, depth_foot = expected_pixel(NAO_TOP, 2.0, 0.0)
    _, v_head, _ = expected_pixel(NAO_TOP, 2.0, 0.58)
    assert abs(rr.min() - v_head) <= 1 and abs(rr.max() - v_foot) <= 1
    # 0.3 m wide: at least as wide as at its farthest point, the feet (lower in a down-pitched camera = nearer).
    width = np.ptp(cc) + 1
    assert F * 0.3 / depth_foot - 1 <= width <= F * 0.3 / depth_foot * 1.3 + 2


def test_field_line_in_front_draws_in_the_bottom_cameras_line_channel() -> None:
    img = render_segmentation(rows(line(0.5, -1.0, 0.5, 1.0)), FULL)
    only_channels(img, BOTTOM + LINES)
    rr, cc = set_pixels(img[BOTTOM + LINES])
    assert cc.min() == 0 and cc.max() == FULL.width - 1             # crosses the whole image
    _, v, _ = expected_pixel(NAO_BOTTOM, 0.5, 0.0)
    assert rr.min() <= v <= rr.max()


def test_penalty_cross_and_line_crossing_mark_the_line_channel() -> None:
    for cls in (ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING):
        img = render_segmentation(rows({"class_id": cls, "x": 0.5, "y": 0.0}), FULL)
        only_channels(img, BOTTOM + LINES)
        u, v, _ = expected_pixel(NAO_BOTTOM, 0.5, 0.0)
        assert img[BOTTOM + LINES, round(v), round(u)] == 1


def test_center_circle_is_a_ring_with_an_empty_middle() -> None:
    img = render_segmentation(rows({"class_id": ObjectClass.CENTER_CIRCLE, "x": 2.5, "y": 0.0, "size_x": 1.5}),
                              FULL)
    mask = img[TOP + LINES]
    for x, painted in ((1.75, True), (2.5, False), (3.25, True)):
        u, v, _ = expected_pixel(NAO_TOP, x, 0.0)
        assert mask[round(v), round(u)] == painted, x


def test_geometry_behind_the_camera_is_clipped_not_wrapped() -> None:
    # A line from behind the robot to 2 m ahead passes under both cameras; its far part must stay a narrow band
    # around the middle column, with nothing mirrored into the top of the image.
    img = render_segmentation(rows(line(-2.0, 0.0, 2.0, 0.0)), FULL)
    for block in (TOP, BOTTOM):
        rr, cc = set_pixels(img[block + LINES])
        assert len(rr) and np.abs(cc - CX).max() < 60
    _, v_far, _ = expected_pixel(NAO_TOP, 2.0, 0.0)
    assert set_pixels(img[TOP + LINES])[0].min() >= math.floor(v_far) - 1
    assert img[BOTTOM + LINES, -1].any()                          # reaches the bottom edge (under the camera)


def test_unknown_classes_are_skipped() -> None:
    frame = rows({"class_id": ObjectClass.UNKNOWN, "x": 0.5, "y": 0.0, "size_x": 0.1},
                 {"class_id": ObjectClass.CAR, "x": 1.0, "y": 0.0, "size_x": 1.0})
    assert not render_segmentation(frame, FULL).any()


def test_160x120_is_a_4x_downscale_of_640x480() -> None:
    # Coverage rule "any part of the object in the pixel" makes the small image the 4x4 max-pool of the big one.
    frame = rows(ball(0.5, 0.1), ball(1.5, -0.3), {"class_id": ObjectClass.ROBOT, "x": 2.0, "y": 0.5},
                 {"class_id": ObjectClass.GOALPOST, "x": 3.0, "y": -0.8, "size_x": 0.1},
                 line(0.3, -2.0, 0.3, 2.0), line(0.4, 0.4, 4.0, 0.9),
                 {"class_id": ObjectClass.CENTER_CIRCLE, "x": 2.5, "y": 0.3, "size_x": 1.5})
    big = render_segmentation(frame, FULL)
    small = render_segmentation(frame, ImageConfig(160, 120))
    pooled = big.reshape(8, 120, 4, 160, 4).max(axis=(2, 4))
    assert all(small[ch].any() for ch in (TOP + BALL, TOP + ROBOT, TOP + POST, TOP + LINES, BOTTOM + LINES))
    assert (pooled != small).sum() <= 4


def test_project_points() -> None:
    cam = NAO_TOP
    on_axis = [[cam.forward_offset + math.cos(cam.pitch), 0.0, cam.height - math.sin(cam.pitch)]]
    uv, depth = project_points(np.array(on_axis + [[-1.0, 0.0, 0.0]]), cam, FULL)
    np.testing.assert_allclose(uv[0], [CX, CY], atol=1e-9)
    assert depth[0] == pytest.approx(1.0) and depth[1] < 0 and np.isnan(uv[1]).all()
    uv, _ = project_points(np.array(on_axis), cam, ImageConfig(160, 120))
    np.testing.assert_allclose(uv[0], [79.5, 59.5], atol=1e-9)
    with pytest.raises(ValueError, match="shape"):
        project_points(np.zeros((3, 2)), cam, FULL)


@pytest.mark.parametrize("width, height", [(0, 480), (640, -1), (640.0, 480), (True, 480), ("640", 480)])
def test_bad_image_config_raises(width, height) -> None:
    with pytest.raises(ValueError, match="positive integer"):
        ImageConfig(width, height)


@pytest.mark.parametrize("bad", [np.zeros(3), np.zeros(2, dtype=[("x", np.float32), ("y", np.float32)]),
                                 [ball(1.0, 0.0)], det.empty(4).reshape(2, 2)])
def test_bad_detections_raise(bad) -> None:
    with pytest.raises(ValueError, match="DETECTION_DTYPE|one-dimensional"):
        render_segmentation(bad, FULL)


def test_wrong_dtype_message_names_the_expected_dtype() -> None:
    with pytest.raises(ValueError, match="DETECTION_DTYPE"):
        render_segmentation(np.zeros(3), FULL)
