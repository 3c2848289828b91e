"""The game's rule state and decisions that need no physics: phases, ball ownership, the touch chain, outs.

Values of ``Phase`` are the PHASE_* constants of dynenv_msgs/WorldState.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

from dynenv_ros.soccer.config import BallConfig, PenaltyConfig
from dynenv_ros.soccer.field import FieldGeometry


class Phase(IntEnum):
    INITIAL = 0
    KICKOFF = 1
    PLAYING = 2
    KICK_IN = 3
    GOAL_KICK = 4
    CORNER_KICK = 5
    FINISHED = 6


@dataclass
class GameState:
    kickoff_team: int = 1                 # who kicked off this episode: breaks "nobody touched it yet" ties
    phase: Phase = Phase.INITIAL
    ball_owner: int = 0                   # +1 / -1 owns a kickoff or free kick, 0 free
    ball_owner_remaining: float = 0.0     # s
    chain: list[int] = field(default_factory=list)   # robot indices, most recent first, no duplicates
    score: dict[int, int] = field(default_factory=lambda: {1: 0, -1: 0})
    penalty_seconds: dict[int, float] = field(default_factory=dict)   # next penalty's duration per team

    def touched(self, robot: int, max_length: int) -> None:
        if robot in self.chain:
            self.chain.remove(robot)
        self.chain.insert(0, robot)
        del self.chain[max_length:]

    def give_ball(self, team: int, seconds: float, phase: Phase) -> None:
        self.ball_owner, self.ball_owner_remaining, self.phase = team, seconds, phase

    def free_ball(self) -> None:
        self.ball_owner, self.ball_owner_remaining, self.phase = 0, 0.0, Phase.PLAYING

    def next_penalty(self, team: int, config: PenaltyConfig) -> float:
        seconds = self.penalty_seconds.get(team, config.first_seconds)
        self.penalty_seconds[team] = seconds + config.increment_seconds
        return seconds


@dataclass(frozen=True)
class OutDecision:
    """What happens after the ball left the field."""
    goal_for: int = 0                      # team that scored, 0 if no goal
    restart: Phase = Phase.PLAYING
    ball_xy: tuple[float, float] = (0.0, 0.0)
    awarded_to: int = 0                    # team owning the free kick


def decide_out(x: float, y: float, last_team: int, geometry: FieldGeometry, ball: BallConfig) -> OutDecision:
    """Goal, kick-in, goal kick or corner for a ball wholly over a line at (x, y), last touched by ``last_team``."""
    hx, hy = geometry.half_length, geometry.half_width
    if abs(x) > hx:
        end = 1 if x > 0 else -1          # the goal at +x belongs to team B (-1), whom team A (+1) attacks
        if abs(y) < geometry.goal_width / 2:
            return OutDecision(goal_for=end, restart=Phase.KICKOFF)
        defender = -end
        if last_team == end:               # the attackers put it out: goal kick for the defenders
            spot = (end * (hx - geometry.goal_area_length), 0.0)
            return OutDecision(restart=Phase.GOAL_KICK, ball_xy=spot, awarded_to=defender)
        spot = (end * hx, hy if y > 0 else -hy)
        return OutDecision(restart=Phase.CORNER_KICK, ball_xy=spot, awarded_to=end)
    # Over a sideline: kick-in on the line, moved toward the goal of the team that touched it last.
    shifted = x - last_team * ball.sideline_out_shift
    shifted = max(-hx, min(hx, shifted))
    return OutDecision(restart=Phase.KICK_IN, ball_xy=(shifted, hy if y > 0 else -hy), awarded_to=-last_team)
