"""dynenv_msgs/DetectionArray ⇄ vision_msgs/Detection3DArray (docs/ros_graph.md, "Standard vision messages").

vision_msgs is what generic perception tools speak (RViz's vision_msgs plugin, trackers, nav2); the mapping keeps
everything the policy reads, so a robot whose vision stack publishes Detection3DArray can feed the policy node
through ``dynenv-vision-adapter --reverse``:

- one Detection3D per detection, frame ``<robot>/camera``; ``results[0].hypothesis.class_id`` is the class name
  with qualifiers joined by "/" (``ball``, ``robot/opponent/fallen``, ``line_crossing/T``...), its score the
  detection's confidence;
- ``results[0].pose``: position (z = 0) and, for robots, heading; the covariance is the error model's spread
  (perception/covariance.py): x, y from the position model, yaw from ``yaw_std`` (uniform on the circle where the
  class has no heading), z, roll and pitch 0 (on the ground plane);
- ``bbox``: centred on the detection, size (size_x, size_y, class height); a field line's box lies along it, its
  length in size.x, so its endpoints survive the trip.

Sighting bits are not carried (vision_msgs has no place for them); the reverse direction derives DISTANT and
PARTIAL from the geometry as the simulator does, and NEARBY from the other reported point objects (the simulator
also counts objects nobody reported, so NEARBY can differ).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from dynenv_msgs.msg import Detection, DetectionArray
from geometry_msgs.msg import Point
from vision_msgs.msg import Detection3D, Detection3DArray, ObjectHypothesisWithPose

from dynenv_ros.core.object_classes import ObjectClass, Sighting, Subtype, TeamRelation
from dynenv_ros.perception.covariance import UNIFORM_YAW_VARIANCE, position_covariance, yaw_variance
from dynenv_ros.perception.params import PerceptionParams

CLASS_NAMES = {c: c.name.lower() for c in (ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.GOALPOST,
                                           ObjectClass.PENALTY_CROSS, ObjectClass.LINE_CROSSING,
                                           ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE, ObjectClass.UNKNOWN)}
CLASSES_BY_NAME = {name: c for c, name in CLASS_NAMES.items()}
TEAM_NAMES = {TeamRelation.OWN: "own", TeamRelation.OPPONENT: "opponent"}
SUBTYPE_NAMES = {Subtype.CROSSING_L: "L", Subtype.CROSSING_T: "T", Subtype.CROSSING_X: "X"}
# Box heights (m): a NAO V6 stands 0.574 m, SPL goalposts are 0.8 m high; markings are flat.
HEIGHTS = {ObjectClass.ROBOT: 0.574, ObjectClass.GOALPOST: 0.8}
LINE_WIDTH = 0.05
POINT_CLASSES = (ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS,
                 ObjectClass.LINE_CROSSING, ObjectClass.UNKNOWN)


def class_label(d: Detection) -> str:
    parts = [CLASS_NAMES.get(ObjectClass(d.class_id), "unknown") if d.class_id in CLASS_NAMES else "unknown"]
    if d.class_id == ObjectClass.ROBOT:
        if d.team in TEAM_NAMES:
            parts.append(TEAM_NAMES[TeamRelation(d.team)])
        if d.fallen:
            parts.append("fallen")
        if d.penalized:
            parts.append("penalized")
    if d.subtype in SUBTYPE_NAMES:
        parts.append(SUBTYPE_NAMES[Subtype(d.subtype)])
    return "/".join(parts)


def parse_label(label: str) -> tuple[ObjectClass, int, int, bool, bool] | None:
    """(class, team, subtype, fallen, penalized) of a label, None if it is not of this vocabulary."""
    name, *qualifiers = label.split("/")
    if name not in CLASSES_BY_NAME:
        return None
    team = subtype = 0
    fallen = penalized = False
    for q in qualifiers:
        if q in ("own", "opponent"):
            team = int(TeamRelation.OWN if q == "own" else TeamRelation.OPPONENT)
        elif q == "fallen":
            fallen = True
        elif q == "penalized":
            penalized = True
        elif q in ("L", "T", "X"):
            subtype = int({"L": Subtype.CROSSING_L, "T": Subtype.CROSSING_T, "X": Subtype.CROSSING_X}[q])
        else:
            return None
    return CLASSES_BY_NAME[name], team, subtype, fallen, penalized


def _set_yaw(orientation, yaw: float) -> None:
    orientation.x = orientation.y = 0.0
    orientation.z, orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def _yaw(orientation) -> float:
    return 2.0 * math.atan2(orientation.z, orientation.w)


def to_vision_msgs(msg: DetectionArray, params: PerceptionParams) -> Detection3DArray:
    out = Detection3DArray(header=msg.header)
    dets = list(msg.detections)
    if not dets:
        return out
    x = np.array([d.position.x for d in dets])
    y = np.array([d.position.y for d in dets])
    near = np.array([params.classes[ObjectClass(d.class_id)].near_range if ObjectClass(d.class_id) in params.classes
                     else 1.0 for d in dets])
    cov = position_covariance(params, x, y, near, np.array([d.sighting for d in dets]))
    heading_variance = yaw_variance(params)
    for k, d in enumerate(dets):
        det = Detection3D(header=msg.header)
        hypothesis = ObjectHypothesisWithPose()
        hypothesis.hypothesis.class_id = class_label(d)
        hypothesis.hypothesis.score = float(d.confidence)
        pose = hypothesis.pose.pose
        covariance = np.zeros((6, 6))
        covariance[:2, :2] = cov[k]
        if d.class_id == ObjectClass.FIELD_LINE:
            sx, sy, ex, ey = d.line_start.x, d.line_start.y, d.line_end.x, d.line_end.y
            pose.position = Point(x=(sx + ex) / 2, y=(sy + ey) / 2, z=0.0)
            along = math.atan2(ey - sy, ex - sx)
            _set_yaw(pose.orientation, along)
            det.bbox.size.x, det.bbox.size.y = math.hypot(ex - sx, ey - sy), LINE_WIDTH
            covariance[5, 5] = UNIFORM_YAW_VARIANCE
        else:
            pose.position = Point(x=d.position.x, y=d.position.y, z=0.0)
            has_heading = d.class_id == ObjectClass.ROBOT and math.isfinite(d.yaw)
            _set_yaw(pose.orientation, float(d.yaw) if has_heading else 0.0)
            det.bbox.size.x, det.bbox.size.y = float(d.size_x), float(d.size_y)
            covariance[5, 5] = heading_variance if has_heading else UNIFORM_YAW_VARIANCE
        det.bbox.size.z = HEIGHTS.get(d.class_id, float(d.size_x) if d.class_id == ObjectClass.BALL else 0.0)
        det.bbox.center = pose
        hypothesis.pose.covariance = covariance.ravel().tolist()
        det.results = [hypothesis]
        out.detections.append(det)
    return out


def sighting_bits(dets: Sequence[Detection], params: PerceptionParams) -> np.ndarray:
    """DISTANT / PARTIAL / NEARBY of reported detections, from their geometry as the simulator defines them
    (perception/model.py): a point object is DISTANT beyond its class's near range and PARTIAL within its
    visibility radius of a view edge; a line is DISTANT when its far end is beyond the near range and PARTIAL when
    an end lies on a view edge or at the range limit (it was clipped); the circle is PARTIAL when its disc crosses
    a view edge; NEARBY marks point objects with another reported one within ``nearby_distance``."""
    n = len(dets)
    bits = np.zeros(n, np.uint8)
    if n == 0:
        return bits
    half = params.field_of_view / 2
    x = np.array([d.position.x for d in dets])
    y = np.array([d.position.y for d in dets])
    for k, det in enumerate(dets):
        cls = ObjectClass(det.class_id) if det.class_id in ObjectClass._value2member_map_ else None
        if cls is None or cls not in params.classes:
            continue
        p = params.classes[cls]
        if cls == ObjectClass.FIELD_LINE:
            ends = ((det.line_start.x, det.line_start.y), (det.line_end.x, det.line_end.y))
            distances = [math.hypot(ex, ey) for ex, ey in ends]
            if max(distances) > p.near_range:
                bits[k] |= int(Sighting.DISTANT)
            on_edge = any(abs(abs(math.atan2(ey, ex)) - half) < 1e-3 for ex, ey in ends)
            if on_edge or max(distances) > p.max_range - 1e-3:
                bits[k] |= int(Sighting.PARTIAL)
            continue
        d = math.hypot(x[k], y[k])
        if d > p.near_range:
            bits[k] |= int(Sighting.DISTANT)
        radius = det.size_x / 2 if cls == ObjectClass.CENTER_CIRCLE else p.visibility_radius
        reach = math.asin(min(1.0, radius / max(d, 1e-9)))
        if abs(math.atan2(y[k], x[k])) > half - reach:
            bits[k] |= int(Sighting.PARTIAL)
    points = np.array([d.class_id in POINT_CLASSES for d in dets])
    gap = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    np.fill_diagonal(gap, np.inf)
    close = (gap < params.miss.nearby_distance) & points[None, :]
    bits[points & close.any(axis=1)] |= int(Sighting.NEARBY)
    return bits


def from_vision_msgs(msg: Detection3DArray, params: PerceptionParams, *, robot_id: int, episode_id: int,
                     motion_period: int, frame_index: int, frames_per_period: int) -> tuple[DetectionArray, list[str]]:
    """The DetectionArray the policy node reads, and the labels that are not of this vocabulary (dropped)."""
    out = DetectionArray(header=msg.header, robot_id=robot_id, episode_id=episode_id, motion_period=motion_period,
                         frame_index=frame_index, frames_per_period=frames_per_period)
    dropped: list[str] = []
    for det in msg.detections:
        if not det.results:
            dropped.append("<no hypothesis>")
            continue
        best = max(det.results, key=lambda h: h.hypothesis.score)
        parsed = parse_label(best.hypothesis.class_id)
        pose = best.pose.pose
        values = (pose.position.x, pose.position.y, det.bbox.size.x, det.bbox.size.y, best.hypothesis.score)
        if parsed is None or not all(math.isfinite(v) for v in values):
            dropped.append(best.hypothesis.class_id if parsed is None else f"{best.hypothesis.class_id} (not finite)")
            continue
        cls, team, subtype, fallen, penalized = parsed
        d = Detection(class_id=int(cls), team=team, subtype=subtype, fallen=fallen, penalized=penalized,
                      confidence=float(min(1.0, max(0.0, best.hypothesis.score))))
        if cls == ObjectClass.FIELD_LINE:
            half, along = det.bbox.size.x / 2, _yaw(pose.orientation)
            cx, cy = pose.position.x, pose.position.y
            a = (cx - half * math.cos(along), cy - half * math.sin(along))
            b = (cx + half * math.cos(along), cy + half * math.sin(along))
            if math.hypot(*b) < math.hypot(*a) - 1e-6 or (abs(math.hypot(*b) - math.hypot(*a)) <= 1e-6 and b[1] < a[1]):
                a, b = b, a          # the simulator's rule: nearer end first (perception/model.py)
            d.line_start, d.line_end = Point(x=a[0], y=a[1]), Point(x=b[0], y=b[1])
            # As the simulator reports a line: at its point closest to the observer, along start → end.
            vx, vy = b[0] - a[0], b[1] - a[1]
            length2 = vx * vx + vy * vy
            t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, -(a[0] * vx + a[1] * vy) / length2))
            d.position = Point(x=a[0] + t * vx, y=a[1] + t * vy)
            d.yaw = (math.atan2(vy, vx) + math.pi / 2) % math.pi - math.pi / 2     # a line has no arrow (as simulated)
            d.size_x, d.size_y = math.sqrt(length2), float(det.bbox.size.y)
        else:
            d.position = Point(x=pose.position.x, y=pose.position.y)
            d.yaw = _yaw(pose.orientation) if cls == ObjectClass.ROBOT else float("nan")
            d.size_x, d.size_y = float(det.bbox.size.x), float(det.bbox.size.y)
        out.detections.append(d)
    if out.detections:
        for d, b in zip(out.detections, sighting_bits(out.detections, params)):
            d.sighting = int(b)
    return out, dropped
