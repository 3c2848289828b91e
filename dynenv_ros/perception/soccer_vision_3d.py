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
