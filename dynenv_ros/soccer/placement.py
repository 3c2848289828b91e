"""Where robots and the ball go: kickoff positions, attack starts, sideline spots for penalties, and the spots of
robots out of play.

Positions are drawn in the frame of the team concerned (own goal at -x) and then turned into the field frame,
so a situation and its mirror image between the teams come out as exact point reflections.
"""
from __future__ import annotations

import math

import numpy as np

from dynenv_ros.soccer.config import START_MARGIN, StartConfig
from dynenv_ros.soccer.field import FieldGeometry

# Kickoff roles (docs/original.md §2.2, converted to metres in the team's own frame). Each entry: x0, x spread (uniform
# in [0, spread), negative = away from the ball), x jitter (uniform ±), y0, y jitter (uniform ±).
# Which slot takes which role: see role_order.
KICKING_ROLES = ((-0.275, -0.5, 0.0, 0.0, 0.125),   # striker just behind the ball
                 (-0.275, -0.5, 0.0, -1.5, 0.25),   # right wing
                 (-0.275, -0.5, 0.0, 1.5, 0.25),    # left wing
                 (-2.25, 0.0, 0.25, 0.0, 0.25),     # midfield
                 (-4.3, 0.0, 0.0, 0.0, 0.25))       # keeper
DEFENDING_ROLES = ((-1.7, -0.5, 0.0, 0.0, 0.25),    # just outside the centre circle
                   (-0.95, -0.5, 0.0, -1.5, 0.25),
                   (-0.95, -0.5, 0.0, 1.5, 0.25),
                   (-2.95, -0.5, 0.0, 0.0, 0.25),
                   (-4.3, 0.0, 0.0, 0.0, 0.25))


def to_field(team: int, x: float, y: float, yaw: float) -> tuple[float, float, float]:
    """Team frame → field frame: team A (+1) is the field frame, team B (-1) its point reflection."""
    if team > 0:
        return x, y, yaw
    return -x, -y, math.remainder(yaw + math.pi, math.tau)


KEEPER_ROLE = 4


def role_order(rng: np.random.Generator, players_per_team: int, role_count: int) -> list[int]:
    """Roles by slot: slot 0 keeps goal (SPL's player 1) once a team has two players, the next slot is the striker
    (kickoff) or the circle defender, the rest are drawn from the remaining roles."""
    if players_per_team == 1:
        return [0]
    others = [r for r in range(1, role_count) if r != KEEPER_ROLE]
    drawn = [others[int(i)] for i in rng.permutation(len(others))[:players_per_team - 2]]
    return [KEEPER_ROLE, 0] + drawn


def kickoff_poses(rng: np.random.Generator, players_per_team: int, kicking_team: int
                  ) -> dict[int, list[tuple[float, float, float]]]:
    """Field-frame poses for each team's players (slot order), kicking team drawn first."""
    return {team: role_poses(rng, players_per_team, team, roles)
            for team, roles in ((kicking_team, KICKING_ROLES), (-kicking_team, DEFENDING_ROLES))}


def role_poses(rng: np.random.Generator, players_per_team: int, team: int,
               roles: tuple[tuple[float, float, float, float, float], ...]) -> list[tuple[float, float, float]]:
    """Field-frame poses of one team's players (slot order) at kickoff roles drawn from ``roles``."""
    poses = []
    for role in role_order(rng, players_per_team, len(roles)):
        x0, spread, x_jitter, y0, y_jitter = roles[role]
        x = x0 + spread * rng.random() + x_jitter * rng.uniform(-1.0, 1.0)
        y = y0 + y_jitter * rng.uniform(-1.0, 1.0)
        poses.append(to_field(team, x, y, 0.0))
    return poses


# An attack start (StartConfig.kind "attack"): how the attackers stand around the ball.
BALL_CLEARANCE = 0.25          # m: no robot's centre nearer the ball's (a body 0.10 m + the ball 0.05 m + room)
ROBOT_SPACING = 0.3            # m: no two robots' centres nearer (bodies 0.2 m across + room)
ROBOT_MARGIN = 0.15            # m: attackers' centres this far inside the field lines
ATTACKER_YAW_JITTER = 0.35     # rad (20°): attackers face the attacked goal's centre within this
SCENE_TRIES = 200              # whole scenes drawn before giving up (ball, attackers, defenders)
ROBOT_TRIES = 50               # spots drawn per attacker within one scene


class NoRoomError(RuntimeError):
    """The start settings leave no room for the scene (a ball too close to a defender on every draw)."""


def attack_scene(rng: np.random.Generator, geometry: FieldGeometry, start: StartConfig, players_per_team: int,
                 attacking_team: int) -> tuple[tuple[float, float], list[tuple[float, float, float]],
                                               list[tuple[float, float, float]] | None]:
    """An attack start in the field frame: the ball, the attackers' poses (slot order) and the defenders' (slot
    order; None when ``start.defenders`` is "absent").

    In the attackers' frame (their goal to attack at (half_length, 0)): the ball at a distance d drawn uniformly from
    [ball_distance_min, ball_distance_max] from the goal's centre and a bearing θ uniform within ±ball_max_angle of
    the goals' axis, narrowed where the field's lines (less START_MARGIN) would cut it; each attacker behind the ball
    (within ±90° of the direction from the goal through the ball) at a distance uniform in [BALL_CLEARANCE,
    attacker_distance], inside the field, facing the goal's centre within ±ATTACKER_YAW_JITTER; the defenders at
    their kickoff defending spots (keeper in its goal area), drawn first. A draw that puts the ball or a robot too
    near another body is drawn again (the whole scene at most SCENE_TRIES times: NoRoomError)."""
    hx, hy = geometry.half_length, geometry.half_width
    for _ in range(SCENE_TRIES):
        defenders = None if start.defenders == "absent" else \
            role_poses(rng, players_per_team, -attacking_team, DEFENDING_ROLES)
        others = [to_field(attacking_team, x, y, 0.0)[:2] for x, y, _ in defenders or ()]  # the attackers' frame
        d = rng.uniform(start.ball_distance_min, start.ball_distance_max)
        limit = min(start.ball_max_angle, math.asin(min(1.0, (hy - START_MARGIN) / d)),
                    math.acos(min(1.0, START_MARGIN / d)))
        theta = rng.uniform(-limit, limit)
        bx, by = hx - d * math.cos(theta), d * math.sin(theta)
        if any(math.hypot(bx - x, by - y) < BALL_CLEARANCE for x, y in others):
            continue
        away = math.atan2(by, bx - hx)             # from the goal's centre through the ball
        attackers = []
        for _slot in range(players_per_team):
            spot = _attacker_spot(rng, geometry, start, bx, by, away, others)
            if spot is None:
                break
            x, y = spot
            others.append(spot)
            yaw = math.atan2(-y, hx - x) + rng.uniform(-ATTACKER_YAW_JITTER, ATTACKER_YAW_JITTER)
            attackers.append(to_field(attacking_team, x, y, yaw))
        else:
            ball = to_field(attacking_team, bx, by, 0.0)
            return (ball[0], ball[1]), attackers, defenders
    raise NoRoomError(f"no room for an attack start of {players_per_team} a side after {SCENE_TRIES} draws "
                      f"(start: {start}); widen ball_distance or attacker_distance")


def _attacker_spot(rng: np.random.Generator, geometry: FieldGeometry, start: StartConfig, bx: float, by: float,
                   away: float, others: list[tuple[float, float]]) -> tuple[float, float] | None:
    """One attacker's spot behind the ball (attackers' frame), clear of ``others``; None after ROBOT_TRIES draws."""
    hx, hy = geometry.half_length - ROBOT_MARGIN, geometry.half_width - ROBOT_MARGIN
    for _ in range(ROBOT_TRIES):
        r = rng.uniform(BALL_CLEARANCE, start.attacker_distance)
        phi = away + rng.uniform(-math.pi / 2, math.pi / 2)
        x, y = bx + r * math.cos(phi), by + r * math.sin(phi)
        if abs(x) <= hx and abs(y) <= hy and all(math.hypot(x - ox, y - oy) >= ROBOT_SPACING for ox, oy in others):
            return x, y
    return None


def absent_spot(geometry: FieldGeometry, team: int, slot: int) -> tuple[float, float, float]:
    """Where a robot out of play for the whole episode stands: 1 m beyond the carpet's edge on the -y side, its
    team's side of the halfway line, 0.5 m apart; out of everything (docs/soccer.md, "Start states")."""
    return -team * (1.0 + 0.5 * slot), -(geometry.half_width + geometry.border + 1.0), 0.0


def sideline_spots(geometry: FieldGeometry, team: int, ball_y: float, spacing: float, count: int
                   ) -> list[tuple[float, float, float]]:
    """A team's spots on the sideline away from the ball, own half, facing into the field (docs/original.md §2.1)."""
    side = 1.0 if ball_y < 0 else -1.0
    y = side * geometry.half_width
    yaw = -side * math.pi / 2
    spots = []
    for i in range(count):
        x = -team * (geometry.half_length - (i + 1) * spacing)
        spots.append((x, y, yaw))
    return spots


def free_spot(spots: list[tuple[float, float, float]], occupied: list[tuple[float, float]], clearance: float
              ) -> tuple[float, float, float]:
    """The first spot with nobody within ``clearance``; the last spot if all are taken."""
    for spot in spots:
        if all((spot[0] - ox) ** 2 + (spot[1] - oy) ** 2 >= clearance ** 2 for ox, oy in occupied):
            return spot
    return spots[-1]
