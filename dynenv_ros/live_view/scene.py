"""The simulator's state as Foxglove's well-known messages, so the Foxglove app's 3D panel draws it with no plugin.

Pure functions from the core records (``FieldGeometry`` or ``DrivingMap``, ``WorldSnapshot``, DETECTION_DTYPE rows,
``sim.frames`` transforms) to ``foxglove.messages`` (``SceneUpdate``, ``FrameTransforms``) and a JSON game state.
They draw what the RViz markers (``ros/markers.py``, ``ros/driving_markers.py``) draw, with the renderer's colours
(``render/``): team A blue, team B red, ball orange; detections yellow (goalposts), magenta (marks), cyan (lines);
false positives red with "FP", confusions ringed red, misses as white rings.

Everything is in the ``map`` frame in metres (REP 103, z up): detections are moved out of the camera frame with the
observer's true pose, so the picture needs no TF. Each ``SceneUpdate`` first deletes every entity of its topic and
then adds the current ones: objects that left (a car home, a detection no longer made) vanish with the next frame.
Entity ids: the field ``field`` (driving ``map``); robots and cars by name; the ball ``ball``; other bodies
``object_<id>``; the score ``score``; one robot's detections ``<robot>/detections``.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from foxglove.messages import (ArrowPrimitive, Color, CubePrimitive, CylinderPrimitive, FrameTransform,
                               FrameTransforms, KeyValuePair, LinePrimitive, LinePrimitiveLineType, Point3, Pose,
                               Quaternion, SceneEntity, SceneEntityDeletion, SceneEntityDeletionType, SceneUpdate,
                               SpherePrimitive, TextPrimitive, Timestamp, Vector3)

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.driving.roads import DrivingMap, LineKind
from dynenv_ros.render.detections import (DEFAULT_MARKER_SIZE, ERROR, LINE_CLASSES, MARKER_SIZE, MISSED,
                                          MISSED_RADIUS, camera_to_field, class_colour, classify_rows)
from dynenv_ros.render.driving import (ASPHALT, BUILDING, CENTRE_LINE, EDGE_LINE, GROUND, INNER_LINE, WALKWAY,
                                       car_colour)
from dynenv_ros.render.topdown import (BALL, CARPET, DEFAULT_ROBOT_RADIUS, FALLEN_OUTLINE, HEAD, HEADING, LINE,
                                       OBSTACLE, PEDESTRIAN, TEAM_COLOURS, Colour, phase_name, score_text)
from dynenv_ros.sim.frames import WORLD_FRAME, PlanarTransform, yaw_quaternion
from dynenv_ros.sim.ground_truth import BodyState, WorldSnapshot
from dynenv_ros.soccer.field import FieldGeometry

# Heights of the 3D shapes, m (the ground truth's; detections are lower and wider so both stay visible).
ROBOT_HEIGHT = 0.5
GOALPOST_HEIGHT = 0.8
BALL_DIAMETER = 0.1
CAR_HEIGHT = 1.5
PEDESTRIAN_HEIGHT = 1.7
OBSTACLE_HEIGHT = 1.0
BUILDING_HEIGHT = 12.0
DETECTION_HEIGHT = 0.3
LINE_Z = 0.002                # painted lines a hair above the ground, detected ones above them
DETECTION_ALPHA = 0.8
PENALIZED_ALPHA = 0.35
CIRCLE_SEGMENTS = 48
TEXT = (240, 240, 240)

GAME_STATE_SCHEMA: dict[str, Any] = {
    "title": "dynenv.GameState", "type": "object",
    "description": "The game at one vision frame (the score line of the 3D view, as numbers). Soccer fills the "
                   "score and phase; driving the car and pedestrian counts.",
    "properties": {
        "scenario": {"type": "string"}, "episode": {"type": "integer"}, "motion_period": {"type": "integer"},
        "sim_time_s": {"type": "number"}, "game_time_s": {"type": "number"},
        "time_remaining_s": {"type": "number"}, "text": {"type": "string"},
        "score_a": {"type": "integer"}, "score_b": {"type": "integer"}, "phase": {"type": "string"},
        "cars": {"type": "integer"}, "cars_home": {"type": "integer"}, "cars_crashed": {"type": "integer"},
        "pedestrians_hit": {"type": "integer"}},
    "required": ["scenario", "episode", "motion_period", "sim_time_s", "game_time_s", "time_remaining_s", "text"]}


# ---------------------------------------------------------------------------------------------------- building blocks

def timestamp(stamp_ns: int) -> Timestamp:
    return Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)


def _color(colour: Colour, alpha: float = 1.0) -> Color:
    r, g, b = colour
    return Color(r=r / 255.0, g=g / 255.0, b=b / 255.0, a=float(alpha))


def _mix(a: Colour, b: Colour) -> Colour:
    return tuple(round((x + y) / 2) for x, y in zip(a, b))  # type: ignore[return-value]


def _pose(x: float, y: float, z: float = 0.0, yaw: float = 0.0, pitch: float = 0.0) -> Pose:
    qx, qy, qz, qw = yaw_quaternion(float(yaw), pitch)
    return Pose(position=Vector3(x=float(x), y=float(y), z=float(z)), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))


def _cylinder(x: float, y: float, diameter: float, height: float, colour: Color, *, z: float | None = None,
              yaw: float = 0.0, pitch: float = 0.0) -> CylinderPrimitive:
    return CylinderPrimitive(pose=_pose(x, y, height / 2 if z is None else z, yaw, pitch),
                             size=Vector3(x=diameter, y=diameter, z=height), bottom_scale=1.0, top_scale=1.0,
                             color=colour)


def _cube(x: float, y: float, z: float, sx: float, sy: float, sz: float, colour: Color,
          yaw: float = 0.0) -> CubePrimitive:
    return CubePrimitive(pose=_pose(x, y, z, yaw), size=Vector3(x=sx, y=sy, z=sz), color=colour)


def _arrow(x: float, y: float, z: float, yaw: float, length: float, diameter: float, colour: Color) -> ArrowPrimitive:
    return ArrowPrimitive(pose=_pose(x, y, z, yaw), shaft_length=0.7 * length, shaft_diameter=diameter,
                          head_length=0.3 * length, head_diameter=2.0 * diameter, color=colour)


def _segments(rows: Iterable[Sequence[float]], z: float, thickness: float, colour: Color) -> LinePrimitive:
    """[x1, y1, x2, y2] rows as one LINE_LIST."""
    points = [Point3(x=float(x), y=float(y), z=z) for x1, y1, x2, y2 in rows for x, y in ((x1, y1), (x2, y2))]
    return LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=thickness, points=points, color=colour,
                         pose=_pose(0.0, 0.0))


def _ring(x: float, y: float, radius: float, z: float, thickness: float, colour: Color) -> LinePrimitive:
    angles = np.linspace(0.0, 2 * math.pi, CIRCLE_SEGMENTS, endpoint=False)
    points = [Point3(x=float(x + radius * math.cos(a)), y=float(y + radius * math.sin(a)), z=z) for a in angles]
    return LinePrimitive(type=LinePrimitiveLineType.LineLoop, thickness=thickness, points=points, color=colour,
                         pose=_pose(0.0, 0.0))


def _text(x: float, y: float, z: float, text: str, size: float, colour: Colour = TEXT) -> TextPrimitive:
    return TextPrimitive(pose=_pose(x, y, z), billboard=True, font_size=size, scale_invariant=False,
                         color=_color(colour), text=text)


def _update(entities: list[SceneEntity], stamp_ns: int) -> SceneUpdate:
    """Replace the topic's picture: delete every entity older than this frame, then add this frame's."""
    return SceneUpdate(deletions=[SceneEntityDeletion(timestamp=timestamp(stamp_ns),
                                                      type=SceneEntityDeletionType.All)],
                       entities=entities)


def _entity(entity_id: str, stamp_ns: int, metadata: dict[str, str] | None = None, **primitives: Any) -> SceneEntity:
    return SceneEntity(timestamp=timestamp(stamp_ns), frame_id=WORLD_FRAME, id=entity_id,
                       metadata=[KeyValuePair(key=k, value=v) for k, v in (metadata or {}).items()], **primitives)


# ------------------------------------------------------------------------------------------------------ the ground

def static_scene(geometry: FieldGeometry | DrivingMap, stamp_ns: int = 0) -> SceneUpdate:
    """What does not move: the soccer field, or the driving map."""
    if isinstance(geometry, DrivingMap):
        return _update([_map_entity(geometry, stamp_ns)], stamp_ns)
    return _update([_field_entity(geometry, stamp_ns)], stamp_ns)


def _field_entity(g: FieldGeometry, stamp_ns: int) -> SceneEntity:
    """Carpet, lines, centre circle, penalty marks and centre spot, goalposts."""
    white = _color(LINE)
    half = g.penalty_mark_size / 2
    crosses = [row for x, y in g.penalty_marks for row in ((x - half, y, x + half, y), (x, y - half, x, y + half))]
    return _entity("field", stamp_ns, {"length_m": f"{g.length:g}", "width_m": f"{g.width:g}"},
                   cubes=[_cube(0.0, 0.0, -0.011, g.length + 2 * g.border, g.width + 2 * g.border, 0.02,
                                _color(CARPET))],
                   lines=[_segments(g.lines, LINE_Z, g.line_width, white),
                          _ring(0.0, 0.0, g.center_circle_radius, LINE_Z, g.line_width, white),
                          _segments(crosses, LINE_Z, g.line_width, white)],
                   cylinders=[_cylinder(x, y, 2 * g.goalpost_radius, GOALPOST_HEIGHT, white)
                              for x, y in g.goalposts])


def _map_entity(dmap: DrivingMap, stamp_ns: int) -> SceneEntity:
    """Ground, walkways and roads (flat boxes), lane lines and buildings, as ``ros/driving_markers.map_markers``."""
    cubes = [_cube(dmap.width / 2, dmap.height / 2, -0.03, dmap.width, dmap.height, 0.02, _color(GROUND))]
    walkway = dmap.config.walkway_width
    for road in dmap.roads:
        (x0, y0), (x1, y1) = road.start, road.end
        for extra, colour, z in ((walkway, WALKWAY, -0.02), (0.0, ASPHALT, -0.01)):
            cubes.append(_cube((x0 + x1) / 2, (y0 + y1) / 2, z, road.length, 2 * (road.half_width + extra), 0.01,
                               _color(colour), road.heading))
    cubes += [_cube(b.x, b.y, BUILDING_HEIGHT / 2, 2 * b.half_x, 2 * b.half_y, BUILDING_HEIGHT, _color(BUILDING))
              for b in dmap.buildings]
    lines = []
    for kind, colour in ((LineKind.EDGE, EDGE_LINE), (LineKind.CENTRE, CENTRE_LINE), (LineKind.INNER, INNER_LINE)):
        rows = [(ln.x1, ln.y1, ln.x2, ln.y2) for ln in dmap.lane_lines if ln.kind == kind]
        if rows:
            lines.append(_segments(rows, 0.005, 0.15, _color(colour)))
    return _entity("map", stamp_ns, {"width_m": f"{dmap.width:g}", "height_m": f"{dmap.height:g}"},
                   cubes=cubes, lines=lines)


# ----------------------------------------------------------------------------------------------------- ground truth

def body_entity_id(body: BodyState, names: Sequence[str]) -> str:
    """Robots and cars by name (their object id is their index), the ball ``ball``, others ``object_<id>``."""
    if body.class_id in (ObjectClass.ROBOT, ObjectClass.CAR) and 0 <= body.id < len(names):
        return names[body.id]
    return "ball" if body.class_id == ObjectClass.BALL else f"object_{body.id}"


def ground_truth_scene(snapshot: WorldSnapshot, names: Sequence[str], stamp_ns: int, *,
                       text_position: tuple[float, float, float] = (0.0, 4.0, 1.0)) -> SceneUpdate:
    """Every body where it truly is, and the score line (soccer) or status line (driving) at ``text_position``."""
    entities = [_body_entity(body, names, stamp_ns) for body in snapshot.objects]
    text = game_state(snapshot)["text"]
    entities.append(_entity("score", stamp_ns, texts=[_text(*text_position, text, 0.3 if _soccer(snapshot)
                                                            else 3.0)]))
    return _update([e for e in entities if e is not None], stamp_ns)


def _soccer(snapshot: WorldSnapshot) -> bool:
    return not any(o.class_id == ObjectClass.CAR for o in snapshot.objects)


def _class_name(class_id: int) -> str:
    try:
        return ObjectClass(class_id).name
    except ValueError:      # a class this code base does not know yet: its number
        return str(int(class_id))


def _body_entity(body: BodyState, names: Sequence[str], stamp_ns: int) -> SceneEntity | None:
    entity_id = body_entity_id(body, names)
    meta = {"class": _class_name(body.class_id), "team": str(body.team), "status": str(int(body.status)),
            "x_m": f"{body.x:.3f}", "y_m": f"{body.y:.3f}", "yaw_rad": f"{body.yaw:.3f}"}
    fallen = bool(body.status & ObjectStatus.FALLEN)
    if body.class_id == ObjectClass.ROBOT:
        radius = body.size_x / 2 if body.size_x > 0 else DEFAULT_ROBOT_RADIUS
        colour = TEAM_COLOURS.get(body.team, TEAM_COLOURS[0])
        alpha = PENALIZED_ALPHA if body.status & ObjectStatus.PENALIZED else 1.0
        if fallen:      # lying along its heading: the cylinder's axis pitched onto the body's x axis
            greyed = _color(_mix(colour, FALLEN_OUTLINE), alpha)
            body_shape = _cylinder(body.x, body.y, 2 * radius, ROBOT_HEIGHT, greyed, z=radius, yaw=body.yaw,
                                   pitch=math.pi / 2)
            top = 2 * radius
        else:
            body_shape = _cylinder(body.x, body.y, 2 * radius, ROBOT_HEIGHT, _color(colour, alpha), yaw=body.yaw)
            top = ROBOT_HEIGHT
        return _entity(entity_id, stamp_ns, meta, cylinders=[body_shape], arrows=[
            _arrow(body.x, body.y, 0.05, body.yaw, 3.5 * radius, 0.05, _color(HEADING, alpha)),
            _arrow(body.x, body.y, top + 0.03, body.yaw + body.head_yaw, 4.5 * radius, 0.02, _color(HEAD, alpha))])
    if body.class_id == ObjectClass.BALL:
        d = body.size_x if body.size_x > 0 else BALL_DIAMETER
        return _entity(entity_id, stamp_ns, meta, spheres=[SpherePrimitive(
            pose=_pose(body.x, body.y, d / 2), size=Vector3(x=d, y=d, z=d), color=_color(BALL))])
    if body.class_id == ObjectClass.CAR:
        if body.status & ObjectStatus.AT_GOAL:          # home: it has left the map
            return None
        colour = car_colour(body.id)
        fill = _mix(colour, ASPHALT) if body.status & ObjectStatus.CRASHED else colour
        return _entity(entity_id, stamp_ns, meta,
                       cubes=[_cube(body.x, body.y, CAR_HEIGHT / 2, body.size_x, body.size_y, CAR_HEIGHT,
                                    _color(fill), body.yaw)],
                       arrows=[_arrow(body.x, body.y, CAR_HEIGHT + 0.1, body.yaw, 0.8 * body.size_x, 0.3,
                                      _color(TEAM_COLOURS.get(body.team, HEADING)))])
    if body.class_id == ObjectClass.PEDESTRIAN:
        d = body.size_x if body.size_x > 0 else 1.0
        hit = bool(body.status & ObjectStatus.CRASHED)
        return _entity(entity_id, stamp_ns, meta, cylinders=[
            _cylinder(body.x, body.y, d, 0.1 if hit else PEDESTRIAN_HEIGHT, _color(ERROR if hit else PEDESTRIAN))])
    if body.class_id == ObjectClass.OBSTACLE:
        return _entity(entity_id, stamp_ns, meta, cubes=[
            _cube(body.x, body.y, OBSTACLE_HEIGHT / 2, body.size_x, body.size_y, OBSTACLE_HEIGHT, _color(OBSTACLE),
                  body.yaw)])
    return None          # landmarks (goalposts, marks) are part of the static field


def game_state(snapshot: WorldSnapshot, *, episode: int | None = None, motion_period: int = 0,
               sim_time_s: float | None = None) -> dict[str, Any]:
    """The JSON game state (``GAME_STATE_SCHEMA``): soccer's score and phase, or driving's counts, and the clock."""
    state: dict[str, Any] = {
        "episode": int(snapshot.episode_id if episode is None else episode), "motion_period": int(motion_period),
        "sim_time_s": float(snapshot.tick * snapshot.tick_period if sim_time_s is None else sim_time_s),
        "game_time_s": float(snapshot.game_time), "time_remaining_s": float(snapshot.time_remaining)}
    if _soccer(snapshot):
        state.update(scenario="robocup", score_a=int(snapshot.score_team_a), score_b=int(snapshot.score_team_b),
                     phase=phase_name(snapshot.phase), text=score_text(snapshot))
        return state
    cars = snapshot.of_class(ObjectClass.CAR)
    home = sum(1 for c in cars if c.status & ObjectStatus.AT_GOAL)
    crashed = sum(1 for c in cars if c.status & ObjectStatus.CRASHED)
    hit = sum(1 for p in snapshot.of_class(ObjectClass.PEDESTRIAN) if p.status & ObjectStatus.CRASHED)
    state.update(scenario="driving", cars=len(cars), cars_home=home, cars_crashed=crashed, pedestrians_hit=hit,
                 text=f"{snapshot.game_time:.1f} s ({snapshot.time_remaining:.0f} s left)   cars {len(cars)}: "
                      f"{home} home, {crashed} crashed   pedestrians hit {hit}")
    return state


# ------------------------------------------------------------------------------------------------------- detections

def detection_scene(robot_name: str, rows: np.ndarray, observer_pose: tuple[float, float, float], stamp_ns: int, *,
                    missed: Iterable[tuple[float, float]] = (), observer_team: int = 1) -> SceneUpdate:
    """One agent's detections (DETECTION_DTYPE rows, its camera frame) in the map frame, as one entity
    ``<robot>/detections``. ``observer_pose`` = (x, y, camera heading = yaw + head yaw), the truth; ``missed``:
    map positions of objects in view but not detected. Lines and lanes are segments, point-like classes shapes of
    their class colour (team relation for robots and cars), false positives red with "FP", confusions ringed red,
    misses white rings; the SELF row (a car's own state) is not a sighting and is skipped."""
    red = _color(ERROR)
    primitives: dict[str, list] = {"spheres": [], "cylinders": [], "cubes": [], "lines": [], "texts": [],
                                   "arrows": []}
    d = np.asarray(rows)
    d = d[d["class_id"] != ObjectClass.SELF] if len(d) else d
    if len(d):
        cls, fx, fy, false_positive, confused = classify_rows(d, observer_pose)
        lines = np.isin(cls, [int(c) for c in LINE_CLASSES])
        for fp in (False, True):
            chosen = lines & (false_positive == fp)
            if chosen.any():
                sx, sy = camera_to_field(observer_pose, d["line_start_x"][chosen], d["line_start_y"][chosen])
                ex, ey = camera_to_field(observer_pose, d["line_end_x"][chosen], d["line_end_y"][chosen])
                rows_xy = np.column_stack([np.atleast_1d(v) for v in (sx, sy, ex, ey)])
                colour = red if fp else _color(class_colour(int(cls[chosen][0])), DETECTION_ALPHA)
                primitives["lines"].append(_segments(rows_xy.tolist(), 2 * LINE_Z, 0.025, colour))
        heading = float(observer_pose[2])
        for i in np.flatnonzero(~lines):
            c, x, y, fp = int(cls[i]), float(fx[i]), float(fy[i]), bool(false_positive[i])
            colour = red if fp else _color(class_colour(c, int(d["team"][i]), observer_team), DETECTION_ALPHA)
            top, radius = _detection_shape(primitives, d[i], c, x, y, heading, colour)
            yaw = float(d["yaw"][i])
            if c in (ObjectClass.ROBOT, ObjectClass.CAR) and math.isfinite(yaw):
                primitives["arrows"].append(_arrow(x, y, top + 0.02, heading + yaw, 2.2 * radius, 0.035,
                                                   _color(HEADING, DETECTION_ALPHA)))
            if fp:
                primitives["texts"].append(_text(x, y, top + 0.2, "FP", 0.2, ERROR))
            if confused[i]:
                primitives["lines"].append(_ring(x, y, radius + 0.05, 0.03, 0.03, red))
    for x, y in missed:
        primitives["lines"].append(_ring(float(x), float(y), MISSED_RADIUS, 0.03, 0.03, _color(MISSED)))
    meta = {"observer": robot_name, "detections": str(len(d)),
            "false_positives": str(int((d["true_id"] == -1).sum())) if len(d) else "0"}
    return _update([_entity(f"{robot_name}/detections", stamp_ns, meta, **primitives)], stamp_ns)


def _detection_shape(primitives: dict[str, list], row: np.void, class_id: int, x: float, y: float, heading: float,
                     colour: Color) -> tuple[float, float]:
    """Add the shape of one point-like detection; its top height and footprint radius (for rings and arrows)."""
    radius = MARKER_SIZE.get(class_id, DEFAULT_MARKER_SIZE)
    if class_id == ObjectClass.BALL:
        primitives["spheres"].append(SpherePrimitive(pose=_pose(x, y, radius),
                                                     size=Vector3(x=2 * radius, y=2 * radius, z=2 * radius),
                                                     color=colour))
        return 2 * radius, radius
    if class_id == ObjectClass.CENTER_CIRCLE:
        size = float(row["size_x"])
        r = size / 2 if math.isfinite(size) and size > 0 else 0.75
        primitives["lines"].append(_ring(x, y, r, 2 * LINE_Z, 0.025, colour))
        return 2 * LINE_Z, r
    if class_id in (ObjectClass.ROBOT, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING,
                    ObjectClass.PEDESTRIAN):
        height = {ObjectClass.ROBOT: DETECTION_HEIGHT / (3 if row["fallen"] else 1),
                  ObjectClass.GOALPOST: GOALPOST_HEIGHT, ObjectClass.PEDESTRIAN: PEDESTRIAN_HEIGHT}.get(class_id, 0.02)
        primitives["cylinders"].append(_cylinder(x, y, 2 * radius, height, colour))
        return height, radius
    # cars, obstacles and any class without a shape of its own: a box of its reported size
    sx, sy = float(row["size_x"]), float(row["size_y"])
    sx = sx if math.isfinite(sx) and sx > 0 else 2 * radius
    sy = sy if math.isfinite(sy) and sy > 0 else 2 * radius
    yaw = float(row["yaw"])
    height = CAR_HEIGHT if class_id == ObjectClass.CAR else OBSTACLE_HEIGHT if class_id == ObjectClass.OBSTACLE else 0.2
    primitives["cubes"].append(_cube(x, y, height / 2, sx, sy, height, colour,
                                     heading + (yaw if math.isfinite(yaw) else 0.0)))
    return height, max(sx, sy) / 2


# --------------------------------------------------------------------------------------------------------------- TF

def frame_transforms(transforms: Sequence[PlanarTransform], stamp_ns: int) -> FrameTransforms:
    """``sim.frames`` transforms (the tree ``/tf`` carries) as Foxglove's FrameTransforms."""
    stamp = timestamp(stamp_ns)
    out = []
    for t in transforms:
        qx, qy, qz, qw = yaw_quaternion(float(t.yaw))
        out.append(FrameTransform(timestamp=stamp, parent_frame_id=t.parent, child_frame_id=t.child,
                                  translation=Vector3(x=float(t.x), y=float(t.y), z=0.0),
                                  rotation=Quaternion(x=qx, y=qy, z=qz, w=qw)))
    return FrameTransforms(transforms=out)
