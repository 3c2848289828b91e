"""ROS-free records → the ros-sports messages (docs/interfaces.md, "ros-sports interfaces").

Thin copies: the mapping itself is in ``perception/soccer_vision_3d.py`` (detections) and
``gamecontroller/game_state.py`` (game state), which run and are tested without ROS.
"""
from __future__ import annotations

import math

from game_controller_spl_interfaces.msg import RCGCD15, RCGCRD4
from geometry_msgs.msg import Point, Vector3
from soccer_vision_3d_msgs.msg import (Ball, BallArray, Goalpost, GoalpostArray, MarkingArray, MarkingEllipse,
                                       MarkingIntersection, MarkingSegment, Robot, RobotArray)
from std_msgs.msg import Header
from vision_msgs.msg import BoundingBox3D

from dynenv_ros.gamecontroller import packet as gc
from dynenv_ros.perception import soccer_vision_3d as sv


def _box(box: sv.Box) -> BoundingBox3D:
    out = BoundingBox3D()
    out.center.position = Point(x=box.x, y=box.y, z=box.z)
    out.center.orientation.z, out.center.orientation.w = math.sin(box.yaw / 2), math.cos(box.yaw / 2)
    out.size = Vector3(x=box.size_x, y=box.size_y, z=box.size_z)
    return out


def soccer_vision_messages(frame: sv.SoccerVision3D, header: Header
                           ) -> tuple[BallArray, RobotArray, GoalpostArray, MarkingArray]:
    """The four arrays of one frame, each with ``header`` (the frame's stamp, the robot's base_link)."""
    balls = BallArray(header=header, balls=[Ball(center=Point(x=b.x, y=b.y, z=b.z)) for b in frame.balls])
    for msg, b in zip(balls.balls, frame.balls):
        msg.confidence.confidence = b.confidence
    robots = RobotArray(header=header)
    for r in frame.robots:
        msg = Robot(bb=_box(r.bb))
        msg.attributes.player_number, msg.attributes.team = r.player_number, r.team
        msg.attributes.state, msg.attributes.facing = r.state, r.facing
        msg.confidence.confidence = r.confidence
        robots.robots.append(msg)
    posts = GoalpostArray(header=header)
    for p in frame.goalposts:
        msg = Goalpost(bb=_box(p.bb))
        msg.attributes.side, msg.attributes.team = p.side, p.team
        msg.confidence.confidence = p.confidence
        posts.posts.append(msg)
    markings = MarkingArray(header=header)
    for seg in frame.segments:
        msg = MarkingSegment(start=Point(x=seg.start[0], y=seg.start[1]), end=Point(x=seg.end[0], y=seg.end[1]))
        msg.confidence.confidence = seg.confidence
        markings.segments.append(msg)
    for i in frame.intersections:
        msg = MarkingIntersection(center=Point(x=i.x, y=i.y), num_rays=i.num_rays)
        msg.confidence.confidence = i.confidence
        markings.intersections.append(msg)
    for e in frame.ellipses:
        msg = MarkingEllipse(diameter=e.diameter)
        msg.center.position = Point(x=e.x, y=e.y)
        msg.confidence.confidence = e.confidence
        markings.ellipses.append(msg)
    return balls, robots, posts, markings


def rcgcd15(data: gc.GameControlData) -> RCGCD15:
    """The RCGCD message ``game_controller_spl`` publishes on ``gc/data`` for this packet content. RCGCD15 has the
    current GameController's layout (struct versions 15 and 18 differ only in the meaning of a few values);
    ``TeamInfo15.team_colour`` has no field in the packet and stays 0, as there."""
    msg = RCGCD15(packet_number=data.packet_number, players_per_team=data.players_per_team,
                  competition_phase=data.competition_phase, competition_type=data.competition_type,
                  game_phase=data.game_phase, state=data.state, set_play=data.set_play,
                  first_half=int(bool(data.first_half)), kicking_team=data.kicking_team,
                  secs_remaining=data.secs_remaining, secondary_time=data.secondary_time)
    for out, team in zip(msg.teams, data.teams):
        out.team_number, out.field_player_colour = team.team_number, team.field_player_colour
        out.goalkeeper_colour, out.goalkeeper, out.score = team.goalkeeper_colour, team.goalkeeper, team.score
        out.penalty_shot, out.single_shots, out.message_budget = (team.penalty_shot, team.single_shots,
                                                                  team.message_budget)
        for slot, player in zip(out.players, team.players):
            slot.penalty, slot.secs_till_unpenalised = player.penalty, player.secs_till_unpenalised
    return msg


def rcgcrd4(data: gc.ReturnData) -> RCGCRD4:
    """A robot's return packet as the ``RCGCRD4`` message ``game_controller_spl`` reads on ``gc/return_data``."""
    return RCGCRD4(player_num=data.player_num, team_num=data.team_num, fallen=int(bool(data.fallen)),
                   pose=list(data.pose), ball_age=data.ball_age, ball=list(data.ball))


def return_data(msg: RCGCRD4) -> gc.ReturnData:
    """``gc/return_data`` → the packet content (checked when encoded: ``packet.encode_return_data``)."""
    return gc.ReturnData(player_num=int(msg.player_num), team_num=int(msg.team_num), fallen=bool(msg.fallen),
                         pose=tuple(float(v) for v in msg.pose), ball_age=float(msg.ball_age),
                         ball=tuple(float(v) for v in msg.ball))
