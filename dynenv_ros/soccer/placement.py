"""Where robots and the ball go: kickoff positions, sideline spots for penalties, and free-kick ball spots.

Positions are drawn in the frame of the team concerned (own goal at -x) and then turned into the field frame,
so a situation and its mirror image between the teams come out as exact point reflections.
"""
from __future__ import annotations

import math

import numpy as np

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
    poses: dict[int, list[tuple[float, float, float]]] = {}
    for team, roles in ((kicking_team, KICKING_ROLES), (-kicking_team, DEFENDING_ROLES)):
        chosen = role_order(rng, players_per_team, len(roles))
        team_poses = []
        for role in chosen:
            x0, spread, x_jitter, y0, y_jitter = roles[role]
            x = x0 + spread * rng.random() + x_jitter * rng.uniform(-1.0, 1.0)
            y = y0 + y_jitter * rng.uniform(-1.0, 1.0)
            team_poses.append(to_field(team, x, y, 0.0))
        poses[team] = team_poses
    return poses


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
