"""SPL field geometry: the lines, crossings, marks and posts a detector can see, mirror-symmetric between teams."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dynenv_ros.core.object_classes import Subtype
from dynenv_ros.soccer.field import FieldGeometry

FIELD = FieldGeometry()


def point_on_segment(point: np.ndarray, segment: np.ndarray, tolerance: float = 1e-9) -> bool:
    start, end = segment[:2], segment[2:]
    direction = end - start
    t = np.clip(np.dot(point - start, direction) / np.dot(direction, direction), 0.0, 1.0)
    return bool(np.linalg.norm(start + t * direction - point) < tolerance)


def test_lines_are_boundary_halfway_and_two_boxes_per_side():
    assert FIELD.lines.shape == (5 + 2 * 2 * 3, 4)
    total_length = np.linalg.norm(FIELD.lines[:, 2:] - FIELD.lines[:, :2], axis=1).sum()
    boxes = 2 * (4.0 + 2 * 1.65) + 2 * (2.2 + 2 * 0.6)
    assert total_length == pytest.approx(2 * 9 + 2 * 6 + 6 + boxes)


def test_every_crossing_lies_where_its_shape_says():
    on_circle = lambda c: abs(np.hypot(c.x, c.y) - FIELD.center_circle_radius) < 1e-9  # noqa: E731
    for crossing in FIELD.line_crossings:
        point = np.array([crossing.x, crossing.y])
        touching = sum(point_on_segment(point, segment) for segment in FIELD.lines) + on_circle(crossing)
        assert touching >= 2, crossing  # a crossing is where at least two lines meet
    shapes = [c.shape for c in FIELD.line_crossings]
    assert (shapes.count(Subtype.CROSSING_L), shapes.count(Subtype.CROSSING_T),
            shapes.count(Subtype.CROSSING_X)) == (12, 10, 2)


def test_geometry_is_mirror_symmetric_between_the_teams():
    def point_set(points):
        return {(round(x, 9), round(y, 9)) for x, y in points}
    crossings = {(round(c.x, 9), round(c.y, 9), c.shape) for c in FIELD.line_crossings}
    assert crossings == {(round(-x, 9) + 0.0, round(-y, 9) + 0.0, s) for x, y, s in crossings}
    assert point_set(FIELD.goalposts) == point_set(-FIELD.goalposts)
    assert point_set(FIELD.penalty_marks) == point_set(-FIELD.penalty_marks)
    segments = {tuple(np.round(s, 9)) for s in FIELD.lines}
    mirrored = {tuple(np.round(-s, 9) + 0.0) for s in FIELD.lines}
    assert {frozenset([a[:2], a[2:]]) for a in segments} == {frozenset([a[:2], a[2:]]) for a in mirrored}


def test_marks_posts_and_regions():
    assert FIELD.penalty_marks[2] == pytest.approx([3.2, 0.0])
    assert np.all(np.abs(FIELD.goalposts[:, 0]) == 4.5) and np.all(np.abs(FIELD.goalposts[:, 1]) == 0.8)
    assert FIELD.is_inside_field(4.5, 3.0) and not FIELD.is_inside_field(4.51, 0.0)
    assert FIELD.is_inside_world(5.1, -3.6) and not FIELD.is_inside_world(5.3, 0.0)


@pytest.mark.parametrize("change, reason", [
    ({"length": -9.0}, "positive length"),
    ({"goal_area_length": 2.0}, "goal area < penalty area"),
    ({"goal_width": 3.0}, "goal < goal area"),
    ({"center_circle_radius": 3.5}, "centre circle"),
])
def test_inconsistent_dimensions_are_refused(change, reason):
    with pytest.raises(ValueError, match=reason):
        dataclasses.replace(FIELD, **change)
