"""MarkerArray pictures for RViz / Foxglove: field, ground truth and one robot's detections, all in frame "map"."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from dynenv_ros.core.object_classes import ObjectClass, ObjectStatus
from dynenv_ros.perception.detections import empty
from dynenv_ros.render.topdown import TEAM_COLOURS
from dynenv_ros.ros.markers import (detection_markers, detection_namespaces, field_markers, ground_truth_marker_id,
                                    ground_truth_markers, missed_positions)
from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.field import FieldGeometry
from dynenv_ros.soccer.world import SoccerWorld

STAMP = Time(sec=12, nanosec=500_000_000)
GEOMETRY = FieldGeometry()


@pytest.fixture(scope="module")
def world() -> SoccerWorld:
    return SoccerWorld(SoccerConfig(players_per_team=2), seed=0)


@pytest.fixture(scope="module")
def snapshot(world):
    return world.snapshot()


def rgb(colour) -> tuple[int, int, int]:
    return round(colour.r * 255), round(colour.g * 255), round(colour.b * 255)


def of_ns(array: MarkerArray, ns: str) -> list[Marker]:
    return [m for m in array.markers if m.ns == ns and m.action == Marker.ADD]


def check_well_formed(array: MarkerArray) -> None:
    """What RViz needs: frame "map", positive scales, normalised orientations, no lifetime, not frame-locked."""
    seen = set()
    for m in array.markers:
        assert m.header.frame_id == "map"
        assert (m.header.stamp.sec, m.header.stamp.nanosec) == (12, 500_000_000)
        assert m.scale.x > 0 and m.scale.y > 0 and m.scale.z > 0, (m.ns, m.id, m.scale)
        q = m.pose.orientation
        assert math.isclose(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2, 1.0, rel_tol=1e-9)
        assert (m.lifetime.sec, m.lifetime.nanosec) == (0, 0) and not m.frame_locked
        assert 0.0 <= m.color.a <= 1.0
        for p in m.points:
            assert all(math.isfinite(v) for v in (p.x, p.y, p.z))
        if m.action == Marker.ADD:
            assert (m.ns, m.id) not in seen, f"duplicate marker {m.ns}/{m.id}"
            seen.add((m.ns, m.id))
            if m.type in (Marker.LINE_LIST,):
                assert len(m.points) > 0 and len(m.points) % 2 == 0
            if m.type == Marker.LINE_STRIP:
                assert len(m.points) >= 2
    back = deserialize_message(serialize_message(array), MarkerArray)
    assert len(back.markers) == len(array.markers)


# ------------------------------------------------------------------------------------------------------------ field

def test_field_markers():
    array = field_markers(GEOMETRY, STAMP)
    check_well_formed(array)
    assert {m.ns for m in array.markers} == {"field"}
    types = [m.type for m in array.markers]
    assert types.count(Marker.CYLINDER) == 4 and types.count(Marker.CUBE) == 1
    assert types.count(Marker.LINE_STRIP) == 1 and types.count(Marker.LINE_LIST) == 2
    lines = next(m for m in array.markers if m.id == 1)
    assert lines.type == Marker.LINE_LIST and len(lines.points) == 2 * len(GEOMETRY.lines)
    assert math.isclose(lines.scale.x, 0.05) and rgb(lines.color) == (255, 255, 255)
    circle = next(m for m in array.markers if m.type == Marker.LINE_STRIP)
    radii = [math.hypot(p.x, p.y) for p in circle.points]
    assert np.allclose(radii, GEOMETRY.center_circle_radius)
    assert (circle.points[0].x, circle.points[0].y) == pytest.approx((circle.points[-1].x, circle.points[-1].y))
    posts = sorted((m for m in array.markers if m.type == Marker.CYLINDER), key=lambda m: m.id)
    assert np.allclose([(m.pose.position.x, m.pose.position.y) for m in posts], GEOMETRY.goalposts)
    assert all(math.isclose(m.scale.z, 0.8) and math.isclose(m.pose.position.z, 0.4) for m in posts)
    carpet = next(m for m in array.markers if m.type == Marker.CUBE)
    assert carpet.scale.x == pytest.approx(GEOMETRY.length + 2 * GEOMETRY.border)
    assert carpet.pose.position.z + carpet.scale.z / 2 < 0.0      # below the lines


# ----------------------------------------------------------------------------------------------------- ground truth

def test_ground_truth_counts_positions_and_colours(snapshot):
    array = ground_truth_markers(snapshot, GEOMETRY, STAMP)
    check_well_formed(array)
    assert {m.ns for m in array.markers} == {"ground_truth"}
    robots = snapshot.of_class(ObjectClass.ROBOT)
    assert len(robots) == 4
    types = [m.type for m in array.markers]
    assert types.count(Marker.CYLINDER) == 4 and types.count(Marker.ARROW) == 8
    assert types.count(Marker.SPHERE) == 1 and types.count(Marker.TEXT_VIEW_FACING) == 1
    assert len(array.markers) == 4 + 8 + 1 + 1
    by_id = {m.id: m for m in array.markers}
    for robot in robots:
        body = by_id[ground_truth_marker_id(robot.id)]
        assert body.type == Marker.CYLINDER
        assert (body.pose.position.x, body.pose.position.y) == pytest.approx((robot.x, robot.y))
        assert body.scale.x == pytest.approx(robot.size_x)
        assert rgb(body.color) == TEAM_COLOURS[robot.team] and body.color.a == 1.0
        heading, head = by_id[ground_truth_marker_id(robot.id, 1)], by_id[ground_truth_marker_id(robot.id, 2)]
        assert heading.type == head.type == Marker.ARROW and head.scale.y < heading.scale.y
        assert arrow_direction(heading) == pytest.approx((math.cos(robot.yaw), math.sin(robot.yaw), 0.0), abs=1e-9)
    assert {rgb(by_id[ground_truth_marker_id(r.id)].color) for r in robots if r.team == 1} == {(40, 80, 230)}
    assert {rgb(by_id[ground_truth_marker_id(r.id)].color) for r in robots if r.team == -1} == {(220, 40, 40)}
    ball = snapshot.of_class(ObjectClass.BALL)[0]
    sphere = next(m for m in array.markers if m.type == Marker.SPHERE)
    assert (sphere.pose.position.x, sphere.pose.position.y) == pytest.approx((ball.x, ball.y))
    assert rgb(sphere.color) == (255, 140, 0)
    text = next(m for m in array.markers if m.type == Marker.TEXT_VIEW_FACING)
    assert "A 0 : 0 B" in text.text and "KICKOFF" in text.text


def arrow_direction(marker: Marker) -> tuple[float, float, float]:
    """Where an ARROW marker points: its pose's orientation applied to the marker's x axis (unit quaternion)."""
    q = marker.pose.orientation
    return (1 - 2 * (q.y ** 2 + q.z ** 2), 2 * (q.x * q.y + q.w * q.z), 2 * (q.x * q.z - q.w * q.y))


@pytest.mark.parametrize("yaws,head_yaws", [((0.0, math.pi, -math.pi / 2, 2.5), (0.0, 0.0, 0.0, 0.0)),
                                             ((0.3, -2.8, math.pi, -math.pi), (1.2, -0.7, 2.0, -2.0))])
def test_heading_and_head_arrows_point_along_the_body_and_the_gaze(snapshot, yaws, head_yaws):
    poses = dict(enumerate(zip(yaws, head_yaws)))
    posed = dataclasses.replace(snapshot, objects=tuple(
        dataclasses.replace(o, yaw=poses[o.id][0], head_yaw=poses[o.id][1]) if o.id in poses else o
        for o in snapshot.objects))
    by_id = {m.id: m for m in ground_truth_markers(posed, GEOMETRY, STAMP).markers}
    for robot_id, (yaw, head_yaw) in poses.items():
        heading = by_id[ground_truth_marker_id(robot_id, 1)]
        head = by_id[ground_truth_marker_id(robot_id, 2)]
        assert arrow_direction(heading) == pytest.approx((math.cos(yaw), math.sin(yaw), 0.0), abs=1e-9)
        gaze = yaw + head_yaw
        assert arrow_direction(head) == pytest.approx((math.cos(gaze), math.sin(gaze), 0.0), abs=1e-9)
        body = by_id[ground_truth_marker_id(robot_id)]   # a standing body is only turned about z, never tilted
        assert arrow_direction(body) == pytest.approx((math.cos(yaw), math.sin(yaw), 0.0), abs=1e-9)


def test_ground_truth_ids_are_stable(world, snapshot):
    first = ground_truth_markers(snapshot, GEOMETRY, STAMP)
    moved = dataclasses.replace(snapshot, objects=tuple(
        dataclasses.replace(o, x=o.x + 0.3, yaw=o.yaw + 0.5) for o in snapshot.objects), score_team_a=1)
    second = ground_truth_markers(moved, GEOMETRY, STAMP)
    assert [(m.ns, m.id, m.type) for m in first.markers] == [(m.ns, m.id, m.type) for m in second.markers]
    assert [m.pose.position.x for m in first.markers] != [m.pose.position.x for m in second.markers]
    assert "A 1 : 0 B" in second.markers[-1].text


def test_fallen_and_penalized_robots(snapshot):
    status = {0: ObjectStatus.FALLEN, 2: ObjectStatus.PENALIZED}
    changed = dataclasses.replace(snapshot, objects=tuple(
        dataclasses.replace(o, status=status.get(o.id, o.status)) for o in snapshot.objects))
    array = ground_truth_markers(changed, GEOMETRY, STAMP)
    check_well_formed(array)
    by_id = {m.id: m for m in array.markers}
    upright, fallen, penalized = (by_id[ground_truth_marker_id(i)] for i in (1, 0, 2))
    assert fallen.pose.position.z < upright.pose.position.z
    assert abs(fallen.pose.orientation.y) > 0.5                    # axis pitched down onto the ground
    assert rgb(fallen.color) != TEAM_COLOURS[1]                    # tinted grey
    assert fallen.color.a == 1.0 and penalized.color.a < 0.5 and upright.color.a == 1.0
    assert rgb(penalized.color) == TEAM_COLOURS[-1]


def test_include_field(snapshot):
    array = ground_truth_markers(snapshot, GEOMETRY, STAMP, include_field=True)
    check_well_formed(array)
    field = field_markers(GEOMETRY, STAMP)
    assert [m.ns for m in array.markers[:len(field.markers)]] == ["field"] * len(field.markers)
    assert len(array.markers) == len(field.markers) + 14


# ------------------------------------------------------------------------------------------------------- detections

def detection(class_id: ObjectClass, x: float, y: float, *, true_id: int = 7, true_class: int | None = None,
              **fields) -> np.ndarray:
    row = empty(1)
    row["class_id"] = class_id
    row["true_class"] = class_id if true_class is None else true_class
    row["x"], row["y"], row["true_id"] = x, y, true_id
    for name, value in fields.items():
        row[name] = value
    return row


def test_detection_lands_in_the_map_frame():
    pose = (1.0, 0.0, math.pi / 2)
    array = detection_markers(detection(ObjectClass.BALL, 2.0, 0.0), pose, STAMP, robot_name="team_a_1")
    check_well_formed(array)
    det_ns, fp_ns, conf_ns, missed_ns = detection_namespaces("team_a_1")
    assert det_ns == "team_a_1/detections"
    clears = array.markers[:4]
    assert [m.action for m in clears] == [Marker.DELETEALL] * 4
    assert {m.ns for m in clears} == {det_ns, fp_ns, conf_ns, missed_ns}
    (ball,) = of_ns(array, det_ns)
    assert ball.type == Marker.SPHERE and rgb(ball.color) == (255, 140, 0)
    assert (ball.pose.position.x, ball.pose.position.y) == pytest.approx((1.0, 2.0), abs=1e-6)
    assert all(m.ns.startswith("team_a_1/") for m in array.markers)


def test_empty_frame_only_clears():
    array = detection_markers(empty(0), (0.0, 0.0, 0.0), STAMP)
    check_well_formed(array)
    assert array.markers and all(m.action == Marker.DELETEALL for m in array.markers)
    assert array.markers[0].ns.startswith("team_a_0/")


def test_false_positive_confusion_and_miss():
    rows = np.concatenate([
        detection(ObjectClass.BALL, 1.0, 0.0, true_id=-1, true_class=0),
        detection(ObjectClass.BALL, 3.0, 0.5, true_id=9, true_class=ObjectClass.PENALTY_CROSS),
        detection(ObjectClass.GOALPOST, 2.0, -1.0, true_id=3),
    ])
    array = detection_markers(rows, (0.0, 0.0, 0.0), STAMP, missed=[(-1.0, 2.0)], robot_name="team_b_0")
    check_well_formed(array)
    assert array.markers[0].action == Marker.DELETEALL
    det, fp, conf, missed = (of_ns(array, ns) for ns in detection_namespaces("team_b_0"))
    fp_shape = next(m for m in fp if m.type == Marker.SPHERE)
    fp_text = next(m for m in fp if m.type == Marker.TEXT_VIEW_FACING)
    assert fp_text.text == "FP" and rgb(fp_text.color) == rgb(fp_shape.color) == (255, 0, 0)
    assert (fp_shape.pose.position.x, fp_shape.pose.position.y) == pytest.approx((1.0, 0.0))
    assert len(det) == 2                                            # the confused ball and the goalpost
    post = next(m for m in det if m.type == Marker.CYLINDER)
    assert rgb(post.color) == (255, 220, 0) and post.pose.position.y == pytest.approx(-1.0)
    (ring,) = conf
    assert ring.type == Marker.LINE_STRIP and rgb(ring.color) == (255, 0, 0)
    centre = np.mean([(p.x, p.y) for p in ring.points[:-1]], axis=0)
    assert centre == pytest.approx((3.0, 0.5), abs=1e-6)
    (miss,) = missed
    assert miss.type == Marker.LINE_STRIP and rgb(miss.color) == (255, 255, 255)
    assert np.mean([(p.x, p.y) for p in miss.points[:-1]], axis=0) == pytest.approx((-1.0, 2.0), abs=1e-6)


def test_detection_classes_and_team_relation():
    rows = np.concatenate([
        detection(ObjectClass.ROBOT, 1.0, 0.0, team=1, yaw=0.0),
        detection(ObjectClass.ROBOT, 2.0, 0.0, team=-1),
        detection(ObjectClass.PENALTY_CROSS, 1.0, 1.0),
        detection(ObjectClass.LINE_CROSSING, 1.0, -1.0),
        detection(ObjectClass.CENTER_CIRCLE, 3.0, 0.0, size_x=1.5),
        detection(ObjectClass.FIELD_LINE, 2.0, 0.0, line_start_x=1.0, line_start_y=-1.0, line_end_x=3.0,
                  line_end_y=-1.0),
        detection(ObjectClass.FIELD_LINE, 2.0, 0.0, line_start_x=1.0, line_start_y=1.0, line_end_x=3.0,
                  line_end_y=1.0),
    ])
    pose = (0.5, -0.5, math.pi)
    for name, own in (("team_a_0", (40, 80, 230)), ("team_b_1", (220, 40, 40))):
        array = detection_markers(rows, pose, STAMP, robot_name=name)
        check_well_formed(array)
        det = of_ns(array, f"{name}/detections")
        robots = [m for m in det if m.type == Marker.CYLINDER and m.scale.z > 0.1]
        assert [rgb(m.color) for m in robots] == [own, TEAM_COLOURS[-1] if own == TEAM_COLOURS[1] else
                                                  TEAM_COLOURS[1]]
        assert sum(m.type == Marker.ARROW for m in det) == 1      # only the robot with a known yaw
        marks = [m for m in det if m.type == Marker.CYLINDER and m.scale.z < 0.1]
        assert len(marks) == 2 and {rgb(m.color) for m in marks} == {(230, 0, 230)}
        (lines,) = [m for m in det if m.type == Marker.LINE_LIST]
        assert len(lines.points) == 4 and rgb(lines.color) == (0, 230, 230)
        # camera (1, -1) seen from (0.5, -0.5) looking along -x: map (-0.5, 0.5)
        assert (lines.points[0].x, lines.points[0].y) == pytest.approx((-0.5, 0.5), abs=1e-6)
        (circle,) = [m for m in det if m.type == Marker.LINE_STRIP]
        centre = np.mean([(p.x, p.y) for p in circle.points[:-1]], axis=0)
        assert centre == pytest.approx((-2.5, -0.5), abs=1e-6)
        assert math.hypot(circle.points[0].x - centre[0], circle.points[0].y - centre[1]) == pytest.approx(0.75)


def test_real_perception_frame(world):
    """A perception model's frame with its misses converts and serialises (the simulator node's path)."""
    from dynenv_ros.perception.params import load_preset
    from dynenv_ros.soccer.vision import SoccerVision

    vision = SoccerVision(world, load_preset("realistic"))
    vision.frame(0)
    perception = vision.perceive()
    x, y = vision.positions(0)
    robot = 1
    me = world.snapshot().objects[robot]
    rows = perception.of_view(robot)
    missed = missed_positions(perception.visible[robot], rows, vision.objects.object_id, x, y)
    array = detection_markers(rows, (me.x, me.y, me.yaw + me.head_yaw), STAMP, missed=missed,
                              robot_name="team_a_1")
    check_well_formed(array)
    assert len(of_ns(array, "team_a_1/missed")) == len(missed)
    assert len(array.markers) >= 4 + int((rows["class_id"] != ObjectClass.FIELD_LINE).sum())
