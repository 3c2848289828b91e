"""Object classes, team relations and sighting flags shared by the simulator core, the agent and the messages.

The values are the constants of ``msg_defs/msg/Detection.msg``; the core cannot import the generated messages
(it must run without ROS), so test/test_object_classes.py checks that both stay equal.
"""
from __future__ import annotations

from enum import IntEnum, IntFlag


class ObjectClass(IntEnum):
    UNKNOWN = 0
    BALL = 1
    ROBOT = 2
    GOALPOST = 3
    PENALTY_CROSS = 4
    LINE_CROSSING = 5
    FIELD_LINE = 6
    CENTER_CIRCLE = 7
    CAR = 20
    PEDESTRIAN = 21
    OBSTACLE = 22
    LANE = 23
    SELF = 24


SOCCER_CLASSES = (ObjectClass.BALL, ObjectClass.ROBOT, ObjectClass.GOALPOST, ObjectClass.PENALTY_CROSS,
                  ObjectClass.LINE_CROSSING, ObjectClass.FIELD_LINE, ObjectClass.CENTER_CIRCLE)
DRIVING_CLASSES = (ObjectClass.CAR, ObjectClass.PEDESTRIAN, ObjectClass.OBSTACLE, ObjectClass.LANE,
                   ObjectClass.SELF)


class TeamRelation(IntEnum):
    UNKNOWN = 0
    OWN = 1
    OPPONENT = -1


class Subtype(IntEnum):
    NONE = 0
    CROSSING_L = 1
    CROSSING_T = 2
    CROSSING_X = 3
    LANE_SAME_DIRECTION = 10
    LANE_OPPOSING = 11
    LANE_EDGE = 12


class Sighting(IntFlag):
    NORMAL = 0
    DISTANT = 1
    PARTIAL = 2
    NEARBY = 4


class ObjectStatus(IntFlag):
    """Ground-truth status bits of ObjectState.msg."""
    NONE = 0
    FALLEN = 1
    PENALIZED = 2
    KICKING = 4
    FINISHED = 8
    CRASHED = 16
    AT_GOAL = 32
