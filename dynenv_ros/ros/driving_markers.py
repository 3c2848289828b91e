"""RViz / Foxglove pictures of the driving world as visualization_msgs/MarkerArray (the driving counterpart of
``ros/markers.py``, whose building blocks it uses). Everything is in the "map" frame (origin at the map's lower-left
corner, docs/driving.md); colours are those of ``render/driving.py``.

- ``map_markers``: ground, walkways, roads, lane lines and the four buildings (namespace "map").
- ``ground_truth_markers``: each car a box of its own colour (team outline colour as its heading arrow, dimmed when
  crashed, hidden once home), its destination as a ring of its colour, pedestrians (struck ones red and flat),
  obstacles, and a status text (namespace "ground_truth"; ids from object ids, so markers update in place).
- ``detection_markers``: one car's detections (DETECTION_DTYPE rows in its frame) — cars, pedestrians, obstacles
  as boxes / cylinders of their reported size, lanes as lines; false positives red with "FP", confusions ringed,
  misses as white rings; the SELF row is not a sighting and is skipped. Opens with a DELETEALL per namespace.
"""
from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from builtin_interfaces.msg import Time
from visualization_msgs.msg import Marker, MarkerArray

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.roads import DrivingMap, LineKind
from dynenv_ros.render.detections import ERROR, MISSED, camera_to_field
from dynenv_ros.render.driving import ASPHALT, BUILDING, CENTRE_LINE, EDGE_LINE, GROUND, INNER_LINE, WALKWAY, car_colour
from dynenv_ros.render.topdown import HEADING, OBSTACLE, PEDESTRIAN, TEAM_COLOURS
from dynenv_ros.ros.markers import (_circle_points, _classify_rows, _delete_all, _fp_label, _Ids, _marker, _mix,
                                    _quaternion, _rgba, _scale, _segment_points, detection_namespaces)
from dynenv_ros.sim.ground_truth import WorldSnapshot

MAP_NS = "map"
GROUND_TRUTH_NS = "ground_truth"
CAR_HEIGHT = 1.5               # m
PEDESTRIAN_HEIGHT = 1.7        # m
OBSTACLE_HEIGHT = 1.0          # m
BUILDING_HEIGHT = 12.0         # m
LINE_WIDTH = 0.15              # m: painted lane lines
DETECTION_ALPHA = 0.6
_SLOTS = 4
_BODY, _HEADING, _GOAL = 0, 1, 2
_TEXT_ID = -1

__all__ = ["map_markers", "ground_truth_markers", "detection_markers", "MAP_NS", "GROUND_TRUTH_NS"]


def map_markers(dmap: DrivingMap, stamp: Time) -> MarkerArray:
    """The static map: ground, walkways, roads (flat boxes), lane lines (LINE_LISTs) and buildings (boxes)."""
    markers = [_marker(MAP_NS, 0, Marker.CUBE, stamp, _rgba(GROUND), _scale(dmap.width, dmap.height, 0.02),
                       x=dmap.width / 2, y=dmap.height / 2, z=-0.03)]
    walkway = dmap.config.walkway_width
    for k, road in enumerate(dmap.roads):
        (x0, y0), (x1, y1) = road.start, road.end
        for slot, (extra, colour, z) in enumerate(((walkway, WALKWAY, -0.02), (0.0, ASPHALT, -0.01))):
            width = 2 * (road.half_width + extra)
            markers.append(_marker(MAP_NS, 1 + 2 * k + slot, Marker.CUBE, stamp, _rgba(colour),
                                   _scale(road.length, width, 0.01), x=(x0 + x1) / 2, y=(y0 + y1) / 2, z=z,
                                   orientation=_quaternion(road.heading)))
    for kind, colour in ((LineKind.EDGE, EDGE_LINE), (LineKind.CENTRE, CENTRE_LINE), (LineKind.INNER, INNER_LINE)):
        segments = [(ln.x1, ln.y1, ln.x2, ln.y2) for ln in dmap.lane_lines if ln.kind == kind]
        if segments:
            markers.append(_marker(MAP_NS, 10 + int(kind) + 1, Marker.LINE_LIST, stamp, _rgba(colour),
                                   _scale(LINE_WIDTH), points=_segment_points(segments, 0.005)))
    for k, b in enumerate(dmap.buildings):
        markers.append(_marker(MAP_NS, 20 + k, Marker.CUBE, stamp, _rgba(BUILDING),
                               _scale(2 * b.half_x, 2 * b.half_y, BUILDING_HEIGHT), x=b.x, y=b.y,
                               z=BUILDING_HEIGHT / 2))
    return MarkerArray(markers=markers)


def status_text(snapshot: WorldSnapshot) -> str:
    cars = snapshot.of_class(ObjectClass.CAR)
    home = sum(1 for c in cars if c.status & ObjectStatus.AT_GOAL)
    crashed = sum(1 for c in cars if c.status & ObjectStatus.CRASHED)
    hit = sum(1 for p in snapshot.of_class(ObjectClass.PEDESTRIAN) if p.status & ObjectStatus.CRASHED)
    return (f"{snapshot.game_time:.1f} s ({snapshot.time_remaining:.0f} s left)   cars {len(cars)}: {home} home, "
            f"{crashed} crashed   pedestrians hit {hit}")


def ground_truth_markers(snapshot: WorldSnapshot, dmap: DrivingMap, stamp: Time, *,
                         include_map: bool = False) -> MarkerArray:
    """Cars, their heading arrows and destinations, pedestrians, obstacles and a status text ("ground_truth")."""
    markers: list[Marker] = list(map_markers(dmap, stamp).markers) if include_map else []
    ns = GROUND_TRUTH_NS

    def mid(object_id: int, slot: int = _BODY) -> int:
        return int(object_id) * _SLOTS + slot

    for car in snapshot.of_class(ObjectClass.CAR):
        colour = car_colour(car.id)
        home = bool(car.status & ObjectStatus.AT_GOAL)
        crashed = bool(car.status & ObjectStatus.CRASHED)
        alpha = 0.0 if home else 1.0                   # home: left the map (a zero alpha hides it in RViz)
        fill = _mix(colour, ASPHALT) if crashed else colour
        markers.append(_marker(ns, mid(car.id), Marker.CUBE, stamp, _rgba(fill, alpha),
                               _scale(car.size_x, car.size_y, CAR_HEIGHT), x=car.x, y=car.y, z=CAR_HEIGHT / 2,
                               orientation=_quaternion(car.yaw)))
        markers.append(_marker(ns, mid(car.id, _HEADING), Marker.ARROW, stamp,
                               _rgba(TEAM_COLOURS.get(car.team, HEADING), alpha),
                               _scale(0.8 * car.size_x, 0.3, 0.3), x=car.x, y=car.y, z=CAR_HEIGHT + 0.1,
                               orientation=_quaternion(car.yaw)))
        goal_alpha = 0.0 if car.status & ObjectStatus.FINISHED or not math.isfinite(car.goal_x) else 1.0
        gx = car.goal_x if math.isfinite(car.goal_x) else 0.0
        gy = car.goal_y if math.isfinite(car.goal_y) else 0.0
        markers.append(_marker(ns, mid(car.id, _GOAL), Marker.LINE_STRIP, stamp, _rgba(colour, goal_alpha),
                               _scale(0.4), points=_circle_points(gx, gy, 2.0 + 0.6 * car.id, 0.05)))
    for p in snapshot.of_class(ObjectClass.PEDESTRIAN):
        d = p.size_x if p.size_x > 0 else 1.0
        if p.status & ObjectStatus.CRASHED:
            markers.append(_marker(ns, mid(p.id), Marker.CYLINDER, stamp, _rgba(ERROR), _scale(d, d, 0.1),
                                   x=p.x, y=p.y, z=0.05))
        else:
            markers.append(_marker(ns, mid(p.id), Marker.CYLINDER, stamp, _rgba(PEDESTRIAN),
                                   _scale(d, d, PEDESTRIAN_HEIGHT), x=p.x, y=p.y, z=PEDESTRIAN_HEIGHT / 2))
    for o in snapshot.of_class(ObjectClass.OBSTACLE):
        markers.append(_marker(ns, mid(o.id), Marker.CUBE, stamp, _rgba(OBSTACLE),
                               _scale(o.size_x, o.size_y, OBSTACLE_HEIGHT), x=o.x, y=o.y, z=OBSTACLE_HEIGHT / 2))
    markers.append(_marker(ns, _TEXT_ID, Marker.TEXT_VIEW_FACING, stamp, _rgba((240, 240, 240)), _scale(3.0),
                           x=dmap.width / 2, y=dmap.height + 4.0, z=2.0, text=status_text(snapshot)))
    return MarkerArray(markers=markers)


_DETECTION_COLOURS = {ObjectClass.CAR: (70, 170, 255), ObjectClass.PEDESTRIAN: PEDESTRIAN,
                      ObjectClass.OBSTACLE: OBSTACLE, ObjectClass.LANE: (0, 220, 220)}


def detection_markers(rows: np.ndarray, observer_pose: tuple[float, float, float], stamp: Time, *,
                      missed: Iterable[tuple[float, float]] = (), car_name: str = "car_0") -> MarkerArray:
    """One car's detections drawn in "map"; ``observer_pose`` = the car's (x, y, yaw) in the map frame."""
    ns_det, ns_fp, ns_conf, ns_missed = detection_namespaces(car_name)
    markers = _delete_all((ns_det, ns_fp, ns_conf, ns_missed), stamp)
    ids = _Ids()
    red = _rgba(ERROR)
    d = np.asarray(rows)
    if len(d):
        d = d[d["class_id"] != ObjectClass.SELF]
    if len(d):
        cls, fx, fy, false_positive, confused = _classify_rows(d, observer_pose)
        lanes = cls == ObjectClass.LANE
        if lanes.any():
            sx, sy = camera_to_field(observer_pose, d["line_start_x"][lanes], d["line_start_y"][lanes])
            ex, ey = camera_to_field(observer_pose, d["line_end_x"][lanes], d["line_end_y"][lanes])
            segments = np.column_stack([np.atleast_1d(v) for v in (sx, sy, ex, ey)])
            markers.append(_marker(ns_det, ids(ns_det), Marker.LINE_LIST, stamp,
                                   _rgba(_DETECTION_COLOURS[ObjectClass.LANE], DETECTION_ALPHA), _scale(0.2),
                                   points=_segment_points(segments, 0.05)))
        heading = float(observer_pose[2])
        for i in np.flatnonzero(~lanes):
            c, x, y = int(cls[i]), float(fx[i]), float(fy[i])
            fp = bool(false_positive[i])
            ns = ns_fp if fp else ns_det
            colour = red if fp else _rgba(_DETECTION_COLOURS.get(c, (150, 150, 150)), DETECTION_ALPHA)
            sx_, sy_ = float(d["size_x"][i]), float(d["size_y"][i])
            sx_ = sx_ if math.isfinite(sx_) and sx_ > 0 else 1.0
            sy_ = sy_ if math.isfinite(sy_) and sy_ > 0 else 1.0
            yaw = float(d["yaw"][i])
            if c == ObjectClass.PEDESTRIAN:
                height = PEDESTRIAN_HEIGHT
                markers.append(_marker(ns, ids(ns), Marker.CYLINDER, stamp, colour, _scale(sx_, sy_, height),
                                       x=x, y=y, z=height / 2))
            else:
                height = CAR_HEIGHT if c == ObjectClass.CAR else OBSTACLE_HEIGHT
                markers.append(_marker(ns, ids(ns), Marker.CUBE, stamp, colour, _scale(sx_, sy_, height),
                                       x=x, y=y, z=height / 2,
                                       orientation=_quaternion(heading + (yaw if math.isfinite(yaw) else 0.0))))
            if fp:
                markers.append(_fp_label(ns_fp, ids(ns_fp), stamp, x, y, height))
            if confused[i]:
                markers.append(_marker(ns_conf, ids(ns_conf), Marker.LINE_STRIP, stamp, red, _scale(0.15),
                                       points=_circle_points(x, y, max(sx_, sy_) / 2 + 0.5, 0.1)))
    for x, y in missed:
        markers.append(_marker(ns_missed, ids(ns_missed), Marker.LINE_STRIP, stamp, _rgba(MISSED), _scale(0.15),
                               points=_circle_points(float(x), float(y), 1.5, 0.1)))
    return MarkerArray(markers=markers)
