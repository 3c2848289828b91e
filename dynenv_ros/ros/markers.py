"""RViz / Foxglove pictures of the simulator as visualization_msgs/MarkerArray, built from the core records.

Pure functions: they take plain records (``FieldGeometry``, ``WorldSnapshot``, DETECTION_DTYPE rows) and a stamp
and return messages; the simulator node publishes them (topics.GROUND_TRUTH_MARKERS, topics.DETECTION_MARKERS).
Everything is in the "map" frame (the field frame), detections included: they are moved out of the camera frame
here with the observer's pose, so a viewer needs no TF tree.

Colours are those of the top-down renderer (``render.topdown``, ``render.detections``) so a PNG and an RViz view
read the same way: team A blue, team B red, ball orange; detections of goalposts yellow, marks magenta, lines cyan;
errors red (false positives in their own namespace with an "FP" label, confusions ringed), misses as white rings.

Marker ids: ground truth ids are derived from object ids, so markers update in place from one call to the next.
Detection markers change count every frame, so ``detection_markers`` starts its array with one DELETEALL per
namespace of the observing robot (Jazzy's RViz deletes only that namespace) and numbers the rest from 0.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.render.detections import (DEFAULT_MARKER_SIZE, ERROR, GOALPOST, LINE_DETECTION, MARK, MARKER_SIZE,
                                          MISSED, MISSED_RADIUS, OTHER, camera_to_field, missed_positions)
from dynenv_ros.render.detections import classify_rows as _classify_rows   # shared with the Foxglove live view
from dynenv_ros.render.topdown import (BALL, CARPET, DEFAULT_ROBOT_RADIUS, FALLEN_OUTLINE, HEAD, HEADING, LINE,
                                       TEAM_COLOURS, Colour, score_text)
from dynenv_ros.ros.conversions import WORLD_FRAME
from dynenv_ros.sim.frames import yaw_quaternion
from dynenv_ros.sim.ground_truth import WorldSnapshot
from dynenv_ros.soccer.field import FieldGeometry

__all__ = ["FIELD_NS", "GROUND_TRUTH_NS", "DETECTION_NAMESPACES", "GOALPOST_HEIGHT", "ROBOT_HEIGHT",
           "field_markers", "ground_truth_markers", "detection_markers", "detection_namespaces", "missed_positions",
           "observer_team_of"]

FIELD_NS = "field"
GROUND_TRUTH_NS = "ground_truth"
# Suffixes of one robot's detection namespaces: "<robot_name>/<suffix>".
DETECTION_NAMESPACES = ("detections", "false_positives", "confusions", "missed")

GOALPOST_HEIGHT = 0.8          # m
ROBOT_HEIGHT = 0.5             # m: a standing robot's cylinder (NAO is 0.57 m; the head arrow sits on top)
BALL_DIAMETER = 0.1            # m: used when a snapshot carries no ball size
CARPET_THICKNESS = 0.02        # m: the carpet's top face lies just below z = 0
LINE_Z = 0.002                 # m: painted lines float a hair above the carpet so they never z-fight it
CIRCLE_SEGMENTS = 48
TEXT_HEIGHT = 0.3              # m: score / phase line
DETECTION_LINE_WIDTH = 0.025   # m: thin, detected lines pile up on the painted ones
DETECTION_ROBOT_HEIGHT = 0.3   # m: wider and lower than the ground-truth cylinder, so both stay visible
DETECTION_FLAT_HEIGHT = 0.02   # m: marks and line crossings are flat discs
DETECTION_ALPHA = 0.8
PENALIZED_ALPHA = 0.35
_MIN_SCALE = 1e-3              # RViz refuses zero scales

# Ground-truth id layout: object id * _SLOTS + slot, so each object's markers keep their ids across calls.
_SLOTS = 4
_BODY, _HEADING, _HEAD = 0, 1, 2
_TEXT_ID = -1                  # negative: never collides with an object's ids


# --------------------------------------------------------------------------------------------------- building blocks

def _rgba(colour: Colour, alpha: float = 1.0) -> ColorRGBA:
    r, g, b = colour
    return ColorRGBA(r=r / 255.0, g=g / 255.0, b=b / 255.0, a=float(alpha))


def _mix(a: Colour, b: Colour, t: float = 0.5) -> Colour:
    return tuple(round((1 - t) * x + t * y) for x, y in zip(a, b))  # type: ignore[return-value]


def _quaternion(yaw: float = 0.0, pitch: float = 0.0) -> Quaternion:
    """Rotation yaw about z, then pitch about the new y axis (ZYX order, no roll)."""
    x, y, z, w = yaw_quaternion(yaw, pitch)
    return Quaternion(x=x, y=y, z=z, w=w)


def _scale(x: float, y: float | None = None, z: float | None = None) -> Vector3:
    y = x if y is None else y
    z = x if z is None else z
    return Vector3(x=max(_MIN_SCALE, float(x)), y=max(_MIN_SCALE, float(y)), z=max(_MIN_SCALE, float(z)))


def _marker(ns: str, marker_id: int, marker_type: int, stamp: Time, colour: ColorRGBA, scale: Vector3, *,
            x: float = 0.0, y: float = 0.0, z: float = 0.0, orientation: Quaternion | None = None,
            points: Sequence[Point] = (), text: str = "") -> Marker:
    m = Marker(ns=ns, id=int(marker_id), type=marker_type, action=Marker.ADD, scale=scale, color=colour,
               frame_locked=False, text=text)
    m.header.stamp = stamp
    m.header.frame_id = WORLD_FRAME
    m.pose = Pose(position=Point(x=float(x), y=float(y), z=float(z)),
                  orientation=orientation if orientation is not None else Quaternion(w=1.0))
    m.points = list(points)
    return m


def _circle_points(cx: float, cy: float, radius: float, z: float, segments: int = CIRCLE_SEGMENTS) -> list[Point]:
    """Closed polyline (first point repeated last) for a LINE_STRIP."""
    angles = np.linspace(0.0, 2 * math.pi, segments + 1)
    return [Point(x=float(cx + radius * math.cos(a)), y=float(cy + radius * math.sin(a)), z=z) for a in angles]


def _segment_points(segments: Iterable[Sequence[float]], z: float) -> list[Point]:
    """[x1, y1, x2, y2] rows to the point pairs of a LINE_LIST."""
    out: list[Point] = []
    for x1, y1, x2, y2 in segments:
        out += [Point(x=float(x1), y=float(y1), z=z), Point(x=float(x2), y=float(y2), z=z)]
    return out


# ------------------------------------------------------------------------------------------------------------ field

def field_markers(geometry: FieldGeometry, stamp: Time) -> MarkerArray:
    """The static field in namespace "field": carpet, lines, centre circle, penalty marks, goalposts.

    Ids: 0 carpet (CUBE), 1 lines (LINE_LIST), 2 centre circle (LINE_STRIP), 3 penalty marks and centre spot
    (LINE_LIST crosses), 10 + k goalpost k in ``geometry.goalposts`` order (CYLINDER).
    """
    g = geometry
    white = _rgba(LINE)
    line = _scale(g.line_width)
    markers = [
        _marker(FIELD_NS, 0, Marker.CUBE, stamp, _rgba(CARPET),
                _scale(g.length + 2 * g.border, g.width + 2 * g.border, CARPET_THICKNESS),
                z=-CARPET_THICKNESS / 2 - 0.001),
        _marker(FIELD_NS, 1, Marker.LINE_LIST, stamp, white, line, points=_segment_points(g.lines, LINE_Z)),
        _marker(FIELD_NS, 2, Marker.LINE_STRIP, stamp, white, line,
                points=_circle_points(0.0, 0.0, g.center_circle_radius, LINE_Z)),
    ]
    half = g.penalty_mark_size / 2
    crosses = [row for x, y in g.penalty_marks for row in ((x - half, y, x + half, y), (x, y - half, x, y + half))]
    markers.append(_marker(FIELD_NS, 3, Marker.LINE_LIST, stamp, white, line, points=_segment_points(crosses, LINE_Z)))
    for k, (x, y) in enumerate(g.goalposts):
        markers.append(_marker(FIELD_NS, 10 + k, Marker.CYLINDER, stamp, white,
                               _scale(2 * g.goalpost_radius, 2 * g.goalpost_radius, GOALPOST_HEIGHT),
                               x=x, y=y, z=GOALPOST_HEIGHT / 2))
    return MarkerArray(markers=markers)


# ----------------------------------------------------------------------------------------------------- ground truth

def ground_truth_marker_id(object_id: int, slot: int = _BODY) -> int:
    """Id of one of an object's ground-truth markers (slot 0 body, 1 heading arrow, 2 head arrow)."""
    return int(object_id) * _SLOTS + slot


def ground_truth_markers(snapshot: WorldSnapshot, geometry: FieldGeometry, stamp: Time, *,
                         include_field: bool = False) -> MarkerArray:
    """Robots, their heading and head arrows, the ball and a score / phase text, in namespace "ground_truth".

    Robots are CYLINDERs in their team colour (A blue, B red); a fallen robot lies on its side along its heading,
    tinted grey; a penalized one is translucent. A thick dark ARROW shows the body heading at ground level, a thin
    yellow one the head direction (yaw + head_yaw) on top of the robot. The ball is an orange SPHERE. Ids come
    from object ids (``ground_truth_marker_id``; the text is id -1), so repeated calls update the same markers.
    ``include_field`` prepends ``field_markers`` (namespace "field") for a one-topic picture.
    """
    markers: list[Marker] = list(field_markers(geometry, stamp).markers) if include_field else []
    ns = GROUND_TRUTH_NS
    for robot in snapshot.of_class(ObjectClass.ROBOT):
        radius = robot.size_x / 2 if robot.size_x > 0 else DEFAULT_ROBOT_RADIUS
        colour = TEAM_COLOURS.get(robot.team, TEAM_COLOURS[0])
        alpha = PENALIZED_ALPHA if robot.status & ObjectStatus.PENALIZED else 1.0
        fallen = bool(robot.status & ObjectStatus.FALLEN)
        if fallen:   # lying along its heading: the cylinder's axis (z) pitched onto the body x axis
            body = _marker(ns, ground_truth_marker_id(robot.id, _BODY), Marker.CYLINDER, stamp,
                           _rgba(_mix(colour, FALLEN_OUTLINE), alpha), _scale(2 * radius, 2 * radius, ROBOT_HEIGHT),
                           x=robot.x, y=robot.y, z=radius, orientation=_quaternion(robot.yaw, math.pi / 2))
            top = 2 * radius
        else:
            body = _marker(ns, ground_truth_marker_id(robot.id, _BODY), Marker.CYLINDER, stamp,
                           _rgba(colour, alpha), _scale(2 * radius, 2 * radius, ROBOT_HEIGHT),
                           x=robot.x, y=robot.y, z=ROBOT_HEIGHT / 2, orientation=_quaternion(robot.yaw))
            top = ROBOT_HEIGHT
        markers.append(body)
        markers.append(_marker(ns, ground_truth_marker_id(robot.id, _HEADING), Marker.ARROW, stamp,
                               _rgba(HEADING, alpha), _scale(3.5 * radius, 0.05, 0.09),
                               x=robot.x, y=robot.y, z=0.05, orientation=_quaternion(robot.yaw)))
        markers.append(_marker(ns, ground_truth_marker_id(robot.id, _HEAD), Marker.ARROW, stamp,
                               _rgba(HEAD, alpha), _scale(4.5 * radius, 0.02, 0.05),
                               x=robot.x, y=robot.y, z=top + 0.03,
                               orientation=_quaternion(robot.yaw + robot.head_yaw)))
    for ball in snapshot.of_class(ObjectClass.BALL):
        diameter = ball.size_x if ball.size_x > 0 else BALL_DIAMETER
        markers.append(_marker(ns, ground_truth_marker_id(ball.id, _BODY), Marker.SPHERE, stamp, _rgba(BALL),
                               _scale(diameter), x=ball.x, y=ball.y, z=diameter / 2))
    markers.append(_marker(ns, _TEXT_ID, Marker.TEXT_VIEW_FACING, stamp, _rgba((240, 240, 240)),
                           _scale(TEXT_HEIGHT), x=0.0, y=geometry.half_width + geometry.border + 0.3, z=1.0,
                           text=score_text(snapshot)))
    return MarkerArray(markers=markers)


# ------------------------------------------------------------------------------------------------------- detections

def detection_namespaces(robot_name: str) -> tuple[str, ...]:
    """"<robot_name>/detections", "…/false_positives", "…/confusions", "…/missed"."""
    return tuple(f"{robot_name}/{suffix}" for suffix in DETECTION_NAMESPACES)


def observer_team_of(robot_name: str) -> int:
    """+1 for "team_a_*" (and anything else), -1 for "team_b_*": the robocup env's agent names."""
    return -1 if robot_name.startswith("team_b") else 1


def _detection_colour(class_id: int, team: int, observer_team: int) -> Colour:
    if class_id == ObjectClass.ROBOT:
        return TEAM_COLOURS.get(int(team) * observer_team, TEAM_COLOURS[0])
    return {ObjectClass.BALL: BALL, ObjectClass.GOALPOST: GOALPOST, ObjectClass.PENALTY_CROSS: MARK,
            ObjectClass.LINE_CROSSING: MARK, ObjectClass.FIELD_LINE: LINE_DETECTION,
            ObjectClass.CENTER_CIRCLE: LINE_DETECTION}.get(int(class_id), OTHER)


class _Ids:
    """Sequential ids per namespace (detection markers are rebuilt from scratch every frame)."""

    def __init__(self) -> None:
        self._next: dict[str, int] = {}

    def __call__(self, ns: str) -> int:
        value = self._next.get(ns, 0)
        self._next[ns] = value + 1
        return value


def _delete_all(namespaces: Iterable[str], stamp: Time) -> list[Marker]:
    """One DELETEALL per namespace in "map": detection arrays change size every frame, so each opens with these
    to wipe the last frame's markers (shared by the soccer and driving detection markers)."""
    markers: list[Marker] = []
    for ns in namespaces:
        clear = Marker(ns=ns, id=0, action=Marker.DELETEALL, scale=_scale(1.0), color=_rgba(MISSED, 0.0))
        clear.header.stamp = stamp
        clear.header.frame_id = WORLD_FRAME
        clear.pose.orientation = Quaternion(w=1.0)
        markers.append(clear)
    return markers


def detection_markers(rows: np.ndarray, observer_pose: tuple[float, float, float], stamp: Time, *,
                      missed: Iterable[tuple[float, float]] = (), robot_name: str = "team_a_0",
                      observer_team: int | None = None, center_circle_radius: float = 0.75) -> MarkerArray:
    """One robot's detections (DETECTION_DTYPE rows, its camera frame) drawn in the "map" frame.

    ``observer_pose`` = (x, y, camera heading = body yaw + head yaw) in the field frame. ``missed``: field
    positions of objects that were visible but not detected (``missed_positions`` computes them). The array opens
    with a DELETEALL for each of this robot's namespaces (``detection_namespaces``), so last frame's markers vanish.

    - ``<robot>/detections``: ball orange SPHERE, robot CYLINDER coloured by the team relation (own team = the
      observer's colour; ``observer_team`` defaults to ``observer_team_of(robot_name)``) with an ARROW for a known
      yaw, goalpost yellow CYLINDER, penalty cross / line crossing magenta flat CYLINDER, field lines one cyan
      LINE_LIST, centre circle a cyan LINE_STRIP (radius size_x / 2, else ``center_circle_radius``).
    - ``<robot>/false_positives``: detections with true_id -1, same shapes in red, each with a red "FP" TEXT.
    - ``<robot>/confusions``: a red ring around each detection whose reported class differs from its real one.
    - ``<robot>/missed``: a hollow white ring at each ``missed`` position.
    """
    if observer_team is None:
        observer_team = observer_team_of(robot_name)
    if observer_team not in (1, -1):
        raise ValueError(f"observer_team must be +1 or -1, got {observer_team!r}")
    ns_det, ns_fp, ns_conf, ns_missed = detection_namespaces(robot_name)
    markers = _delete_all((ns_det, ns_fp, ns_conf, ns_missed), stamp)
    ids = _Ids()
    red = _rgba(ERROR)

    d = np.asarray(rows)
    if len(d):
        cls, fx, fy, false_positive, confused = _classify_rows(d, observer_pose)
        lines = cls == ObjectClass.FIELD_LINE
        for fp in (False, True):
            chosen = lines & (false_positive == fp)
            if not chosen.any():
                continue
            sx, sy = camera_to_field(observer_pose, d["line_start_x"][chosen], d["line_start_y"][chosen])
            ex, ey = camera_to_field(observer_pose, d["line_end_x"][chosen], d["line_end_y"][chosen])
            segments = np.column_stack([np.atleast_1d(v) for v in (sx, sy, ex, ey)])
            ns = ns_fp if fp else ns_det
            markers.append(_marker(ns, ids(ns), Marker.LINE_LIST, stamp,
                                   red if fp else _rgba(LINE_DETECTION, DETECTION_ALPHA),
                                   _scale(DETECTION_LINE_WIDTH), points=_segment_points(segments, 2 * LINE_Z)))
            if fp:
                for x1, y1, x2, y2 in segments:
                    markers.append(_fp_label(ns_fp, ids(ns_fp), stamp, (x1 + x2) / 2, (y1 + y2) / 2, 0.1))
        heading = float(observer_pose[2])
        for i in np.flatnonzero(~lines):
            c, x, y = int(cls[i]), float(fx[i]), float(fy[i])
            fp = bool(false_positive[i])
            ns = ns_fp if fp else ns_det
            colour = red if fp else _rgba(_detection_colour(c, d["team"][i], observer_team), DETECTION_ALPHA)
            shape, top, radius = _detection_shape(ns, ids(ns), stamp, colour, d[i], c, x, y, heading,
                                                  center_circle_radius)
            markers.append(shape)
            yaw = float(d["yaw"][i])
            if c == ObjectClass.ROBOT and math.isfinite(yaw):   # the robot's facing, camera → field frame
                markers.append(_marker(ns, ids(ns), Marker.ARROW, stamp, _rgba(HEADING, DETECTION_ALPHA),
                                       _scale(2.2 * radius, 0.04, 0.07), x=x, y=y, z=top + 0.02,
                                       orientation=_quaternion(heading + yaw)))
            if fp:
                markers.append(_fp_label(ns_fp, ids(ns_fp), stamp, x, y, top))
            if confused[i]:
                markers.append(_marker(ns_conf, ids(ns_conf), Marker.LINE_STRIP, stamp, red, _scale(0.03),
                                       points=_circle_points(x, y, radius + 0.05, 0.03)))
    for x, y in missed:
        markers.append(_marker(ns_missed, ids(ns_missed), Marker.LINE_STRIP, stamp, _rgba(MISSED), _scale(0.03),
                               points=_circle_points(float(x), float(y), MISSED_RADIUS, 0.03)))
    return MarkerArray(markers=markers)


def _detection_shape(ns: str, marker_id: int, stamp: Time, colour: ColorRGBA, row: np.void, class_id: int,
                     x: float, y: float, heading: float,
                     center_circle_radius: float) -> tuple[Marker, float, float]:
    """The marker of one point-like detection, its top height and its footprint radius (for rings and arrows)."""
    radius = MARKER_SIZE.get(class_id, DEFAULT_MARKER_SIZE)
    if class_id == ObjectClass.BALL:
        return _marker(ns, marker_id, Marker.SPHERE, stamp, colour, _scale(2 * radius), x=x, y=y, z=radius), \
            2 * radius, radius
    if class_id == ObjectClass.ROBOT:
        height = DETECTION_ROBOT_HEIGHT / (3 if row["fallen"] else 1)
        return _marker(ns, marker_id, Marker.CYLINDER, stamp, colour, _scale(2 * radius, 2 * radius, height),
                       x=x, y=y, z=height / 2), height, radius
    if class_id == ObjectClass.GOALPOST:
        return _marker(ns, marker_id, Marker.CYLINDER, stamp, colour,
                       _scale(2 * radius, 2 * radius, GOALPOST_HEIGHT), x=x, y=y, z=GOALPOST_HEIGHT / 2), \
            GOALPOST_HEIGHT, radius
    if class_id in (ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING):
        return _marker(ns, marker_id, Marker.CYLINDER, stamp, colour,
                       _scale(2 * radius, 2 * radius, DETECTION_FLAT_HEIGHT), x=x, y=y,
                       z=DETECTION_FLAT_HEIGHT / 2), DETECTION_FLAT_HEIGHT, radius
    if class_id == ObjectClass.CENTER_CIRCLE:
        size = float(row["size_x"])
        r = size / 2 if math.isfinite(size) and size > 0 else center_circle_radius
        return _marker(ns, marker_id, Marker.LINE_STRIP, stamp, colour, _scale(DETECTION_LINE_WIDTH),
                       points=_circle_points(x, y, r, 2 * LINE_Z)), 2 * LINE_Z, r
    # A class this view has no shape for (driving classes): a grey cube of its reported size.
    sx, sy = float(row["size_x"]), float(row["size_y"])
    sx = sx if math.isfinite(sx) and sx > 0 else 2 * radius
    sy = sy if math.isfinite(sy) and sy > 0 else 2 * radius
    yaw = float(row["yaw"])
    return _marker(ns, marker_id, Marker.CUBE, stamp, colour, _scale(sx, sy, 0.2), x=x, y=y, z=0.1,
                   orientation=_quaternion(heading + (yaw if math.isfinite(yaw) else 0.0))), 0.2, max(sx, sy) / 2


def _fp_label(ns: str, marker_id: int, stamp: Time, x: float, y: float, top: float) -> Marker:
    return _marker(ns, marker_id, Marker.TEXT_VIEW_FACING, stamp, _rgba(ERROR), _scale(0.2), x=x, y=y,
                   z=top + 0.2, text="FP")
