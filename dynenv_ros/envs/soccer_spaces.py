"""Gymnasium spaces and ground-truth encodings for soccer agents.

Until perception lands (issue 4) an agent observes the ground truth in its *team frame*: team A's frame is the
field frame, team B's is its point reflection (positions and headings turned by π), so both teams see the
same picture of the same situation (DynEnv turned positions but not headings, docs/original.md §12.1).
"""
from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from dynenv_ros.soccer.config import SoccerConfig
from dynenv_ros.soccer.world import SoccerWorld

POSITION_BOUND = 10.0   # m; robots beyond the 0.7 m border are penalized, the ball is out before that
VELOCITY_BOUND = 10.0   # m/s
SELF_FIELDS = ("x", "y", "cos_yaw", "sin_yaw", "cos_head", "sin_head", "fallen", "penalized", "kicking")
BALL_FIELDS = ("x", "y", "vx", "vy", "owner")          # owner: +1 own team, -1 opponents, 0 free
OTHER_FIELDS = ("x", "y", "cos_yaw", "sin_yaw", "vx", "vy", "fallen", "penalized", "kicking")
GAME_FIELDS = ("time_remaining", "owner_time_remaining", "goal_difference")
ROBOT_STATE_FIELDS = ("x", "y", "cos_yaw", "sin_yaw", "vx", "vy", "cos_head", "sin_head", "team", "fallen",
                      "penalized", "kicking")
GAME_STATE_FIELDS = ("time_remaining", "ball_owner", "owner_time_remaining", "score_a", "score_b", "phase")


def action_space(config: SoccerConfig) -> spaces.Space:
    """Discrete: MultiDiscrete [walk 5, turn 3, kick 3, head 2·units+1]; continuous: head in rad per period."""
    if config.head_mode == "discrete":
        return spaces.MultiDiscrete([5, 3, 3, 2 * config.motion.head_units + 1])
    bound = config.motion.head_max_delta
    return spaces.Dict({"motion": spaces.MultiDiscrete([5, 3, 3]),
                        "head": spaces.Box(-bound, bound, (1,), np.float32)})


def _bounds(kinds: list[str]) -> tuple[np.ndarray, np.ndarray]:
    limits = {"pos": POSITION_BOUND, "vel": VELOCITY_BOUND, "unit": 1.0, "flag": 1.0, "frac": 1.0, "goals": 50.0,
              "phase": 6.0}
    low = np.array([0.0 if k in ("flag", "frac", "phase") else -limits[k] for k in kinds], np.float32)
    high = np.array([limits[k] for k in kinds], np.float32)
    return low, high


def _kinds(names: tuple[str, ...]) -> list[str]:
    table = {"x": "pos", "y": "pos", "vx": "vel", "vy": "vel", "cos_yaw": "unit", "sin_yaw": "unit",
             "cos_head": "unit", "sin_head": "unit", "fallen": "flag", "penalized": "flag", "kicking": "flag",
             "owner": "unit", "team": "unit", "ball_owner": "unit", "time_remaining": "frac",
             "owner_time_remaining": "frac", "goal_difference": "goals", "score_a": "goals", "score_b": "goals",
             "phase": "phase"}
    return [table[n] for n in names]


class GroundTruthEncoder:
    """Flat float32 vectors: per agent [self, ball, teammates…, opponents…, game]; globally the state."""

    def __init__(self, config: SoccerConfig) -> None:
        self.config = config
        n = config.n_robots
        kinds = (_kinds(SELF_FIELDS) + _kinds(BALL_FIELDS) + _kinds(OTHER_FIELDS) * (n - 1) + _kinds(GAME_FIELDS))
        self.observation_space = spaces.Box(*_bounds(kinds), dtype=np.float32)
        state_kinds = _kinds(ROBOT_STATE_FIELDS) * n + _kinds(BALL_FIELDS[:4]) + _kinds(GAME_STATE_FIELDS)
        state_kinds[-1] = "phase"
        self.state_space = spaces.Box(*_bounds(state_kinds), dtype=np.float32)
        self._low, self._high = self.observation_space.low, self.observation_space.high
        per_team = config.players_per_team
        # Row order of the other robots as seen by each robot: teammates by slot, then opponents by slot.
        self._others = []
        for i in range(n):
            team_start = 0 if i < per_team else per_team
            mates = [j for j in range(team_start, team_start + per_team) if j != i]
            opponents = [j for j in range(per_team - team_start, 2 * per_team - team_start)]
            self._others.append(np.array(mates + opponents, dtype=np.intp))

    def _clock_fractions(self, world: SoccerWorld) -> tuple[float, float]:
        """Episode time left and ball-ownership time left, each as a fraction of its longest value."""
        c = self.config
        longest_ownership = max(c.ball.free_kick_ownership_seconds, c.ball.kickoff_ownership_seconds)
        return (world.time_remaining / (c.episode_periods * c.period_seconds),
                world.state.ball_owner_remaining / longest_ownership)

    def _robot_table(self, world: SoccerWorld) -> np.ndarray:
        rows = []
        for r in world.robots:
            rules = r.rules
            moving = r.in_space
            v = r.body.velocity if moving else (0.0, 0.0)
            yaw = r.body.angle
            rows.append((r.x, r.y, math.cos(yaw), math.sin(yaw), v[0], v[1], math.cos(r.head_yaw),
                         math.sin(r.head_yaw), r.team, rules.fallen, rules.penalized, r.kick is not None))
        return np.array(rows, dtype=np.float64)

    def observations(self, world: SoccerWorld) -> np.ndarray:
        """(n_robots, obs_dim) team-frame ground truth for every robot."""
        table = self._robot_table(world)
        bx, by = world.ball_xy
        bv = world.ball.velocity
        s = world.state
        time_frac, owner_frac = self._clock_fractions(world)
        out = np.empty((len(world.robots), self.observation_space.shape[0]), np.float64)
        team = table[:, 8]
        for i, others in enumerate(self._others):
            t = team[i]
            me = table[i]
            row = [t * me[0], t * me[1], t * me[2], t * me[3], me[6], me[7], me[9], me[10], me[11],
                   t * bx, t * by, t * bv.x, t * bv.y, t * s.ball_owner]
            o = table[others]
            block = np.column_stack((t * o[:, 0:6], o[:, 9:12]))
            goal_diff = s.score[int(t)] - s.score[-int(t)]
            out[i] = np.concatenate((row, block.ravel(), (time_frac, owner_frac, goal_diff)))
        return np.clip(out, self._low, self._high).astype(np.float32)

    def state(self, world: SoccerWorld) -> np.ndarray:
        """Field-frame ground truth of the whole game (PettingZoo ``state()``)."""
        table = self._robot_table(world)
        s = world.state
        bx, by = world.ball_xy
        bv = world.ball.velocity
        time_frac, owner_frac = self._clock_fractions(world)
        tail = (bx, by, bv.x, bv.y, time_frac, s.ball_owner, owner_frac,
                s.score[1], s.score[-1], int(s.phase))
        flat = np.concatenate((table.ravel(), tail))
        return np.clip(flat, self.state_space.low, self.state_space.high).astype(np.float32)
