"""The targets of the self-supervised localization and reconstruction losses, for every robot at one instant.

The instant is the one a padded observation describes: the last vision frame of its motion period (the period's
end; for the observation after a reset, the reset state, which every frame of that period shows). Everything is in
the observing robot's **team frame**: origin at the field centre, x towards the opponent goal, y to its left, in
metres. Team A's frame is the field frame; team B's is the field frame turned by π — positions negated and every
orientation turned by π (cos and sin negated), so both teams see the same picture of the same situation (DynEnv
reflected positions but not orientations, docs/original.md §12.1). Angles relative to the robot itself (the head yaw)
are the same in every frame: h is the head yaw relative to the body, θ + h the gaze.

Per robot (arrays with leading robot axis A; the vectorised batch adds an env axis in front), float32:

| key | shape | columns |
|---|---|---|
| ``pose`` | (A, 6) | ``POSE_COLUMNS``: x, y, cos(θ+h), sin(θ+h), cos h, sin h (θ body yaw, h head yaw) |
| ``ball`` | (A, 3) | ``BALL_COLUMNS``: x, y, owner (+1 own team, −1 opponents, 0 free: ``game[0]``) |
| ``robots`` | (A, R, 6) | ``ROBOT_COLUMNS`` of every other robot: x, y, cos yaw, sin yaw, teammate 1/0, fallen 1/0 |
| ``ball_seen`` | (A,) | 1 where the robot truly saw the ball in at least one frame of the period, else 0 |
| ``robots_seen`` | (A, R) | the same for each row of ``robots`` |

R = 2·players_per_team − 1. Rows of ``robots`` (``other_robots``): the robot's teammates by robot index, then the
opponents by robot index (the order of the ground-truth observation's other robots). A penalized robot is where
the world put it (a sideline spot), not fallen.

"Truly saw" is the truth the observation reward uses (``perception.seen``, DynEnv's ``seen_stats``): the object was
in view, in range and not hidden, and the perception model detected it as what it is (neither missed nor confused
with another class) — never a false positive, however close it lies. With the ``none`` perception preset it is
exactly geometric visibility.
"""
from __future__ import annotations

import numpy as np

from dynenv_ros.perception.model import Perception
from dynenv_ros.soccer.vision import SoccerVision

POSE_COLUMNS = ("x", "y", "cos_gaze", "sin_gaze", "cos_head", "sin_head")
BALL_COLUMNS = ("x", "y", "owner")
ROBOT_COLUMNS = ("x", "y", "cos_yaw", "sin_yaw", "teammate", "fallen")
TARGET_KEYS = ("pose", "ball", "robots", "ball_seen", "robots_seen")


def other_robots(players_per_team: int) -> np.ndarray:
    """(A, R) robot indices of the rows of ``robots`` per observing robot: teammates by index, then opponents by
    index (robots 0..P-1 are team A, P..2P-1 team B)."""
    p = players_per_team
    index = np.arange(2 * p)
    team_b = index >= p
    # Per observer, all robots sorted by (opponent?, index), itself left out.
    order = np.where(team_b[:, None] == team_b[None, :], index[None, :], index[None, :] + 2 * p)
    ranked = np.argsort(order, axis=1, kind="stable")
    return ranked[ranked != index[:, None]].reshape(2 * p, 2 * p - 1)


def target_shapes(players_per_team: int) -> dict[str, tuple[int, ...]]:
    """Per-robot shapes (without the leading robot axis), in ``TARGET_KEYS`` order."""
    others = 2 * players_per_team - 1
    return {"pose": (len(POSE_COLUMNS),), "ball": (len(BALL_COLUMNS),), "robots": (others, len(ROBOT_COLUMNS)),
            "ball_seen": (), "robots_seen": (others,)}


def empty_targets(players_per_team: int, *batch: int) -> dict[str, np.ndarray]:
    """Zeroed float32 target arrays with leading ``batch`` axes (e.g. ``empty_targets(2, A)``)."""
    return {key: np.zeros(batch + shape, np.float32) for key, shape in target_shapes(players_per_team).items()}


class LearningTargets:
    """The targets of one world's robots (P players per team: robots 0..P-1 team A, P..2P-1 team B). ``fill`` reads
    them from the world's vision after ``SoccerVision.perceive``; ``compute`` from field-frame arrays."""

    def __init__(self, players_per_team: int) -> None:
        self.players_per_team = p = players_per_team
        n = 2 * p
        self.others = other_robots(p)                                          # (A, R)
        self.teams = np.where(np.arange(n) < p, 1, -1)
        sign = self.teams.astype(np.float64)          # the team frame: field frame · sign (−1: turned by π)
        self._sign2, self._sign3 = sign[:, None], sign[:, None, None]
        self._rows = np.arange(n)[:, None]
        self._teammate = (self.teams[self.others] == self.teams[:, None]).astype(np.float32)
        # Work arrays (float64): every robot, then the ball, [x, y, cos yaw, sin yaw] (the ball's cos, sin: 0); and
        # the poses before the cast. The arrays are tiny: the cost is the number of numpy calls, kept low.
        self._table = np.zeros((n + 1, 4))
        self._pose = np.empty((n, len(POSE_COLUMNS)))

    def compute(self, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, head: np.ndarray, fallen: np.ndarray,
                owner: np.ndarray, seen: np.ndarray, out: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Fill ``out`` (``empty_targets(P, A)``'s keys and shapes; new arrays if None) from the field-frame state
        at one instant. x, y: (A + 1,) positions of robots 0..A-1, then the ball (m); yaw, head, fallen: (A,) body
        yaw, head yaw relative to the body (rad), fallen flag; owner: (A,) ball owner relative to each robot's
        team; seen: (A, A + 1) bool, what each robot truly saw (robots, then the ball)."""
        n = 2 * self.players_per_team
        if out is None:
            out = empty_targets(self.players_per_team, n)
        table, pose = self._table, self._pose
        table[:, 0], table[:, 1] = x, y
        table[:n, 2], table[:n, 3] = np.cos(yaw), np.sin(yaw)
        gaze = yaw + head                             # turns with the frame
        pose[:, 0], pose[:, 1], pose[:, 2], pose[:, 3] = x[:n], y[:n], np.cos(gaze), np.sin(gaze)
        pose[:, :4] *= self._sign2
        pose[:, 4], pose[:, 5] = np.cos(head), np.sin(head)     # relative to the body: the same in every frame
        out["pose"][...] = pose
        ball = out["ball"]
        ball[:, :2] = table[n, :2] * self._sign2
        ball[:, 2] = owner
        robots = out["robots"]
        robots[..., :4] = table[self.others] * self._sign3
        robots[..., 4] = self._teammate
        robots[..., 5] = fallen[self.others]
        out["ball_seen"][:] = seen[:, n]
        out["robots_seen"][:] = seen[self._rows, self.others]
        return out

    def fill(self, vision: SoccerVision, perception: Perception,
             out: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The targets of the instant the period's observation describes: its last vision frame."""
        n = 2 * self.players_per_team
        frames = len(perception) // n
        last = frames - 1
        x, y = vision.positions(last)
        yaw, head, fallen = vision.robot_states(last)
        seen = perception.seen.reshape(frames, n, -1)[:, :, :n + 1].any(axis=0)   # robots 0..n-1, the ball n
        owner = vision.game_controller[last, :, 0]     # what the observation's game[0] holds
        return self.compute(x[:n + 1], y[:n + 1], yaw, head, fallen, owner, seen, out)
