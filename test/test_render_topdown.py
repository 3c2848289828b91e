"""Top-down renderer: geometry of the image, what lands on which pixel, and atomic PNG/GIF writing."""
from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest
from PIL import Image

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.render.topdown import (LEGEND_HEIGHT, STRIP_HEIGHT, EpisodeRecorder, FieldView, as_array, render_snapshot,
                                       save_png)
from dynenv_ros.soccer.actions import SoccerAction
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld

PPM = 40


@pytest.fixture
def world() -> SoccerWorld:
    return SoccerWorld(SoccerConfig.from_mapping({"falls": {"enabled": False}}), seed=0)


def render(world: SoccerWorld, snapshot=None, **kwargs) -> np.ndarray:
    snap = snapshot if snapshot is not None else world.snapshot()
    return as_array(render_snapshot(snap, world.config.field, pixels_per_metre=PPM,
                                    ball_radius=world.config.ball.radius, **kwargs))


def pixel(world: SoccerWorld, rgb: np.ndarray, x: float, y: float) -> np.ndarray:
    col, row = FieldView(world.config.field, PPM).field_to_pixel(x, y)
    return rgb[int(row), int(col)].astype(int)


def patch(world: SoccerWorld, rgb: np.ndarray, x: float, y: float, half: int = 6) -> np.ndarray:
    col, row = (int(v) for v in FieldView(world.config.field, PPM).field_to_pixel(x, y))
    return rgb[row - half:row + half + 1, col - half:col + half + 1].reshape(-1, 3).astype(int)


def count(pixels: np.ndarray, predicate) -> int:
    return sum(bool(predicate(p)) for p in pixels)


def is_orange(p) -> bool:
    return p[0] > 200 and 90 < p[1] < 190 and p[2] < 80


def is_blue(p) -> bool:
    return p[2] > 150 and p[2] > p[0] + 80 and p[2] > p[1] + 80


def is_red(p) -> bool:
    return p[0] > 150 and p[0] > p[1] + 80 and p[0] > p[2] + 80


def is_white(p) -> bool:
    return min(p) > 200


def test_size_and_array_format(world):
    g = world.config.field
    rgb = render(world)
    width = round(2 * (g.half_length + g.border) * PPM)
    height = round(2 * (g.half_width + g.border) * PPM) + STRIP_HEIGHT + LEGEND_HEIGHT   # strip, carpet, legend
    assert rgb.shape == (height, width, 3) and rgb.dtype == np.uint8
    assert FieldView(g, PPM).size == (width, height)
    assert rgb.flags.writeable  # a copy, safe for the caller to draw on


def test_ball_robots_and_lines_land_on_their_pixels(world):
    world.place_ball(1.0, -1.5)
    world.place_robot(0, -1.0, 1.0, 0.0)       # team A, facing +x: probe behind the heading tick
    world.place_robot(2, 2.5, 1.0, math.pi)    # team B, facing -x
    rgb = render(world)
    assert is_orange(pixel(world, rgb, 1.0, -1.5))
    assert is_blue(pixel(world, rgb, -1.05, 1.0))
    assert is_red(pixel(world, rgb, 2.55, 1.0))
    g = world.config.field
    assert is_white(pixel(world, rgb, 0.0, 0.0))                       # centre spot (ball moved away)
    assert is_white(pixel(world, rgb, -g.half_length, -2.0))           # own goal line
    assert is_white(pixel(world, rgb, 0.0, g.center_circle_radius))    # centre circle on the halfway line
    assert is_white(pixel(world, rgb, 2.0, g.half_width))              # left sideline: top of the carpet
    assert is_white(pixel(world, rgb, g.half_length - g.penalty_mark_distance, 0.0))
    carpet = pixel(world, rgb, 2.0, -2.0)
    assert carpet[1] > carpet[0] + 40 and carpet[1] > carpet[2] + 40   # green, nothing drawn there


def test_field_y_is_flipped_to_image_rows(world):
    world.place_ball(3.0, 2.0)
    rgb = render(world)
    rows, _ = np.nonzero([[is_orange(p) for p in row] for row in rgb[:-LEGEND_HEIGHT].astype(int)])  # not the legend
    assert rows.size > 0
    carpet_middle = STRIP_HEIGHT + (rgb.shape[0] - STRIP_HEIGHT - LEGEND_HEIGHT) / 2
    assert rows.max() < carpet_middle  # y = +2 (left) is up in the picture


def test_moving_the_ball_changes_the_image(world):
    world.place_ball(1.0, 1.0)
    before = render(world)
    world.place_ball(-1.0, -1.0)
    after = render(world)
    assert not np.array_equal(before, after)
    assert is_orange(pixel(world, before, 1.0, 1.0)) and not is_orange(pixel(world, after, 1.0, 1.0))


def test_fallen_robot_is_hollow_and_penalized_is_dimmed(world):
    world.place_robot(0, -2.0, -1.0, 0.0)
    world.place_robot(1, -2.0, 1.0, 0.0)
    snap = world.snapshot()
    objects = tuple(dataclasses.replace(o, status=ObjectStatus.FALLEN) if o.id == 0 else
                    dataclasses.replace(o, status=ObjectStatus.PENALIZED) if o.id == 1 else o
                    for o in snap.objects)
    rgb = render(world, dataclasses.replace(snap, objects=objects))
    normal = render(world)
    fallen_box, standing_box = patch(world, rgb, -2.0, -1.0), patch(world, normal, -2.0, -1.0)
    fallen_blue, standing_blue = count(fallen_box, is_blue), count(standing_box, is_blue)
    assert standing_blue > 10 and fallen_blue < standing_blue / 2          # hollow: little team colour left
    assert count(fallen_box, lambda p: abs(p[0] - 128) < 20 and abs(p[1] - 128) < 20 and abs(p[2] - 128) < 20)
    penalized_box, active_box = patch(world, rgb, -2.0, 1.0), patch(world, normal, -2.0, 1.0)
    assert count(penalized_box, is_blue) == 0 and count(active_box, is_blue) > 10   # dimmed toward the carpet
    assert count(penalized_box, lambda p: p[2] > p[0] + 40 and p[2] > 100) > 10     # yet still bluish


def test_fov_wedge_is_drawn_and_checked(world):
    world.place_ball(-3.0, -2.5)
    world.place_robot(0, 0.0, 0.0, 0.0)
    plain = render(world)
    wedge = render(world, fov=(0, math.radians(30)))
    x = 3.0  # along the upper ray, y = x * tan(30 deg)
    assert not np.array_equal(plain, wedge)
    assert count(patch(world, wedge, x, x * math.tan(math.radians(30)), 2), lambda p: min(p) > 120)  # pale ray
    assert not count(patch(world, plain, x, x * math.tan(math.radians(30)), 2), lambda p: min(p) > 120)
    assert np.array_equal(pixel(world, plain, 3.0, 0.0), pixel(world, wedge, 3.0, 0.0))  # inside: untouched
    with pytest.raises(ValueError, match="no robot with id"):
        render(world, fov=(99, 0.5))
    with pytest.raises(ValueError, match="half angle"):
        render(world, fov=(0, 4.0))


def test_rejects_bad_scale(world):
    for ppm in (0, -5, float("nan")):
        with pytest.raises(ValueError, match="pixels_per_metre"):
            render_snapshot(world.snapshot(), world.config.field, pixels_per_metre=ppm)
        with pytest.raises(ValueError, match="pixels_per_metre"):
            EpisodeRecorder(world.config.field, pixels_per_metre=ppm)


def test_png_is_written_atomically(world, tmp_path):
    image = render_snapshot(world.snapshot(), world.config.field, pixels_per_metre=PPM)
    path = tmp_path / "frame.png"
    save_png(image, path)
    assert sorted(os.listdir(tmp_path)) == ["frame.png"]   # no .tmp left behind
    with Image.open(path) as back:
        assert back.format == "PNG" and back.size == image.size
        assert np.array_equal(as_array(back), as_array(image))
    with pytest.raises(ValueError, match="does not exist"):
        save_png(image, tmp_path / "missing" / "frame.png")


def test_failed_write_leaves_no_file(world, tmp_path):
    class Broken(Exception):
        pass

    image = render_snapshot(world.snapshot(), world.config.field, pixels_per_metre=PPM)
    path = tmp_path / "frame.png"

    def explode(*args, **kwargs):
        open(str(path) + ".tmp", "wb").write(b"half a png")
        raise Broken

    image.save = explode  # instance attribute: this image only
    with pytest.raises(Broken):
        save_png(image, path)
    assert os.listdir(tmp_path) == []


def test_gif_round_trip(world, tmp_path):
    recorder = EpisodeRecorder(world.config.field, pixels_per_metre=10, ball_radius=world.config.ball.radius)
    with pytest.raises(ValueError, match="no frames"):
        recorder.save_gif(tmp_path / "empty.gif")
    idle = [SoccerAction()] * world.n_robots
    for i in range(4):
        world.place_ball(-2.0 + i, 0.5 * i)
        recorder.add(world.snapshot())
        world.step(idle)
    assert len(recorder) == 4
    path = tmp_path / "episode.gif"
    recorder.save_gif(path, fps=5)
    assert sorted(os.listdir(tmp_path)) == ["episode.gif"]
    with Image.open(path) as gif:
        assert gif.format == "GIF" and gif.n_frames == 4 and gif.info.get("loop") == 0
        assert gif.info.get("duration") == 200
    for fps in (0, -1.0):
        with pytest.raises(ValueError, match="fps"):
            recorder.save_gif(path, fps=fps)
    with pytest.raises(ValueError, match="does not exist"):
        recorder.save_gif(tmp_path / "nope" / "episode.gif")


def test_strip_shows_text(world):
    rgb = render(world)
    strip = rgb[:STRIP_HEIGHT].astype(int)
    assert (strip.min(axis=2) > 200).sum() > 50   # light text on the dark strip
    assert ObjectClass.BALL in {o.class_id for o in world.snapshot().objects}


def test_robots_are_labelled_and_a_legend_names_the_marks(world):
    """Each robot carries its short name (a0 = team_a_0) in light text beside it; the legend row below the carpet
    shows both team colours and the ball's."""
    world.place_robot(0, -2.0, 1.0, 0.0)
    rgb = render(world)
    col, row = (int(v) for v in FieldView(world.config.field, PPM).field_to_pixel(-2.0, 1.0))
    near = rgb[max(0, row - 30):row, col:col + 40].astype(int)
    assert np.sum(np.all(near > 200, axis=2)) > 5                       # label text up and right of the robot
    legend = rgb[-LEGEND_HEIGHT:].astype(int)
    assert any(is_blue(p) for p in legend.reshape(-1, 3)) and any(is_red(p) for p in legend.reshape(-1, 3))
    assert any(is_orange(p) for p in legend.reshape(-1, 3))
