"""Who team B is in each world of a league run: every episode, each world draws its opponent from the league's
members by prioritized fictitious self-play (PFSP; Vinyals et al. 2019, AlphaStar): a member is drawn with a
weight f(s) = (1 − s)² (their "hard" weighting), where s is the learner's recent score against it (win 1, draw ½,
loss 0), so the opponents it cannot yet beat come most often. A floor keeps every member in play, so what was
learnt against one is not forgotten.

Members: the scripted teams played inside the worlds — ``perceiving`` (keeper and chasers on each robot's own
detections and pose estimate), ``perceiving_chasers`` (chasers in every slot), ``keeper_and_chasers`` (the
ground-truth team) — and ``snapshot``: a frozen copy of the learner, whose actions the trainer sends for team B.
The score is a moving average over each member's last games (``memory``), starting from ½. ``state`` and
``restore`` carry the scores and game counts across a resumed run (the trainer checkpoints them), so a resume does
not send the learner back to uniform draws.
"""
from __future__ import annotations

from typing import Any, Iterable

import numpy as np

LEAGUE_MEMBERS = ("perceiving", "perceiving_chasers", "keeper_and_chasers", "snapshot")
FLOOR = 0.05          # each member's least share of the draws, whatever its score
MEMORY = 50           # games: the moving average's horizon


def pfsp_weights(scores: np.ndarray, floor: float = FLOOR) -> np.ndarray:
    """Draw probabilities from the learner's scores against each member: (1 − s)², then the floor, normalised."""
    hard = np.square(1.0 - np.clip(scores, 0.0, 1.0))
    total = hard.sum()
    base = hard / total if total > 0 else np.full_like(hard, 1.0 / hard.size)
    mixed = floor + (1.0 - floor * hard.size) * base
    return mixed / mixed.sum()


class League:
    """The members, the learner's score against each, and the draw of the next opponent."""

    def __init__(self, members: Iterable[str], rng: np.random.Generator, memory: int = MEMORY,
                 floor: float = FLOOR) -> None:
        self.members = tuple(members)
        unknown = [m for m in self.members if m not in LEAGUE_MEMBERS]
        if not self.members or unknown:
            raise ValueError(f"league members must be some of {LEAGUE_MEMBERS}, got {self.members}")
        if not 0.0 <= floor * len(self.members) < 1.0:
            raise ValueError(f"floor {floor} leaves nothing to weight among {len(self.members)} members")
        self.rng, self.memory, self.floor = rng, memory, floor
        self.scores = np.full(len(self.members), 0.5)
        self.games = np.zeros(len(self.members), np.int64)

    def draw(self) -> str:
        return self.members[int(self.rng.choice(len(self.members), p=pfsp_weights(self.scores, self.floor)))]

    def record(self, member: str, goals_for: int, goals_against: int) -> None:
        """One finished game of the learner against ``member``."""
        i = self.members.index(member)
        outcome = 1.0 if goals_for > goals_against else 0.0 if goals_for < goals_against else 0.5
        self.games[i] += 1
        rate = 1.0 / min(int(self.games[i]), self.memory)
        self.scores[i] += rate * (outcome - self.scores[i])

    def stats(self) -> dict[str, float]:
        """Per member: the learner's score and the share of draws it now gets (for the run's log)."""
        weights = pfsp_weights(self.scores, self.floor)
        out: dict[str, float] = {}
        for member, score, weight, games in zip(self.members, self.scores, weights, self.games):
            out[f"league/{member}_score"] = float(score)
            out[f"league/{member}_share"] = float(weight)
            out[f"league/{member}_games"] = float(games)
        return out

    def state(self) -> dict[str, Any]:
        """What ``restore`` needs: the members, the learner's score against each and the games counted (JSON)."""
        return {"members": list(self.members), "scores": [float(x) for x in self.scores],
                "games": [int(n) for n in self.games]}

    def restore(self, state: dict[str, Any]) -> None:
        """Scores and game counts from ``state`` (a checkpoint's); ValueError, and nothing changed, unless its
        members are these and every score lies in [0, 1] and every count is a whole number ≥ 0."""
        try:
            members = [str(m) for m in state["members"]]
            scores = np.asarray(state["scores"], dtype=np.float64)
            games = np.asarray(state["games"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"a league state needs members, scores and games lists: {error}") from None
        if members != list(self.members):
            raise ValueError(f"the league state's members {members} are not this league's {list(self.members)}")
        if scores.shape != (len(members),) or games.shape != (len(members),):
            raise ValueError(f"a league state needs one score and one game count per member ({len(members)})")
        if not np.all(np.isfinite(scores)) or np.any((scores < 0.0) | (scores > 1.0)):
            raise ValueError(f"league scores must lie in [0, 1], got {scores.tolist()}")
        if not np.all(np.isfinite(games)) or np.any(games < 0) or np.any(games != np.round(games)):
            raise ValueError(f"league game counts must be whole numbers >= 0, got {games.tolist()}")
        self.scores = scores.copy()
        self.games = games.astype(np.int64)
