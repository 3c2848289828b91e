"""The game a simulator node serves, without ROS: a scenario's session (``soccer_session``, ``driving_session``) and
its action gate (``action_gate``), run period by period, and what goes out when.

Stepped mode runs a motion period as soon as every controlled robot has acted (or when asked: ``step_request``)
and sends its frames, then its feedback, at once; real time sends one frame per call of ``realtime_tick`` (the
node's wall timer) and runs the next period when the last one's frames are out. Sim time (every stamp) runs on
across episodes, so ``use_sim_time`` nodes never see it jump back; the world's tick restarts with each episode
(``absolute_tick``). The node's adapter (``nodes/sim_node.py``) is the ``Outlet``: it converts and publishes.
"""
from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Mapping
from typing import Any, Protocol

import yaml

from dynenv_ros.envs.action_gate import ActionGate
from dynenv_ros.envs.session import PeriodOutput
from dynenv_ros.envs.soccer_session import kickoff_team
from dynenv_ros.sim.seeding import checked_seed

MODES_OF_RUNNING = ("stepped", "realtime")
SCENARIOS = ("robocup", "driving")
MAX_STEP_PERIODS = 100   # /sim/step: at most this many motion periods per call, so services stay answered
MAX_OPTIONS_CHARS = 4096  # /sim/reset: options_yaml longer than this is refused before parsing
# What the diagnostics count, in their order: action outcomes, then each refusal's kind.
COUNTED = ("accepted", "missing", "ignored_after_episode_end", "publish_failed") + tuple(
    f"rejected_{r}" for r in ("malformed", "out_of_range", "unknown_robot", "wrong_episode", "late", "early",
                              "duplicate", "mac_missing", "mac_invalid", "replayed"))

Poses = tuple[Any, Any]     # a period's (F, n, 3) pose estimates and their variances


class Outlet(Protocol):
    """What the node does with the game's output."""

    def frame(self, output: PeriodOutput, k: int, poses: Poses | None, tick: int) -> None:
        """Send frame k of a period (``poses``: the period's estimates, None without localization; ``tick``: its
        sim time, ``SimGame.absolute_tick``)."""

    def feedback(self, output: PeriodOutput, digests: dict[int, bytes], tick: int) -> None:
        """Send each robot's feedback of a period (``digests``: robot -> the action it ran; ``tick``: the sim time
        of the period's last frame)."""

    def episode_started(self, episode: int, tick: int) -> None:
        """A new episode is about to send its first frames (``tick``: sim time now)."""

    def period_ran(self, output: PeriodOutput) -> None:
        """A period ran; its frames go out next."""

    def announce(self, text: str, tick: int) -> None:
        """Say that something happened (a goal, a penalty, ...; ``tick``: sim time now), after its period's frames
        went out."""

    def finish(self) -> None:
        """The episode ended, with no new one to come: let every reader have everything, and stop."""


class SimGame:
    """One served game (module docstring). ``seed``: the first episode's (None: drawn)."""

    def __init__(self, session: Any, gate: ActionGate, outlet: Outlet, scenario: str, mode: str, seed: int | None,
                 localization: bool, auto_reset: bool, exit_when_finished: bool) -> None:
        self.session, self.gate, self.outlet = session, gate, outlet
        self.scenario, self.mode, self.seed = scenario, mode, seed
        self.names = gate.names
        self.config = session.config
        self.localization, self.auto_reset, self.exit_when_finished = localization, auto_reset, exit_when_finished
        self.tick_seconds = self.config.rates.tick_seconds
        self.started = False
        self.frames_published = self.periods_run = self.episodes_started = 0
        self.tick_offset = 0
        self.episode_scores: list[tuple[int, int]] = []
        self.first_period_wall = self.last_period_wall = 0.0
        self.started_wall = time.monotonic()
        self._window: deque[tuple[float, float, int]] = deque(maxlen=2)   # (wall, sim, frames) for achieved rates
        self._buffer: deque[tuple[PeriodOutput, int, Poses | None]] = deque()   # real time: frames awaiting their turn

    def absolute_tick(self, tick: int) -> int:
        """The sim-time tick (across episodes) of an episode's ``tick``."""
        return self.tick_offset + tick

    def now_tick(self) -> int:
        """The sim-time tick of the world now."""
        return self.tick_offset + self.session.world.tick

    # -- episodes ----------------------------------------------------------------------------------------------
    def start(self, seed: int | None, kickoff: int = 1) -> None:
        self.started = True
        self.started_wall = time.monotonic()
        self.reset(seed, kickoff)

    def reset(self, seed: int | None, kickoff: int) -> None:
        """A new episode; its first observation (period 0) goes out. One vision period separates episodes."""
        if self.episodes_started:
            self.tick_offset += self.session.world.tick + self.config.rates.vision_period_ticks
        self.session.new_episode(seed, kickoff)
        self.episodes_started += 1
        self.outlet.episode_started(self.session.episode_id, self.now_tick())
        self._buffer.clear()
        self.gate.clear()
        self._emit(self.session.initial())

    def reset_request(self, options_yaml: str, use_seed: bool, seed: int) -> tuple[bool, str]:
        """/sim/reset: (True, what started) or (False, why refused). A reset starts a game still waiting."""
        try:
            kickoff, chosen = self._reset_options(options_yaml), checked_seed(int(seed)) if use_seed else None
        except (ValueError, yaml.YAMLError) as error:
            return False, f"reset refused: {error}"
        if self.started:
            self.reset(chosen, kickoff)
        else:
            self.start(chosen, kickoff)
        return True, f"episode {self.session.episode_id} started"

    def _reset_options(self, options_yaml: str) -> int:
        """The kickoff team ``options_yaml`` asks for (team A when it does not say)."""
        if len(options_yaml) > MAX_OPTIONS_CHARS:
            raise ValueError(f"options_yaml is {len(options_yaml)} characters; at most {MAX_OPTIONS_CHARS}")
        try:
            options = yaml.safe_load(options_yaml) if options_yaml.strip() else {}
        except RecursionError:              # "[[[[…" parses recursively: deep nesting exhausts the stack
            raise ValueError("options_yaml is nested too deeply") from None
        if not isinstance(options, dict):
            raise ValueError(f"options_yaml must be a mapping such as {{kickoff_team: b}}, got "
                             f"{type(options).__name__}")
        known = self.session.reset_options
        unknown = sorted(set(options) - set(known), key=repr)
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; known: {list(known)}")
        return kickoff_team(options.get("kickoff_team", "a"))

    # -- periods -----------------------------------------------------------------------------------------------
    def admit(self, robot: int, msg: Any) -> None:
        """An action that passed the gate's screen; in stepped mode the period runs once every robot has acted."""
        if self.gate.admit(robot, msg) and self.mode == "stepped" and self.session.ready():
            self.run_period()

    def step_request(self, ticks: int) -> tuple[bool, str]:
        """/sim/step: run ``ticks`` (a multiple of the motion period; 0: one period) in stepped mode."""
        period_ticks = self.config.rates.motion_period_ticks
        if not self.started:
            return False, "not started yet: waiting for subscribers (wait_for_subscribers & co.)"
        if self.mode != "stepped":
            return False, "/sim/step works in stepped mode only"
        if ticks % period_ticks:
            return False, f"ticks must be a multiple of the motion period ({period_ticks}), or 0 for one period"
        if ticks // period_ticks > MAX_STEP_PERIODS:
            return False, (f"ticks {ticks} is {ticks // period_ticks} periods; one call runs at most "
                           f"{MAX_STEP_PERIODS} ({MAX_STEP_PERIODS * period_ticks} ticks): call again for more")
        for _ in range(max(1, ticks // period_ticks)):
            if self.session.finished and not self.auto_reset:
                break
            self.run_period()
        if self.session.finished and not self.auto_reset:
            return False, "the episode has finished; call /sim/reset"
        return True, "stepped"

    def run_period(self) -> None:
        """Run the period being collected (robots without an action follow the missing-action rule), or start the
        next episode if this one has finished and ``auto_reset`` is on."""
        if not self.started:
            return
        if self.session.finished:
            if self.auto_reset:
                self.reset(None, 1)
            return
        executed = self.gate.period_runs()
        output = self.session.step()
        self.gate.period_ran(output.episode_id, output.motion_period, executed)
        self.periods_run += 1
        self.outlet.period_ran(output)
        now = time.monotonic()
        self.first_period_wall = self.first_period_wall or now
        self.last_period_wall = now
        self._emit(output)
        logged = getattr(self.session, "logged_events", ("goal", "penalty"))
        for event in output.events:
            if event.kind in logged:
                who = self.names[event.robot] if event.robot is not None else f"team {'A' if event.team > 0 else 'B'}"
                self.outlet.announce(f"{event.kind}: {who} {event.detail}", self.now_tick())

    def realtime_tick(self) -> None:
        """Real time, once per vision period: the next frame (and after a period's last, its feedback)."""
        if not self._buffer:
            self.run_period()
        if self._buffer:
            output, k, poses = self._buffer.popleft()
            self._frame(output, k, poses)
            if k == len(output.frames) - 1:
                self._feedback(output)

    def _emit(self, output: PeriodOutput) -> None:
        """Stepped mode: every frame of the period now, then the feedback; real time: the frames wait for their
        instants. The period's pose estimates go with them (the session's arrays are new ones every period)."""
        localization = self.session.vision.localization if self.localization else None
        poses = None if localization is None else (localization.estimates, localization.variances)
        if self.mode == "realtime":
            self._buffer.extend((output, k, poses) for k in range(len(output.frames)))
            return
        for k in range(len(output.frames)):
            self._frame(output, k, poses)
        self._feedback(output)

    def _frame(self, output: PeriodOutput, k: int, poses: Poses | None) -> None:
        self.outlet.frame(output, k, poses, self.absolute_tick(output.frames[k].tick))
        self.frames_published += 1

    def _feedback(self, output: PeriodOutput) -> None:
        self.outlet.feedback(output, self.gate.digests(output.episode_id, output.motion_period),
                             self.absolute_tick(output.frames[-1].tick))
        if output.terminated or output.truncated:
            score = self.session.episode_score()
            if score is not None:
                self.episode_scores.append(score)
            if self.auto_reset and self.mode == "stepped":
                self.reset(None, 1)
            elif not self.auto_reset and self.exit_when_finished:
                self.outlet.finish()

    # -- what it did -------------------------------------------------------------------------------------------
    def diagnostics(self, switches: Mapping[str, bool], recorder_error: str = "") -> dict[str, str]:
        """Achieved rates over the last diagnostics window and action counts, as strings (DiagnosticStatus);
        ``switches``: what is on or off (authentication, ...), listed after the rates."""
        now = time.monotonic()
        sim_now = self.session.world.tick * self.tick_seconds
        self._window.append((now, sim_now, self.frames_published))
        (t0, s0, f0), (t1, s1, f1) = self._window[0], self._window[-1]
        wall = max(t1 - t0, 1e-9)
        overall = self.periods_run * self.config.period_seconds / max(now - self.started_wall, 1e-9)
        # From the first period to the last: the loop itself, without start-up and discovery.
        running = (self.periods_run - 1) * self.config.period_seconds / max(
            self.last_period_wall - self.first_period_wall, 1e-9) if self.periods_run > 1 else 0.0
        values = {"mode": self.mode, "episode": str(self.session.episode_id), "period": str(self.session.period),
                  "real_time_factor_since_start": f"{overall:.2f}",
                  "real_time_factor_running": f"{running:.2f}",
                  "sim_time_s": f"{sim_now:.2f}", "real_time_factor": f"{(s1 - s0) / wall:.2f}",
                  "vision_frames_per_s": f"{(f1 - f0) / wall:.1f}", "periods_run": str(self.periods_run)}
        values.update((key, "on" if on else "off") for key, on in switches.items())
        values.update((key, str(self.session.counts.get(key, 0))) for key in COUNTED)
        if recorder_error:
            values["recorder_error"] = recorder_error
        return values

    def report(self, diagnostics: dict[str, str]) -> dict[str, Any]:
        """The JSON summary a node writes on exit (``report_path``)."""
        report: dict[str, Any] = {
            "diagnostics": diagnostics, "episode_scores": self.episode_scores,
            "published": {"world_state": self.frames_published, "detections_per_robot": self.frames_published,
                          "feedback_per_robot": self.periods_run + self.episodes_started,
                          "pose_estimates_per_robot": self.frames_published if self.localization else 0},
            # what a lossless recorder must hold on each /<robot>/action (the main job checks it)
            "accepted_actions": {n: self.session.accepted_per_robot[i] for i, n in enumerate(self.names)},
            "robots": self.names, "scenario": self.scenario}
        report.update(self.session.report_extra())
        return report

    def write_report(self, path: str, diagnostics: dict[str, str]) -> None:
        with open(path, "w") as handle:
            json.dump(self.report(diagnostics), handle, indent=2)


__all__ = ["SimGame", "Outlet", "MODES_OF_RUNNING", "SCENARIOS",
           "MAX_STEP_PERIODS", "MAX_OPTIONS_CHARS", "COUNTED"]
