"""A curriculum of start states for soccer training (``TrainConfig.curriculum``, docs/training.md "A curriculum of
start states"): ordered stages, each saying how its training episodes start (``soccer.config.StartConfig``) and at
how many of the learner's env steps it ends; the last lasts to the run's end.

Reverse curricula start episodes near success and move the start back as the policy learns (Florensa et al. 2017;
Google Research Football's academy): an empty goal with the ball 1–3 m from it, then further, then defended, then
the kickoff game. The worlds change stage only between episodes (``sampling.worlds.follow_curriculum``).

A stage as YAML (every key but ``until`` optional; ``until`` absent on the last stage, required on every other)::

    {until: 300_000, start: attack, ball_distance: [1.0, 3.0], attacker_distance: 1.0, defenders: absent,
     episode_seconds: 20}

``ball_distance``, ``attacker_distance``, ``defenders`` and ``kickoff_share`` apply to ``start: attack`` only (a
kickoff stage that names them is refused); left out, they take ``StartConfig``'s defaults (1–3 m, 1 m, present, 0).
``kickoff_share`` mixes kickoffs into an attack stage (that share of its episodes, drawn per episode by each world),
so that a last stage can keep the attack scenes while the game from the kickoff is learnt: a curriculum that moves
wholly to kickoffs can forget how to score (docs/training.md). ``episode_seconds``
left out: the run's own (``TrainConfig.episode_seconds``, else the world's 120 s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from dynenv_ros.soccer.config import DEFENDERS, START_KINDS

STAGE_KEYS = ("until", "start", "ball_distance", "attacker_distance", "defenders", "kickoff_share", "episode_seconds")
ATTACK_KEYS = ("ball_distance", "attacker_distance", "defenders", "kickoff_share")
MAX_EPISODE_SECONDS = 3600.0


class CurriculumError(ValueError):
    """A curriculum that cannot work; the message names the stage and its key."""


@dataclass(frozen=True)
class CurriculumStage:
    """One stage: how its episodes start and when it ends (module docstring)."""
    until: int | None = None                               # learner's env steps at which the stage ends; None: last
    start: str = "kickoff"                                 # StartConfig.kind
    ball_distance: tuple[float, float] | None = None       # m from the attacked goal's centre, [min, max]
    attacker_distance: float | None = None                 # m
    defenders: str | None = None                           # "present" or "absent"
    kickoff_share: float | None = None                     # share of the stage's episodes that are kickoffs instead
    episode_seconds: float | None = None                   # s; None: the run's

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, the keys set only (what ``parse_curriculum`` reads back)."""
        out: dict[str, Any] = {"until": self.until, "start": self.start}
        for key in ("ball_distance", "attacker_distance", "defenders", "kickoff_share", "episode_seconds"):
            value = getattr(self, key)
            if value is not None:
                out[key] = list(value) if isinstance(value, tuple) else value
        return out

    def soccer_settings(self) -> dict[str, Any]:
        """The ``SoccerConfig`` settings this stage changes (``start``, ``episode_seconds``), as a mapping."""
        start: dict[str, Any] = {"kind": self.start}
        if self.ball_distance is not None:
            start["ball_distance_min"], start["ball_distance_max"] = self.ball_distance
        if self.attacker_distance is not None:
            start["attacker_distance"] = self.attacker_distance
        if self.defenders is not None:
            start["defenders"] = self.defenders
        if self.kickoff_share is not None:
            start["kickoff_share"] = self.kickoff_share
        settings: dict[str, Any] = {"start": start}
        if self.episode_seconds is not None:
            settings["episode_seconds"] = self.episode_seconds
        return settings


def parse_curriculum(value: Any) -> tuple[CurriculumStage, ...]:
    """Stages from a list of mappings (YAML, JSON) or of stages; CurriculumError naming the stage and key of
    anything that cannot work (a field-dependent check, distances inside the field, is the world config's:
    ``TrainConfig`` builds each stage's ``SoccerConfig``)."""
    if not isinstance(value, (list, tuple)) or not value:
        raise CurriculumError(f"expected a list of stages (mappings with until, start, ...), got {value!r}")
    stages = tuple(_stage(i, item) for i, item in enumerate(value))
    last = len(stages) - 1
    previous = 0
    for i, stage in enumerate(stages):
        if i == last:
            if stage.until is not None:
                raise CurriculumError(f"stage {i} (the last) lasts to the run's end: leave out its until "
                                      f"(got {stage.until})")
            continue
        if stage.until is None:
            raise CurriculumError(f"stage {i}: until (the env steps at which it ends) is required on every stage "
                                  f"but the last")
        if stage.until <= previous:
            raise CurriculumError(f"stage {i}: until {stage.until} must be greater than "
                                  + (f"stage {i - 1}'s ({previous})" if i else "0")
                                  + ": stage ends must increase")
        previous = stage.until
    return stages


def _stage(i: int, item: Any) -> CurriculumStage:
    if isinstance(item, CurriculumStage):
        item = item.as_dict()
    if not isinstance(item, Mapping):
        raise CurriculumError(f"stage {i}: expected a mapping of {', '.join(STAGE_KEYS)}, got {item!r}")
    for key in item:
        if key not in STAGE_KEYS:
            raise CurriculumError(f"stage {i}: unknown key {key!r}; a stage takes {', '.join(STAGE_KEYS)}")
    until = item.get("until")
    if until is not None and (isinstance(until, bool) or not isinstance(until, int) or until < 1):
        raise CurriculumError(f"stage {i}: until must be a whole number of env steps >= 1, got {until!r}")
    start = item.get("start", "kickoff")
    if start not in START_KINDS:
        raise CurriculumError(f"stage {i}: unknown start {start!r}; expected one of {', '.join(START_KINDS)}")
    given = [key for key in ATTACK_KEYS if item.get(key) is not None]
    if start != "attack" and given:
        raise CurriculumError(f"stage {i}: {', '.join(given)} appl{'ies' if len(given) == 1 else 'y'} to start: "
                              f"attack only (this stage starts with a {start})")
    distance = item.get("ball_distance")
    if distance is not None:
        if not isinstance(distance, (list, tuple)) or len(distance) != 2 or not all(_number(d) for d in distance):
            raise CurriculumError(f"stage {i}: ball_distance must be [min, max] in metres, got {distance!r}")
        low, high = float(distance[0]), float(distance[1])
        if low > high:
            raise CurriculumError(f"stage {i}: ball_distance [{low:g}, {high:g}] is inverted (min > max)")
        distance = (low, high)
    reach = item.get("attacker_distance")
    if reach is not None:
        if not _number(reach):
            raise CurriculumError(f"stage {i}: attacker_distance must be a number of metres, got {reach!r}")
        reach = float(reach)
    defenders = item.get("defenders")
    if defenders is not None and defenders not in DEFENDERS:
        raise CurriculumError(f"stage {i}: unknown defenders {defenders!r}; expected one of {', '.join(DEFENDERS)}")
    share = item.get("kickoff_share")
    if share is not None:               # range and defenders: StartConfig.check, with every other start setting
        if not _number(share):
            raise CurriculumError(f"stage {i}: kickoff_share must be a number (a share of episodes), got {share!r}")
        share = float(share)
    seconds = item.get("episode_seconds")
    if seconds is not None:
        if not _number(seconds) or not 0.0 < seconds <= MAX_EPISODE_SECONDS:
            raise CurriculumError(f"stage {i}: episode_seconds must be in (0, {MAX_EPISODE_SECONDS:g}], got "
                                  f"{seconds!r}")
        seconds = float(seconds)
    return CurriculumStage(until, start, distance, reach, defenders, share, seconds)


def _number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def stage_at(stages: tuple[CurriculumStage, ...] | None, env_steps: int) -> int:
    """The stage in force after ``env_steps`` of the learner's (0 = the first; 0 without a curriculum): a stage ends
    once env_steps reaches its ``until``."""
    for i, stage in enumerate(stages or ()):
        if stage.until is None or env_steps < stage.until:
            return i
    return 0
