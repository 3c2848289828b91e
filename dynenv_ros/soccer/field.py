"""SPL field geometry in metres, in the field frame: origin at the centre spot, x toward the goal team A attacks.

Dimensions follow the RoboCup SPL rules (2020 onward): 9 x 6 m field, 0.7 m border, penalty area 1.65 x 4.0 m,
goal area 0.6 x 2.2 m, penalty marks 1.3 m from the goal lines, centre circle 1.5 m in diameter. DynEnv drew a
single 0.6 x 2.2 m box per side and a circle of twice the radius it stored; see docs/differences.md.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dynenv_ros.core.object_classes import Subtype


@dataclass(frozen=True)
class LineCrossing:
    x: float
    y: float
    shape: Subtype  # CROSSING_L, CROSSING_T or CROSSING_X


@dataclass(frozen=True)
class FieldGeometry:
    length: float = 9.0
    width: float = 6.0
    border: float = 0.7
    line_width: float = 0.05
    penalty_area_length: float = 1.65
    penalty_area_width: float = 4.0
    goal_area_length: float = 0.6
    goal_area_width: float = 2.2
    penalty_mark_distance: float = 1.3
    center_circle_radius: float = 0.75
    goal_width: float = 1.6   # between goalpost centres
    goalpost_radius: float = 0.05
    penalty_mark_size: float = 0.1

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"{name} must be a positive length in metres, got {value!r}")
        hx, hy = self.length / 2, self.width / 2
        if not (self.goal_area_length < self.penalty_area_length < hx - self.center_circle_radius):
            raise ValueError("need goal area < penalty area < half field minus the centre circle (lengths)")
        if not (self.goal_width < self.goal_area_width < self.penalty_area_width < self.width):
            raise ValueError("need goal < goal area < penalty area < field (widths)")
        if not self.center_circle_radius < hy:
            raise ValueError("the centre circle must fit between the sidelines")

    @property
    def half_length(self) -> float:
        return self.length / 2

    @property
    def half_width(self) -> float:
        return self.width / 2

    @cached_property
    def lines(self) -> np.ndarray:
        """Straight field lines as an (N, 4) array of segments [x1, y1, x2, y2]."""
        hx, hy = self.half_length, self.half_width
        segments = [[-hx, -hy, hx, -hy], [-hx, hy, hx, hy], [-hx, -hy, -hx, hy], [hx, -hy, hx, hy],
                    [0.0, -hy, 0.0, hy]]
        for side in (-1.0, 1.0):
            goal_line = side * hx
            for depth, half in ((self.penalty_area_length, self.penalty_area_width / 2),
                                (self.goal_area_length, self.goal_area_width / 2)):
                front = goal_line - side * depth
                segments += [[front, -half, front, half], [goal_line, -half, front, -half],
                             [goal_line, half, front, half]]
        return np.asarray(segments, dtype=float)

    @cached_property
    def line_crossings(self) -> tuple[LineCrossing, ...]:
        """Where lines meet, with the shape a detector reports: corners L, junctions T, circle/halfway X."""
        hx, hy, r = self.half_length, self.half_width, self.center_circle_radius
        crossings = [LineCrossing(sx * hx, sy * hy, Subtype.CROSSING_L) for sx in (-1, 1) for sy in (-1, 1)]
        crossings += [LineCrossing(0.0, sy * hy, Subtype.CROSSING_T) for sy in (-1, 1)]
        crossings += [LineCrossing(0.0, sy * r, Subtype.CROSSING_X) for sy in (-1, 1)]
        for sx in (-1, 1):
            for depth, half in ((self.penalty_area_length, self.penalty_area_width / 2),
                                (self.goal_area_length, self.goal_area_width / 2)):
                for sy in (-1, 1):
                    crossings.append(LineCrossing(sx * hx, sy * half, Subtype.CROSSING_T))
                    crossings.append(LineCrossing(sx * (hx - depth), sy * half, Subtype.CROSSING_L))
        return tuple(crossings)

    @cached_property
    def penalty_marks(self) -> np.ndarray:
        """(3, 2): the centre spot and the two penalty marks."""
        mark = self.half_length - self.penalty_mark_distance
        return np.array([[0.0, 0.0], [-mark, 0.0], [mark, 0.0]])

    @cached_property
    def goalposts(self) -> np.ndarray:
        """(4, 2) goalpost centres: team A's own goal (x < 0), then the goal team A attacks (x > 0); y ascending."""
        hx, hg = self.half_length, self.goal_width / 2
        return np.array([[-hx, -hg], [-hx, hg], [hx, -hg], [hx, hg]])

    def is_inside_field(self, x: float, y: float) -> bool:
        return abs(x) <= self.half_length and abs(y) <= self.half_width

    def is_inside_world(self, x: float, y: float) -> bool:
        """On the carpet: the field plus its border."""
        return abs(x) <= self.half_length + self.border and abs(y) <= self.half_width + self.border
