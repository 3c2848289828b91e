"""The driving map as pure geometry: roads, lanes, walkways, buildings, spawn spots, destinations.

Map frame (see config.py): origin at the lower-left corner, x east, y north, metres; traffic drives on the right.
Each road has a centre line from ``start`` to ``end``; a point is described on it by its longitudinal coordinate
``s`` (0 at ``start``) and its lateral offset ``d`` (positive to the left of the road's direction).

Nothing here moves or draws; the world, the scripted driver, perception and the renderer all read this.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property

import numpy as np

from dynenv_ros.driving.config import MapConfig


class LanePosition(IntEnum):
    """Where a car is, best first: a car takes the best class over all roads (docs/original.md §3)."""
    AT_GOAL = 0
    RIGHT_LANE = 1
    OPPOSING_LANE = 2
    OVER_ROAD = 3            # on a road's width but past one of its ends
    OFF_ROAD = 4


class LineKind(IntEnum):
    """Lane-line type, as DynEnv's full-state lanes (§4.6): 1 edge, −1 centre, 0 between lanes of one direction."""
    INNER = 0
    EDGE = 1
    CENTRE = -1


@dataclass(frozen=True)
class Road:
    name: str
    start: tuple[float, float]
    end: tuple[float, float]
    lanes: int               # per direction
    lane_width: float

    @cached_property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    @cached_property
    def direction(self) -> tuple[float, float]:
        """Unit vector from start to end."""
        return ((self.end[0] - self.start[0]) / self.length, (self.end[1] - self.start[1]) / self.length)

    @cached_property
    def heading(self) -> float:
        return math.atan2(self.direction[1], self.direction[0])

    @property
    def half_width(self) -> float:
        """Centre line to edge, m."""
        return self.lanes * self.lane_width

    def to_road(self, x: float, y: float) -> tuple[float, float]:
        """(s, d): along the road from its start, and to the left of it."""
        ux, uy = self.direction
        dx, dy = x - self.start[0], y - self.start[1]
        return dx * ux + dy * uy, -dx * uy + dy * ux

    def to_map(self, s: float, d: float) -> tuple[float, float]:
        ux, uy = self.direction
        return self.start[0] + s * ux - d * uy, self.start[1] + s * uy + d * ux

    def lane_offset(self, sign: int, k: int) -> float:
        """Lateral offset d of the centre of lane k (0 = next to the centre line) for traffic in direction
        ``sign`` (+1 start→end, −1 end→start). Right-hand traffic: +1 drives at d < 0."""
        return -sign * (k + 0.5) * self.lane_width


def classify_on_road(road: Road, x: float, y: float, yaw: float, off_margin: float,
                     end_margin: float) -> tuple[LanePosition, int]:
    """Lane position of a pose on one road, and which end it is past (−1 start, +1 end, 0 none)."""
    s, d = road.to_road(x, y)
    if abs(d) >= road.half_width + off_margin:
        return LanePosition.OFF_ROAD, 0
    if s < -end_margin:
        return LanePosition.OVER_ROAD, -1
    if s > road.length + end_margin:
        return LanePosition.OVER_ROAD, 1
    along = math.cos(road.heading - yaw)
    return (LanePosition.RIGHT_LANE if along * d < 0 else LanePosition.OPPOSING_LANE), 0


@dataclass(frozen=True)
class Building:
    x: float
    y: float
    half_x: float
    half_y: float

    @property
    def corners(self) -> np.ndarray:
        """(4, 2), counter-clockwise from the lower-left corner."""
        return np.array([[self.x - self.half_x, self.y - self.half_y], [self.x + self.half_x, self.y - self.half_y],
                         [self.x + self.half_x, self.y + self.half_y], [self.x - self.half_x, self.y + self.half_y]])


@dataclass(frozen=True)
class LaneLine:
    road: int
    x1: float
    y1: float
    x2: float
    y2: float
    kind: LineKind
    offset: float            # lateral offset d on its road


@dataclass(frozen=True)
class LaneCentre:
    """The centre of one lane, as a segment in its direction of travel."""
    road: int
    sign: int                # +1 start→end, −1 end→start
    k: int                   # 0 next to the centre line
    x1: float
    y1: float
    x2: float
    y2: float

    @property
    def heading(self) -> float:
        return math.atan2(self.y2 - self.y1, self.x2 - self.x1)


@dataclass(frozen=True)
class SpawnSpot:
    x: float
    y: float
    yaw: float
    road: int
    end: int                 # index into DrivingMap.destinations of the road end the car enters from
    lane: int                # k, 0 next to the centre line


@dataclass(frozen=True)
class WalkwaySegment:
    """A stretch of walkway between a map edge and the other road: pedestrians walk along it, obstacles stand on it.

    ``side`` is +1 left of the road's direction, −1 right; ``s_min..s_max`` its extent along the road.
    """
    road: int
    side: int
    s_min: float
    s_max: float
    inner: float             # |d| of the road edge
    outer: float             # |d| of the walkway line

    @property
    def length(self) -> float:
        return self.s_max - self.s_min


class DrivingMap:
    """The map of one DrivingConfig: roads[0] runs north (x = vertical_road_x), roads[1] east (y = horizontal_road_y).

    Destinations are the four road ends: 0 south end, 1 north end (vertical road), 2 west end, 3 east end.
    """

    def __init__(self, config: MapConfig | None = None) -> None:
        self.config = m = config or MapConfig()
        self.width, self.height = m.width, m.height
        self.roads = (Road("vertical", (m.vertical_road_x, 0.0), (m.vertical_road_x, m.height), m.vertical_lanes,
                           m.lane_width),
                      Road("horizontal", (0.0, m.horizontal_road_y), (m.width, m.horizontal_road_y),
                           m.horizontal_lanes, m.lane_width))
        self.crossing = (m.vertical_road_x, m.horizontal_road_y)
        hx, hy = m.building_half_size
        self.buildings = tuple(Building(x, y, hx, hy) for x, y in m.building_centres)
        self.destinations = np.array([self.roads[0].start, self.roads[0].end, self.roads[1].start,
                                      self.roads[1].end], dtype=float)
        self._end_of = {(0, -1): 0, (0, 1): 1, (1, -1): 2, (1, 1): 3}
        # Per road, what classify() needs, precomputed: it runs for every car at every vision instant.
        self._classify_rows = tuple(
            (r, road.start[0], road.start[1], road.direction[0], road.direction[1], road.length,
             road.half_width + m.off_road_margin, self._end_of[(r, -1)], self._end_of[(r, 1)])
            for r, road in enumerate(self.roads))

    # -- ends --------------------------------------------------------------------------------------------------
    def end_index(self, road: int, end: int) -> int:
        """Destination index of a road's start (end = −1) or end (+1)."""
        return self._end_of[(road, end)]

    def road_of_end(self, index: int) -> tuple[int, int]:
        """(road, −1 start / +1 end) of a destination index."""
        for key, value in self._end_of.items():
            if value == index:
                return key
        raise IndexError(f"no road end {index}; the map has 4")

    def nearest_end(self, x: float, y: float) -> int:
        return int(np.argmin(np.hypot(self.destinations[:, 0] - x, self.destinations[:, 1] - y)))

    # -- classification ---------------------------------------------------------------------------------------
    def classify(self, x: float, y: float, yaw: float, goal: int | None = None) -> LanePosition:
        """The best lane position over both roads; AT_GOAL when past the destination ``goal``'s road end and within
        the goal radius of it (docs/original.md §3: AtGoal < InRightLane < InOpposingLane < OverRoad < OffRoad).

        The same rule as ``classify_on_road`` per road, inlined (it runs for every car at every vision instant).
        """
        m = self.config
        margin = m.end_margin
        cy, sy = math.cos(yaw), math.sin(yaw)
        best = LanePosition.OFF_ROAD
        for _, x0, y0, ux, uy, length, off, start_end, end_end in self._classify_rows:
            dx, dy = x - x0, y - y0
            d = -dx * uy + dy * ux
            if abs(d) >= off:
                continue
            s = dx * ux + dy * uy
            if s < -margin or s > length + margin:
                if goal is not None and goal == (start_end if s < 0 else end_end):
                    gx, gy = self.destinations[goal]
                    if math.hypot(x - gx, y - gy) <= m.goal_radius:
                        return LanePosition.AT_GOAL
                position = LanePosition.OVER_ROAD
            else:   # cos(road heading − yaw) · d < 0: the right-hand side of the road for this heading
                position = LanePosition.RIGHT_LANE if (ux * cy + uy * sy) * d < 0 else LanePosition.OPPOSING_LANE
            if position < best:
                best = position
        return best

    def on_carriageway(self, x: float, y: float, margin: float = 0.0) -> bool:
        """Within a road's width (plus ``margin``) and between its ends."""
        for road in self.roads:
            s, d = road.to_road(x, y)
            if abs(d) < road.half_width + margin and 0.0 <= s <= road.length:
                return True
        return False

    def inside(self, x: float, y: float) -> bool:
        return 0.0 <= x <= self.width and 0.0 <= y <= self.height

    # -- lines and lanes --------------------------------------------------------------------------------------
    @cached_property
    def lane_lines(self) -> tuple[LaneLine, ...]:
        """Every painted line, at d = k·lane width for k = −n..n, over each road's whole length."""
        lines = []
        for r, road in enumerate(self.roads):
            for k in range(-road.lanes, road.lanes + 1):
                d = k * road.lane_width
                kind = LineKind.CENTRE if k == 0 else LineKind.EDGE if abs(k) == road.lanes else LineKind.INNER
                (x1, y1), (x2, y2) = road.to_map(0.0, d), road.to_map(road.length, d)
                lines.append(LaneLine(r, x1, y1, x2, y2, kind, d))
        return tuple(lines)

    @cached_property
    def lane_centres(self) -> tuple[LaneCentre, ...]:
        """Every lane's centre line, oriented in its direction of travel (for perception and the scripted driver)."""
        centres = []
        for r, road in enumerate(self.roads):
            for sign in (1, -1):
                for k in range(road.lanes):
                    d = road.lane_offset(sign, k)
                    a, b = road.to_map(0.0, d), road.to_map(road.length, d)
                    if sign < 0:
                        a, b = b, a
                    centres.append(LaneCentre(r, sign, k, a[0], a[1], b[0], b[1]))
        return tuple(centres)

    @cached_property
    def walkway_lines(self) -> np.ndarray:
        """(4, 4) segments [x1, y1, x2, y2]: each road's walkway lines, at ±(lanes + walkway) from its centre."""
        rows = []
        for road in self.roads:
            for side in (1, -1):
                d = side * (road.half_width + self.config.walkway_width)
                rows.append([*road.to_map(0.0, d), *road.to_map(road.length, d)])
        return np.asarray(rows, dtype=float)

    @cached_property
    def walkway_segments(self) -> tuple[WalkwaySegment, ...]:
        """Walkway stretches between each map edge and the other road's carriageway (8 in all)."""
        m = self.config
        segments = []
        for r, road in enumerate(self.roads):
            other = self.roads[1 - r]
            # Where the other road's carriageway crosses this road, in this road's s.
            cs, _ = road.to_road(*self.crossing)
            for side in (1, -1):
                for s_min, s_max in ((0.0, cs - other.half_width), (cs + other.half_width, road.length)):
                    segments.append(WalkwaySegment(r, side, s_min, s_max, road.half_width,
                                                   road.half_width + m.walkway_width))
        return tuple(segments)

    # -- spawn spots ------------------------------------------------------------------------------------------
    @cached_property
    def spawn_spots(self) -> tuple[SpawnSpot, ...]:
        """``spawns_per_lane`` spots per incoming lane at each road end, heading into the map (30 by default)."""
        m = self.config
        spots = []
        for r, road in enumerate(self.roads):
            for end in (-1, 1):
                sign = -end               # entering at the start (end = −1) drives start→end
                yaw = road.heading if sign > 0 else math.remainder(road.heading + math.pi, math.tau)
                for k in range(road.lanes):
                    d = road.lane_offset(sign, k)
                    for j in range(m.spawns_per_lane):
                        along = m.spawn_first + j * m.spawn_spacing
                        s = along if sign > 0 else road.length - along
                        x, y = road.to_map(s, d)
                        spots.append(SpawnSpot(x, y, yaw, r, self.end_index(r, end), k))
        return tuple(spots)


def point_in_box(x: float, y: float, cx: float, cy: float, half_x: float, half_y: float) -> bool:
    return abs(x - cx) <= half_x and abs(y - cy) <= half_y


__all__ = ["LanePosition", "LineKind", "Road", "Building", "LaneLine", "LaneCentre", "SpawnSpot", "WalkwaySegment",
           "DrivingMap", "classify_on_road", "point_in_box"]
