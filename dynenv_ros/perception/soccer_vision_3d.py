"""A robot's emulated detections as the ros-sports ``soccer_vision_3d_msgs`` describe them (ROS-free records).

Team stacks and ros-sports tools speak ``soccer_vision_3d_msgs``; these records carry exactly what those messages
can carry, so the ROS side (``ros/ros_sports_conversion.py``) only copies numbers. What the mapping does and what
does not map is in docs/interfaces.md, "soccer_vision_3d_msgs".

Frame: the observer's ``<robot>/base_link`` (REP 103/105, on the ground between the feet, as a ``base_footprint``:
x forward along the body, y left, z up, metres). The detections come in the camera frame, which is the body frame
turned by the head's yaw (``sim/frames.py``), so every position and heading is turned by ``head_yaw``. Heights come
from the objects' real sizes: the ball's centre lies a radius above the ground, a robot's and a goalpost's box
stand on it.

What the emulated pipeline gets wrong stays wrong here, as a real detector's output would: noisy positions and
headings, a confused class (a robot reported as a goalpost is a ``Goalpost``), false positives, missed objects,
and the detector's confidence.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dynenv_ros.core.object_classes import ObjectClass, Subtype, TeamRelation

# Heights (m): a NAO V6 stands 0.574 m, SPL goalposts are 0.8 m high.
ROBOT_HEIGHT = 0.574
GOALPOST_HEIGHT = 0.8
# soccer_vision_attribute_msgs/Robot and Goalpost constants (the message's values, kept equal by the tests).
TEAM_UNKNOWN, TEAM_OWN, TEAM_OPPONENT = 0, 1, 2
STATE_UNKNOWN, STATE_STANDING, STATE_FALLEN, STATE_KICKING, STATE_INACTIVE = 0, 1, 2, 3, 4
FACING_UNKNOWN, FACING_THIS_WAY, FACING_AWAY, FACING_LEFT, FACING_RIGHT = 0, 1, 2, 3, 4
SIDE_UNKNOWN = 0
# Rays of a line crossing by its shape: an L joins 2 lines' ends, a T has 3 rays, an X 4; 0 = shape unknown.
CROSSING_RAYS = {int(Subtype.CROSSING_L): 2, int(Subtype.CROSSING_T): 3, int(Subtype.CROSSING_X): 4}
_TEAMS = {int(TeamRelation.OWN): TEAM_OWN, int(TeamRelation.OPPONENT): TEAM_OPPONENT,
          int(TeamRelation.UNKNOWN): TEAM_UNKNOWN}


@dataclass(frozen=True)
class Box:
    """``vision_msgs/BoundingBox3D``: centre (m), heading about z (rad; 0 where the class has none), size (m)."""
    x: float
    y: float
    z: float
    yaw: float
    size_x: float
    size_y: float
    size_z: float


@dataclass(frozen=True)
class Ball:
    x: float
    y: float
    z: float
    confidence: float


@dataclass(frozen=True)
class Robot:
    bb: Box
    team: int             # TEAM_*
    state: int            # STATE_*
    facing: int           # FACING_*
    confidence: float
    player_number: int = 0   # NUMBER_UNKNOWN: the emulation reads no jersey numbers


@dataclass(frozen=True)
class Goalpost:
    bb: Box
    confidence: float
    side: int = SIDE_UNKNOWN   # SPL goals look alike: the detector knows neither side nor team
    team: int = TEAM_UNKNOWN


@dataclass(frozen=True)
class Segment:
    start: tuple[float, float]
    end: tuple[float, float]
    confidence: float


@dataclass(frozen=True)
class Intersection:
    x: float
    y: float
    num_rays: int
    confidence: float


@dataclass(frozen=True)
class Ellipse:
    x: float
    y: float
    diameter: float
    confidence: float


@dataclass(frozen=True)
class SoccerVision3D:
    """One frame's detections by message: ``BallArray``, ``RobotArray``, ``GoalpostArray``, ``MarkingArray``."""
    balls: list[Ball] = field(default_factory=list)
    robots: list[Robot] = field(default_factory=list)
    goalposts: list[Goalpost] = field(default_factory=list)
    segments: list[Segment] = field(default_factory=list)
    intersections: list[Intersection] = field(default_factory=list)
    ellipses: list[Ellipse] = field(default_factory=list)
    unmapped: int = 0          # detections of a class no message has (UNKNOWN, driving classes)


def wrapped(angle: float) -> float:
    """An angle in [−π, π)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def facing(x: float, y: float, heading: float) -> int:
    """Which way a robot at (x, y) with ``heading`` faces as the observer sees it: toward the observer
    (``THIS_WAY``) or away within 45°, else to the observer's left or right (any frame: all in the same one)."""
    if not math.isfinite(heading):
        return FACING_UNKNOWN
    relative = wrapped(heading - math.atan2(y, x))   # 0: looking along the line of sight, away from the observer
    if abs(relative) <= math.pi / 4:
        return FACING_AWAY
    if abs(relative) >= 3 * math.pi / 4:
        return FACING_THIS_WAY
    return FACING_LEFT if relative > 0 else FACING_RIGHT


def robot_state(fallen: bool, penalized: bool) -> int:
    """A detected robot's state: a penalized one stands inactive at the sideline, a fallen one lies."""
    if penalized:
        return STATE_INACTIVE
    return STATE_FALLEN if fallen else STATE_STANDING


def _confidence(value: float, class_id: int) -> float:
    if not (math.isfinite(value) and 0.0 <= value <= 1.0):
        raise ValueError(f"a detection's confidence must be in [0, 1], got {value} (class {class_id})")
    return float(value)


def soccer_vision_3d(rows: np.ndarray, head_yaw: float) -> SoccerVision3D:
    """The records of one robot's detections (``perception.detections.DETECTION_DTYPE`` rows, camera frame) in its
    body frame; ``head_yaw``: the head's yaw relative to the body (rad, + left)."""
    if not math.isfinite(head_yaw):
        raise ValueError(f"head_yaw must be finite, got {head_yaw}")
    c, s = math.cos(head_yaw), math.sin(head_yaw)

    def body(x: float, y: float) -> tuple[float, float]:
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"a detection's position must be finite, got ({x}, {y})")
        return c * x - s * y, s * x + c * y

    out = SoccerVision3D()
    unmapped = 0
    for r in rows.tolist():
        (class_id, x, y, yaw, sx, sy, conf, team, subtype, fallen, penalized, lsx, lsy, lex, ley, _sighting,
         _true_id, _true_class) = r
        confidence = _confidence(conf, class_id)
        bx, by = body(x, y)
        if class_id == ObjectClass.BALL:
            out.balls.append(Ball(bx, by, sx / 2, confidence))
        elif class_id == ObjectClass.ROBOT:
            heading = wrapped(yaw + head_yaw) if math.isfinite(yaw) else float("nan")
            box = Box(bx, by, ROBOT_HEIGHT / 2, heading if math.isfinite(heading) else 0.0, sx, sy, ROBOT_HEIGHT)
            if team not in _TEAMS:
                raise ValueError(f"a robot detection's team must be 1, -1 or 0, got {team}")
            out.robots.append(Robot(box, _TEAMS[team], robot_state(fallen, penalized), facing(bx, by, heading),
                                    confidence))
        elif class_id == ObjectClass.GOALPOST:
            out.goalposts.append(Goalpost(Box(bx, by, GOALPOST_HEIGHT / 2, 0.0, sx, sy, GOALPOST_HEIGHT),
                                          confidence))
        elif class_id == ObjectClass.FIELD_LINE:
            out.segments.append(Segment(body(lsx, lsy), body(lex, ley), confidence))
        elif class_id == ObjectClass.LINE_CROSSING:
            out.intersections.append(Intersection(bx, by, CROSSING_RAYS.get(subtype, 0), confidence))
        elif class_id in (ObjectClass.CENTER_CIRCLE, ObjectClass.PENALTY_CROSS):
            # No penalty-mark type exists: a spot marking of the mark's size, told from the circle by its diameter.
            out.ellipses.append(Ellipse(bx, by, sx, confidence))
        else:
            unmapped += 1
    return SoccerVision3D(out.balls, out.robots, out.goalposts, out.segments, out.intersections, out.ellipses,
                          unmapped)


# -- back: a team's soccer_vision_3d messages → the detections the policy reads (issue 41, the policy node's input) --
# The messages are read by attribute (rclpy or rosbags), so this runs without ROS.
KINDS = ("balls", "robots", "goalposts", "markings")   # the messages that make up a frame
IGNORED_KINDS = ("field_boundary", "obstacles")        # read and ignored: the emulation detects neither
MAX_PER_MESSAGE = 256     # items of one array (or of each of a MarkingArray's three): the policy's per-stream bound
CONFIDENCE_UNKNOWN = -1.0  # soccer_vision_attribute_msgs/Confidence: the detector gives none
BALL_DIAMETER = 0.1        # SPL ball (m): the size of a ball reported with its centre on the ground (z ≤ 0)
CROSSING_SIZE = 0.1        # the emulation's size of a line crossing, which the message has no field for
LINE_WIDTH = 0.05          # a field line's width, the same
# A marking ellipse this wide or wider is the centre circle (1.5 m), else a penalty mark (0.1 m).
CIRCLE_MIN_DIAMETER = 0.75
SUBTYPES_BY_RAYS = {rays: subtype for subtype, rays in CROSSING_RAYS.items()}
_RELATIONS = {TEAM_OWN: int(TeamRelation.OWN), TEAM_OPPONENT: int(TeamRelation.OPPONENT),
              TEAM_UNKNOWN: int(TeamRelation.UNKNOWN)}


class MessageRefused(ValueError):
    """A soccer_vision_3d message the policy cannot read; ``reason`` is one word (``not_finite``, ``confidence``,
    ``enum``, ``too_many``)."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason


def _items(kind: str, msg: Any) -> dict[str, list[Any]]:
    if kind == "balls":
        return {"balls": list(msg.balls)}
    if kind == "robots":
        return {"robots": list(msg.robots)}
    if kind == "goalposts":
        return {"posts": list(msg.posts)}
    return {"segments": list(msg.segments), "intersections": list(msg.intersections),
            "ellipses": list(msg.ellipses)}


def _check_finite(what: str, *values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise MessageRefused("not_finite", f"{what} has a value that is not finite: {values}")


def _check_confidence(what: str, item: Any) -> float:
    value = float(item.confidence.confidence)
    if value == CONFIDENCE_UNKNOWN:
        return 1.0       # a detector that rates nothing is taken at its word
    if not (math.isfinite(value) and 0.0 <= value <= 1.0):
        raise MessageRefused("confidence", f"{what} has confidence {value}, outside 0 … 1 (or -1: unknown)")
    return value


def _check_enum(what: str, value: int, allowed: range) -> int:
    if int(value) not in allowed:
        raise MessageRefused("enum", f"{what} is {value}, not one of {allowed.start} … {allowed.stop - 1}")
    return int(value)


def _yaw_of(q: Any) -> float:
    x, y, z, w = (float(getattr(q, a)) for a in "xyzw")
    _check_finite("an orientation", x, y, z, w)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _is_identity(q: Any) -> bool:
    return (float(q.x), float(q.y), float(q.z), abs(float(q.w))) == (0.0, 0.0, 0.0, 1.0)


def detection_rows(kind: str, msg: Any) -> np.ndarray:
    """One message's detections as ``DETECTION_DTYPE`` rows, still in the body frame (``camera_rows`` turns them
    into the camera frame once the head's yaw at the frame's stamp is known): the inverse of ``soccer_vision_3d``.
    ``MessageRefused`` with the reason for a message that cannot be read (docs/deploy.md, "Bad input"). Sighting
    bits are left 0 (the caller derives them from the geometry)."""
    from dynenv_ros.perception.detections import empty
    if kind not in KINDS:
        raise ValueError(f"no soccer_vision_3d kind '{kind}'")
    items = _items(kind, msg)
    for name, values in items.items():
        if len(values) > MAX_PER_MESSAGE:
            raise MessageRefused("too_many", f"{len(values)} {name} in one message, at most {MAX_PER_MESSAGE}")

    def camera(x: float, y: float) -> tuple[float, float]:
        return x, y

    rows = empty(sum(len(v) for v in items.values()))
    k = 0
    for name, values in items.items():
        for item in values:
            r = rows[k]
            k += 1
            r["confidence"] = _check_confidence(name, item)
            if name == "balls":
                p = item.center
                _check_finite("a ball", p.x, p.y, p.z)
                r["class_id"], (r["x"], r["y"]) = ObjectClass.BALL, camera(p.x, p.y)
                r["size_x"] = r["size_y"] = 2 * p.z if p.z > 0 else BALL_DIAMETER
            elif name in ("robots", "posts"):
                bb = item.bb
                p, size = bb.center.position, bb.size
                _check_finite(f"a {name[:-1]}'s box", p.x, p.y, p.z, size.x, size.y, size.z)
                yaw = _yaw_of(bb.center.orientation)
                r["x"], r["y"] = camera(p.x, p.y)
                r["size_x"], r["size_y"] = abs(size.x), abs(size.y)
                a = item.attributes
                if name == "robots":
                    facing_value = _check_enum("a robot's facing", a.facing, range(0, 5))
                    state = _check_enum("a robot's state", a.state, range(0, 5))
                    team = _check_enum("a robot's team", a.team, range(0, 3))
                    r["class_id"], r["team"] = ObjectClass.ROBOT, _RELATIONS[team]
                    unknown = facing_value == FACING_UNKNOWN and _is_identity(bb.center.orientation)
                    r["yaw"] = float("nan") if unknown else wrapped(yaw)
                    r["fallen"], r["penalized"] = state == STATE_FALLEN, state == STATE_INACTIVE
                else:
                    _check_enum("a goalpost's side", a.side, range(0, 3))
                    _check_enum("a goalpost's team", a.team, range(0, 3))
                    r["class_id"] = ObjectClass.GOALPOST
            elif name == "segments":
                a0, b0 = item.start, item.end
                _check_finite("a line segment", a0.x, a0.y, b0.x, b0.y)
                _line(r, camera(a0.x, a0.y), camera(b0.x, b0.y))
            elif name == "intersections":
                p = item.center
                _check_finite("a line crossing", p.x, p.y)
                if int(item.num_rays) < 0:
                    raise MessageRefused("enum", f"a line crossing has {item.num_rays} rays")
                r["class_id"], (r["x"], r["y"]) = ObjectClass.LINE_CROSSING, camera(p.x, p.y)
                r["subtype"] = SUBTYPES_BY_RAYS.get(int(item.num_rays), int(Subtype.NONE))
                r["size_x"] = r["size_y"] = CROSSING_SIZE
            else:
                p = item.center.position
                _check_finite("a marking ellipse", p.x, p.y, item.diameter)
                if item.diameter <= 0:
                    raise MessageRefused("not_finite", f"a marking ellipse has diameter {item.diameter}")
                circle = item.diameter >= CIRCLE_MIN_DIAMETER
                r["class_id"] = ObjectClass.CENTER_CIRCLE if circle else ObjectClass.PENALTY_CROSS
                r["x"], r["y"] = camera(p.x, p.y)
                r["size_x"] = r["size_y"] = item.diameter
            r["true_id"] = -2
    return rows


def _line(r: np.void, a: tuple[float, float], b: tuple[float, float]) -> None:
    """A field line as the emulation reports one (perception/soccer_kernels.py): nearer end first (ties: the right
    end), at the segment's point closest to the camera, its direction modulo π, its length and width."""
    gap = math.hypot(*b) - math.hypot(*a)
    if gap < -1e-6 or (abs(gap) <= 1e-6 and b[1] < a[1]):
        a, b = b, a
    ex, ey = b[0] - a[0], b[1] - a[1]
    length2 = ex * ex + ey * ey
    t = 0.0 if length2 == 0.0 else min(1.0, max(0.0, -(a[0] * ex + a[1] * ey) / length2))
    r["class_id"] = ObjectClass.FIELD_LINE
    r["line_start_x"], r["line_start_y"], r["line_end_x"], r["line_end_y"] = a[0], a[1], b[0], b[1]
    r["x"], r["y"] = a[0] + t * ex, a[1] + t * ey
    r["yaw"] = (math.atan2(ey, ex) + math.pi / 2) % math.pi - math.pi / 2
    r["size_x"], r["size_y"] = math.sqrt(length2), LINE_WIDTH


def camera_rows(rows: np.ndarray, head_yaw: float) -> np.ndarray:
    """Body-frame rows (``detection_rows``) in the camera frame, the body frame turned by ``head_yaw`` (rad, + left):
    positions, line ends and robots' headings turned back by it, a line's direction kept modulo π; the end order
    and the closest point of a line do not change under a turn (distances from the robot stay)."""
    if not math.isfinite(head_yaw):
        raise ValueError(f"head_yaw must be finite, got {head_yaw}")
    out = rows.copy()
    c, s = math.cos(head_yaw), math.sin(head_yaw)
    for x, y in (("x", "y"), ("line_start_x", "line_start_y"), ("line_end_x", "line_end_y")):
        bx, by = rows[x].astype(np.float64), rows[y].astype(np.float64)
        out[x], out[y] = c * bx + s * by, -s * bx + c * by
    robots = rows["class_id"] == ObjectClass.ROBOT
    lines = rows["class_id"] == ObjectClass.FIELD_LINE
    yaw = rows["yaw"].astype(np.float64) - head_yaw
    out["yaw"] = np.where(robots, (yaw + math.pi) % (2 * math.pi) - math.pi,
                          np.where(lines, (yaw + math.pi / 2) % math.pi - math.pi / 2, rows["yaw"]))
    return out
