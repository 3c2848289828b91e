"""Detection overlay: camera-frame rows land on the right field pixels, errors are marked, the figure script runs."""
from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image
from tool_scripts import load_tool

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.perception.detections import empty
from dynenv_ros.perception.params import load_preset
from dynenv_ros.render.detections import (BALL, ERROR, LINE_DETECTION, MISSED, camera_to_field, field_view,
                                          missed_positions, overlay_detections)
from dynenv_ros.render.topdown import CARPET, FOV, as_array, save_png
from dynenv_ros.soccer.field import FieldGeometry

PPM = 40
FIGURES = ("perception_none.png", "perception_realistic.png", "perception_realistic_m3.png", "perception_dynenv.png")


@pytest.fixture
def view():
    return field_view(FieldGeometry(), PPM)


def blank(view) -> Image.Image:
    return Image.new("RGB", view.size, CARPET)


def ball_at(x: float, y: float, **fields) -> np.ndarray:
    rows = empty(1)
    rows["class_id"] = rows["true_class"] = ObjectClass.BALL
    rows["x"], rows["y"] = x, y
    rows["true_id"] = 4
    for name, value in fields.items():
        rows[name] = value
    return rows


def colour_at(image: Image.Image, view, x: float, y: float) -> tuple[int, int, int]:
    col, row = view.field_to_pixel(x, y)
    return image.getpixel((int(col), int(row)))


def count(image: Image.Image, colour, view=None) -> int:
    """Pixels of ``colour``; with ``view``, on the carpet only (the legend below shows every colour once)."""
    pixels = np.asarray(image)
    if view is not None:
        pixels = pixels[view.strip_height:pixels.shape[0] - view.legend_height]
    return int(np.all(pixels == np.array(colour, np.uint8), axis=2).sum())


@pytest.mark.parametrize("heading, expected", [(0.0, (2.0, 0.0)), (math.pi / 2, (0.0, 2.0))])
def test_camera_x_lands_along_the_heading(view, heading, expected):
    assert np.allclose(camera_to_field((0.0, 0.0, heading), 2.0, 0.0), expected, atol=1e-12)
    image = overlay_detections(blank(view), view, (0.0, 0.0, heading), ball_at(2.0, 0.0))
    assert colour_at(image, view, *expected) == BALL
    other = (0.0, 2.0) if heading == 0.0 else (2.0, 0.0)
    assert colour_at(image, view, *other) == CARPET


def test_camera_y_is_left_of_the_gaze(view):
    pose = (1.0, -1.0, math.pi / 2)                    # looking along +y: camera-left is field -x
    assert np.allclose(camera_to_field(pose, 1.0, 0.5), (0.5, 0.0), atol=1e-12)


def test_false_positive_draws_red_and_a_true_detection_does_not(view):
    truthful = overlay_detections(blank(view), view, (0.0, 0.0, 0.0), ball_at(2.0, 0.0))
    assert count(truthful, ERROR, view) == 0
    fp = overlay_detections(blank(view), view, (0.0, 0.0, 0.0), ball_at(2.0, 0.0, true_id=-1, true_class=0))
    assert count(fp, ERROR, view) > 10


def test_confusion_is_ringed_in_red(view):
    confused = ball_at(2.0, 0.0, true_id=1102, true_class=ObjectClass.PENALTY_CROSS)
    image = overlay_detections(blank(view), view, (0.0, 0.0, 0.0), confused)
    assert count(image, ERROR, view) > 10
    assert colour_at(image, view, 2.0, 0.0) == BALL


def test_line_detection_draws_cyan_along_its_segment(view):
    rows = empty(1)
    rows["class_id"] = rows["true_class"] = ObjectClass.FIELD_LINE
    rows["true_id"] = -2
    rows["line_start_x"], rows["line_start_y"], rows["line_end_x"], rows["line_end_y"] = 1.0, -1.0, 3.0, -1.0
    image = overlay_detections(blank(view), view, (0.5, 0.5, 0.0), rows)
    for x in (1.6, 2.5, 3.4):                          # field segment (1.5, -0.5) → (3.5, -0.5)
        assert colour_at(image, view, x, -0.5) == LINE_DETECTION
    assert colour_at(image, view, 2.5, 0.5) == CARPET
    assert count(image, LINE_DETECTION, view) < 2.2 * PPM * 3     # a thin segment, nothing else


def test_missed_objects_are_hollow_white_circles(view):
    image = overlay_detections(blank(view), view, (0.0, 0.0, 0.0), empty(0), truth=[(1.0, 1.0)],
                               fov_half_angle=None)
    assert colour_at(image, view, 1.0, 1.0) == CARPET
    assert count(image, MISSED, view) > 10


def test_the_observers_view_wedge_and_the_detection_legend_are_drawn(view):
    """Edges at heading ± half angle from the observer; the second legend row names the detection marks."""
    image = overlay_detections(blank(view), view, (-1.0, 0.0, 0.0), empty(0), fov_half_angle=math.pi / 4)
    assert colour_at(image, view, 0.0, 1.0) == FOV and colour_at(image, view, 1.0, -2.0) == FOV
    assert colour_at(image, view, 1.0, 0.0) == CARPET                   # inside the wedge: nothing drawn
    legend = np.asarray(image)[image.size[1] - view.legend_height:]
    for colour in (BALL, LINE_DETECTION, ERROR):
        assert np.all(legend == np.array(colour, np.uint8), axis=2).any(), colour
    bare = overlay_detections(blank(view), view, (-1.0, 0.0, 0.0), empty(0), fov_half_angle=None, legend=False)
    assert count(bare, FOV) == 0 and count(bare, BALL) == 0


def test_missed_positions_skip_objects_that_have_a_detection():
    visible = np.array([True, True, False, True])
    ids = np.array([0, 4, 1000, 1102])
    rows = ball_at(1.0, 0.0, true_id=1102, class_id=ObjectClass.BALL, true_class=ObjectClass.PENALTY_CROSS)
    xs, ys = np.array([0.0, 1.0, 2.0, 3.0]), np.zeros(4)
    assert missed_positions(visible, rows, ids, xs, ys) == [(0.0, 0.0), (1.0, 0.0)]


def test_image_of_another_scale_is_refused(view):
    with pytest.raises(ValueError, match="pixels_per_metre"):
        overlay_detections(Image.new("RGB", (10, 10)), view, (0.0, 0.0, 0.0), empty(0))


@pytest.fixture(scope="module")
def figure_script():
    return load_tool("perception_figures")


def test_figure_script_writes_the_four_pngs_byte_identical_on_every_run(figure_script, tmp_path):
    """docs/perception.md: the pictures come from fixed seeds, byte-identical output."""
    first, second = tmp_path / "first", tmp_path / "second"
    assert figure_script.main(["--out", str(first)]) == 0
    assert figure_script.main(["--out", str(second)]) == 0
    expected = field_view(FieldGeometry(), figure_script.PIXELS_PER_METRE).size
    for name in FIGURES:
        data = (first / name).read_bytes()
        assert data == (second / name).read_bytes(), f"{name} differs between two runs"
        assert len(data) < 150_000
        with Image.open(first / name) as image:
            assert image.format == "PNG" and image.size == expected
    assert sorted(p.name for p in first.iterdir()) == sorted(FIGURES)
    assert len({(first / name).read_bytes() for name in FIGURES}) == len(FIGURES)   # four different pictures


def _figure_png(module, figure, seed, path):
    """One figure drawn from the period of world seed ``seed``: (PNG bytes, pixels below the caption strip)."""
    overrides = {} if figure.noise_magnitude is None else {"noise_magnitude": figure.noise_magnitude}
    period = module.run_period(load_preset(figure.preset, **overrides), seed)
    save_png(module.draw_figure(figure, period), path)
    with Image.open(path) as image:
        field = as_array(image)[field_view(FieldGeometry(), module.PIXELS_PER_METRE).strip_height:]
    return path.read_bytes(), field


@pytest.mark.parametrize("index", [1, 3], ids=["realistic", "dynenv"])
def test_figure_bytes_repeat_for_a_seed_and_change_with_it(figure_script, tmp_path, index):
    figure = figure_script.FIGURES[index]
    a_bytes, a_field = _figure_png(figure_script, figure, 5, tmp_path / "a.png")
    b_bytes, b_field = _figure_png(figure_script, figure, 5, tmp_path / "b.png")
    c_bytes, c_field = _figure_png(figure_script, figure, 6, tmp_path / "c.png")
    assert a_bytes == b_bytes                           # same seed: the same file, byte for byte
    assert c_bytes != a_bytes                           # another seed: another file ...
    assert not np.array_equal(c_field, a_field)         # ... and not only its caption: the drawn detections differ
