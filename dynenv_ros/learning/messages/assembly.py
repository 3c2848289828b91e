"""Experience from messages: each robot's (or car's) detections, actions, step feedback and (for the self-supervised
losses) ground truth, assembled into fixed-length sequences the learner's ``update`` takes — with no ROS import
(messages are read by attribute: rclpy's, rosbags' and plain objects alike). The trainer node feeds it from live
topics, ``dynenv-train --from-bag`` from recorded bags. What differs between soccer and driving (agent names, the
padded layout, how an Action becomes the learnt action and the previous action shown, per-agent episode ends) is the
scenario's (``learning.messages.scenarios``); everything below holds for both.

The alignment (docs/ros_graph.md, "Training over ROS"). Per stream — one robot of one game (``source``, e.g. the
game's namespace) — an *observation slot* (episode e, period p) gathers:

- the frames of period p (``DetectionArray.motion_period == p``, frame indices 0..F-1): the observation;
- the *answer*: the robot's ``Action`` addressed to period p + 1, with the behaviour policy's log-probability,
  value and version (Action's learning fields);
- the feedback of period p (``StepFeedback.motion_period == p``): the reward of running period p (the reward of
  the *previous* slot's answer), terminated/truncated, and what the robot truly saw during p (the seen targets);
- ground truth at the last frame of p (``WorldState`` with that frame's stamp), for the localization and
  reconstruction targets.

Step t of a sequence is slot (e, p): observation p, its answer, and the feedback of period p + 1 (reward, episode
end). After an episode's end the next slot is the robot's next episode's period 0 (``starts``), as in the in-process
rollouts (``learning.sampling.collector``); a truncated episode is bootstrapped with the value the policy gave the episode's
final observation (the answer it sent to it, which the simulator ignores) or, when it sent none (a stepped policy
node that already sees the next episode skips it), with the value of the last observation acted on
(``bootstrap_estimated``). A sequence of T steps needs T + 1 slots:
the last one is the next sequence's first (they overlap by one observation, like rollouts).

Per-agent ends (driving): a car's feedback says ``terminated`` from the period it crashed or got home (with its
team's bonus decided) until its game's episode ends, while the simulator keeps publishing its frames and the policy
keeps answering. As in the in-process rollouts (``Rollout.alive``), those periods are no experience: the stream's
episode ends at the first terminated feedback, its later periods' messages are dropped (``after_end``), and the
stream goes on with the game's next episode. So that such a period never starts a chain (a stream that starts, or
restarts after a cut, mid-episode), a chain's first slot after period 0 waits for its own feedback.

Everything that can go wrong with messages is counted, never raised: ``late`` (for a slot already passed),
``duplicate`` (a second frame index, answer or feedback for a slot, the same again: the first wins), ``out_of_order`` (arrived after a
newer slot's messages; still used), ``malformed`` (fields out of range, non-finite learning fields),
``actions_rounded`` (a learnt action the learner's action space holds only approximately — a head turn between the
discrete head's steps, a driving command that is not one of the nine discrete ones — taken to the nearest),
``out_of_range`` (learning fields or rewards beyond the bounds ``LOG_PROB_MIN``, ``VALUE_BOUND``,
``REWARD_BOUND``: refused), ``beyond_horizon`` (an answer or feedback more than ``horizon`` periods ahead of the
stream's frames: refused, so forged far-future messages cannot fill the bounded slots), the answer resolution's
counters (below), ``not_learning`` (an answer without learning fields: a scripted or foreign policy — its steps
cannot be corrected off-policy), and ``missing``: a slot that never completes (a lost message, a killed node) once
the stream has moved ``patience`` periods past it. A missing slot *cuts* the sequence: the steps gathered since the
last emitted sequence are discarded (``steps_discarded``) and the stream restarts at its next complete slot as if
an episode started there (recurrent state zeroed: the learner cannot know the state the policy had).

Which answer is learnt (issue 27): a slot keeps up to ``MAX_CANDIDATES`` distinct answers (by digest; a byte-equal
copy is a ``duplicate``, one more is refused as ``candidates_full``), and the step is the answer the simulator ran:
the one whose digest (``security.action_auth.action_digest``, bound to the action topic) the next period's
feedback names in ``StepFeedback.action_digest``. A second, different answer is counted ``rival_answers`` and
``rivals_resolved`` once the feedback picked one; a feedback that names an answer the trainer never got cuts the
sequence once the stream moved ``patience`` periods on (``unmatched_action``); an empty digest from a simulator that
names actions (the stream has seen a digest) means the robot acted by default — the answer did not run, so the slot
is no step (``not_executed``). Feedback without digests (a simulator or bag from before issue 27) keeps the older
rule, whose counters are ``early_replaced`` and ``contested`` (``_rival``): an answer that arrived before its
period's frames gives way to one that came after them; two that cannot be told apart make the slot no step.

With ``secrets`` (``security.action_auth.GameSecrets``) an Action must carry its team's MAC and a StepFeedback the
simulator's, else it is refused before anything else is read: ``action_mac_missing``, ``action_mac_invalid``,
``feedback_mac_missing``, ``feedback_mac_invalid``.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from dynenv_ros.envs.detection_messages import frame_problem, pack_messages
from dynenv_ros.envs.learning_targets import LearningTargets, empty_targets
from dynenv_ros.learning.messages.scenarios import ExperienceScenario
from dynenv_ros.learning.algo.experience import STEP_ARRAYS, StepArrays
from dynenv_ros.security.action_auth import GameSecrets, action_digest, check_action, check_feedback

STATUS_FALLEN = 1                 # ObjectState.STATUS_FALLEN
KEPT_ENDS = 8                     # per stream: the last episodes whose per-agent end is remembered
# Bounds on what a message may teach (docs/training.md, "What the trainer refuses"). Outside them the message is
# refused and counted ``out_of_range``; a NaN or infinity is ``malformed``.
LOG_PROB_MIN = -50.0              # Action.log_prob of a discrete action in [LOG_PROB_MIN, 0]; a density's |.| <= 50
VALUE_BOUND = 1e4                 # |Action.value| (discounted return, reward units)
REWARD_BOUND = 1e4                # |each StepFeedback reward term| per period
MAX_CANDIDATES = 4                # distinct answers kept per slot until the feedback names the one that ran
HORIZON = 8                       # periods an answer or feedback may be ahead of the stream's newest frame
# The refusals a trainer reports (counted, and summarised in its log once per diagnostics period).
REFUSALS = ("malformed", "out_of_range", "beyond_horizon", "candidates_full", "unknown_robot", "action_mac_missing",
            "action_mac_invalid", "feedback_mac_missing", "feedback_mac_invalid")
ANSWER_FIELDS = ("walk", "turn", "kick", "head_yaw_delta", "throttle", "brake", "steering", "policy_version",
                 "log_prob", "value")


def answer_content(msg: Any) -> tuple:
    """What makes two Actions for one slot the same answer (a re-delivered one) or rivals (one of them forged)."""
    return tuple(getattr(msg, name, None) for name in ANSWER_FIELDS)


def version(action: Any) -> int:
    """Action.policy_version; 0 for an Action recorded before the learning fields existed."""
    return int(getattr(action, "policy_version", 0))


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


@dataclass
class Slot:
    """What one observation slot (episode, period) of one stream has received."""
    frames: dict[int, Any] = field(default_factory=dict)
    frames_per_period: int = 0
    answer: Any = None            # the answer learnt: the one the feedback named (or, without digests, _rival's)
    answers: list[tuple[bytes, Any]] = field(default_factory=list)   # distinct candidates (digest, Action)
    feedback: Any = None
    answer_early: bool = False    # the answer arrived before this period's frames were all here
    contested: bool = False       # two different answers that cannot be told apart: the slot is no step
    resolved: bool = False        # the next period's feedback named one of the answers

    @property
    def observed(self) -> bool:
        return self.frames_per_period > 0 and len(self.frames) == self.frames_per_period

    @property
    def last_stamp(self) -> int | None:
        last = self.frames.get(self.frames_per_period - 1)
        return None if last is None else stamp_ns(last.header)


@dataclass(eq=False)
class Sequence(StepArrays):
    """T steps of one stream, in the arrays of ``learning.algo.experience.Rollout`` for one robot (no robot axis):
    obs (T+1, ...), actions (T, width) as the scenario stores them (soccer (T, 4) int64, the head as its discrete
    index; driving (T, 2) int64 or (T, 3) float32), log_probs (T,), values (T+1,), rewards (T,),
    reward_terms (T, 4), episode_end, truncated, final_values (T,), starts, can_act (T+1,), targets (T+1, ...) or
    empty, versions (T,) int64 (Action.policy_version of each step), ``continues``: it follows the stream's previous
    sequence without a cut (the learner carries that sequence's final recurrent state into it)."""
    stream: tuple[str, str]
    targets: dict[str, np.ndarray]
    versions: np.ndarray
    continues: bool
    index: int                    # 0, 1, 2 … per stream: the learner processes a stream's sequences in order
    keys: list[tuple[int, int]]   # (episode, period) of each of the T + 1 observations


@dataclass
class _Stream:
    slots: dict[tuple[int, int], Slot] = field(default_factory=dict)
    cursor: tuple[int, int] | None = None       # the oldest slot not yet part of an emitted sequence's steps
    chain: list[tuple[int, int]] = field(default_factory=list)   # slots of the sequence being gathered
    chain_starts_episode: bool = True           # the chain's first slot starts an episode (or follows a cut)
    continues: bool = False                     # the chain follows an emitted sequence without a cut
    newest: tuple[int, int] = (-1, -1)
    emitted: int = 0
    restart_after: tuple[int, int] | None = None   # after a cut: restart at the first observed slot after this
    ends: dict[int, int] = field(default_factory=dict)   # episode -> the first period its feedback ended (driving)
    frames_newest: tuple[int, int] | None = None   # the newest slot with a frame (the horizon is counted from it)
    digests_seen: bool = False                  # its simulator names the actions it ran (StepFeedback.action_digest)


class ExperienceAssembler:
    """Sequences of ``steps`` periods from the messages of any number of streams. ``scenario`` (e.g.
    ``SoccerExperience(players_per_team, frames, head_max, head_units)`` or ``DrivingExperience(config)``, module
    ``learning.messages.scenarios``) names the agents, fixes the observation layout and converts actions;
    ``with_targets`` builds the self-supervised targets from ground truth (soccer). ``learns(robot_name)`` picks
    which agents' experience is kept (all by default). ``secrets``: authenticated actions and feedback required
    (module docstring); ``horizon``: periods an answer or feedback may run ahead of its stream's frames."""

    def __init__(self, steps: int, scenario: ExperienceScenario, with_targets: bool = False, patience: int = 8,
                 learns=None, max_slots: int = 256, require_learning_fields: bool = True,
                 secrets: GameSecrets | None = None, horizon: int = HORIZON) -> None:
        if steps < 1:
            raise ValueError(f"steps must be >= 1, got {steps}")
        if with_targets and not scenario.supports_targets:
            raise ValueError(f"scenario {scenario.scenario!r} has no self-supervised targets (with_targets=False)")
        self.steps, self.scenario, self.frames = steps, scenario, scenario.frames
        self.layout = scenario.layout
        self.with_targets, self.patience, self.max_slots = with_targets, patience, max_slots
        self.learns = learns or (lambda name: True)
        # False: every answer is a step, whoever chose it (behaviour cloning from bags; an Action recorded before
        # the learning fields existed reads as version 0)
        self.require_learning_fields = require_learning_fields
        self.secrets, self.horizon = secrets, horizon
        self.streams: dict[tuple[str, str], _Stream] = {}
        self.truth: dict[str, dict[tuple[int, int], Any]] = {}     # source -> (episode, stamp ns) -> WorldState
        self.names = list(scenario.names)
        if with_targets:
            self.players = scenario.players
            self.targets = LearningTargets(scenario.players)
        self.counts: Counter[str] = Counter()
        self.ready: list[Sequence] = []
        self._known: dict[tuple[str, str], tuple] = {}     # per stream: seen-since-episode-start, carried over
        self.last_missing = ""          # the last step given up as missing, and what it lacked
        self.last_refused = ""          # the last message refused as out of range, and why

    # -- messages in ------------------------------------------------------------------------------------------
    def _stream(self, source: str, robot: str) -> _Stream | None:
        if robot not in self.names:
            self.counts["unknown_robot"] += 1
            return None
        if not self.learns(robot):
            return None
        return self.streams.setdefault((source, robot), _Stream())

    @staticmethod
    def topic(source: str, robot: str, kind: str) -> str:
        """The topic a robot's ``kind`` (action, feedback) is published on, which MACs and digests are bound to:
        ``<source>/<robot>/<kind>``; a source may carry a prefix up to ':' that keeps games apart (``dynenv-train
        --from-bag``'s bag index), not part of the topic."""
        return f"{source.rpartition(':')[2]}/{robot}/{kind}"

    def _refuse(self, count: str, why: str) -> None:
        self.counts[count] += 1
        self.last_refused = why

    def _beyond_horizon(self, stream: _Stream, key: tuple[int, int]) -> bool:
        """``key`` lies more than ``horizon`` periods ahead of the stream's newest frame (the next episode's first
        periods count from 0); nothing is ahead before the first frame."""
        front = stream.frames_newest
        if front is None or key <= front:
            return False
        if key[0] == front[0]:
            return key[1] > front[1] + self.horizon
        return key[0] > front[0] + 1 or key[1] > self.horizon

    def _slot(self, stream: _Stream, key: tuple[int, int]) -> Slot | None:
        """The slot for ``key``, or None when the stream has passed it (counted late) or the agent's episode ended
        before it (``after_end``)."""
        end = stream.ends.get(key[0])
        if end is not None and key[1] > end:
            self.counts["after_end"] += 1
            return None
        if stream.cursor is not None and key < stream.cursor:
            self.counts["late"] += 1
            return None
        if key < stream.newest:
            self.counts["out_of_order"] += 1
        stream.newest = max(stream.newest, key)
        slot = stream.slots.get(key)
        if slot is None:
            slot = stream.slots[key] = Slot()
            if len(stream.slots) > self.max_slots:          # bounded: the oldest goes (counted missing)
                oldest = min(stream.slots)
                del stream.slots[oldest]
                self.counts["missing"] += 1
        return slot

    def add_frame(self, source: str, robot: str, msg: Any) -> None:
        stream = self._stream(source, robot)
        if stream is None:
            return
        if frame_problem(msg) or msg.robot_id != self.names.index(robot) or msg.frames_per_period != self.frames:
            self.counts["malformed"] += 1
            return
        key = (int(msg.episode_id), int(msg.motion_period))
        stream.frames_newest = key if stream.frames_newest is None else max(stream.frames_newest, key)
        slot = self._slot(stream, key)
        if slot is None:
            return
        if slot.frames_per_period and msg.frame_index in slot.frames:
            self.counts["duplicate"] += 1
            return
        slot.frames_per_period = int(msg.frames_per_period)
        slot.frames[int(msg.frame_index)] = msg
        self._advance(source, robot, stream)

    def add_action(self, source: str, robot: str, msg: Any) -> None:
        stream = self._stream(source, robot)
        if stream is None:
            return
        topic = self.topic(source, robot, "action")
        if self.secrets is not None:
            problem = check_action(msg, topic, self.secrets.for_agent(robot))
            if problem:
                self._refuse(f"action_{problem}", f"{source or '/'} {robot} action for period {msg.motion_period}: "
                                                  f"{problem}")
                return
        if msg.motion_period == 0 or msg.robot_id != self.names.index(robot) or self._action_problem(msg):
            self.counts["malformed"] += 1
            return
        problem = self._range_problem(msg)
        if problem:
            self.counts["out_of_range"] += 1
            self.last_refused = f"{source or '/'} {robot} action for period {msg.motion_period}: {problem}"
            return
        try:
            digest = action_digest(msg, topic)
        except ValueError:                  # a value no Action can hold (a plain object's, never rclpy's)
            self.counts["malformed"] += 1
            return
        self._file(source, robot, stream, (int(msg.episode_id), int(msg.motion_period) - 1), "answer", msg, digest)

    def add_feedback(self, source: str, robot: str, msg: Any) -> None:
        stream = self._stream(source, robot)
        if stream is None:
            return
        if self.secrets is not None:
            problem = check_feedback(msg, self.topic(source, robot, "feedback"), self.secrets.simulator)
            if problem:
                self._refuse(f"feedback_{problem}", f"{source or '/'} {robot} feedback of period "
                                                    f"{msg.motion_period}: {problem}")
                return
        terms = (msg.reward_primary, msg.reward_rule, msg.reward_auxiliary, msg.reward_observation)
        if msg.robot_id != self.names.index(robot) or not all(math.isfinite(v) for v in terms):
            self.counts["malformed"] += 1
            return
        if any(abs(v) > REWARD_BOUND for v in terms):
            self.counts["out_of_range"] += 1
            self.last_refused = (f"{source or '/'} {robot} feedback of period {msg.motion_period}: a reward term "
                                 f"beyond ±{REWARD_BOUND:g}")
            return
        self._file(source, robot, stream, (int(msg.episode_id), int(msg.motion_period)), "feedback", msg)

    def _file(self, source: str, robot: str, stream: _Stream, key: tuple[int, int], field_name: str,
              msg: Any, digest: bytes = b"") -> None:
        """An answer into its slot's candidates (``digest``: its action digest), or the feedback into its slot (the
        first one wins; a second is a duplicate)."""
        if self._beyond_horizon(stream, key):
            what = f"action for period {key[1] + 1}" if field_name == "answer" else f"feedback of period {key[1]}"
            self._refuse("beyond_horizon", f"{source or '/'} {robot} {what} of episode {key[0]}: more than "
                                           f"{self.horizon} periods ahead of its frames")
            return
        slot = self._slot(stream, key)
        if slot is None:
            return
        if field_name == "answer":
            if any(known == digest for known, _ in slot.answers):
                self.counts["duplicate"] += 1
                return
            if len(slot.answers) >= MAX_CANDIDATES:
                self._refuse("candidates_full", f"{source or '/'} {robot} action for period {key[1] + 1}: "
                                                f"{MAX_CANDIDATES} different answers are waiting already")
                return
            slot.answers.append((digest, msg))
            if len(slot.answers) > 1:
                if stream.digests_seen:         # the feedback will say which one ran
                    self.counts["rival_answers"] += 1
                else:
                    self._rival(slot, msg)
                self._advance(source, robot, stream)
                return
        elif getattr(slot, field_name) is not None:
            self.counts["duplicate"] += 1
            return
        setattr(slot, field_name, msg)
        if field_name == "answer":
            slot.answer_early = not slot.observed
        if field_name == "feedback" and len(getattr(msg, "action_digest", ())):
            stream.digests_seen = True
        if field_name == "feedback" and self.scenario.per_agent_ends and (msg.terminated or msg.truncated):
            self._end_episode(stream, key)
        self._advance(source, robot, stream)

    def _rival(self, slot: Slot, msg: Any) -> None:
        """While the stream's feedback has named no action (module docstring): a second answer for a slot, the
        rule feedback without a digest falls back on. The same content: a duplicate. A different one: the simulator
        accepts an answer only once its period's frames are out (an earlier one is refused as ``early``), so an
        answer that came before the frames gives way to one that came after them (``early_replaced``); two that
        cannot be told apart make the slot no step (``contested``: the step is cut, never learnt from a guess).
        Every different one is a ``rival_answers``."""
        if answer_content(msg) == answer_content(slot.answer):
            self.counts["duplicate"] += 1
            return
        self.counts["rival_answers"] += 1
        if slot.answer_early and slot.observed and not slot.contested:
            slot.answer, slot.answer_early = msg, False
            self.counts["early_replaced"] += 1
        else:
            slot.contested = True
            self.counts["contested"] += 1

    def _range_problem(self, msg: Any) -> str:
        """Why an Action's learning fields are outside the documented bounds ("" when inside)."""
        if not version(msg):
            return ""
        if abs(msg.log_prob) > -LOG_PROB_MIN:
            return f"|log_prob| {abs(msg.log_prob):g} beyond {-LOG_PROB_MIN:g}"
        if abs(msg.value) > VALUE_BOUND:
            return f"value {msg.value:g} beyond ±{VALUE_BOUND:g}"
        return ""

    def _end_episode(self, stream: _Stream, key: tuple[int, int]) -> None:
        """The agent's episode ended at period ``key[1]`` (per-agent ends): its later periods are no experience —
        their slots go (their messages counted ``after_end``), and a chain that would start in them restarts with
        the next episode."""
        episode, period = key
        if stream.ends.get(episode, period + 1) <= period:
            return
        stream.ends[episode] = period
        while len(stream.ends) > KEPT_ENDS:
            del stream.ends[min(stream.ends)]
        for k in [k for k in stream.slots if k[0] == episode and k[1] > period]:
            slot = stream.slots.pop(k)
            self.counts["after_end"] += len(slot.frames) + len(slot.answers) + (slot.feedback is not None)
        if not stream.chain and stream.cursor is not None and stream.cursor[0] == episode \
                and stream.cursor[1] > period:
            stream.restart_after = key

    def add_world_state(self, source: str, msg: Any) -> None:
        """Ground truth of one frame (kept only when targets are built, for ``patience`` periods' worth)."""
        if not self.with_targets:
            return
        store = self.truth.setdefault(source, {})
        store[(int(msg.episode_id), stamp_ns(msg.header))] = msg
        keep = 4 * self.patience * self.frames * max(1, 2 * self.players)
        while len(store) > keep:
            del store[next(iter(store))]

    def _action_problem(self, msg: Any) -> str:
        problem = self.scenario.action_problem(msg)
        if problem:
            return problem
        if not version(msg):                # recorded before the learning fields existed: none to check
            return ""
        at_most_zero = msg.log_prob <= 1e-4 or not self.scenario.probability_actions
        if not (math.isfinite(msg.log_prob) and at_most_zero and math.isfinite(msg.value)):
            return "learning fields not finite"
        return ""

    # -- sequences out ----------------------------------------------------------------------------------------
    @property
    def pending_steps(self) -> int:
        """Steps gathered but not yet in a whole sequence (at a bag's end: the steps it cannot use)."""
        pending = 0
        for stream in self.streams.values():
            key = stream.chain[-1] if stream.chain else stream.cursor
            waiting = key is not None and len(stream.chain) < self.steps and self._step_ready(stream, key) is True
            pending += len(stream.chain) + waiting       # + a step whose successor (a next episode) never came
        return pending

    def take(self) -> list[Sequence]:
        """The sequences completed since the last call, oldest first."""
        out, self.ready = self.ready, []
        return out

    def _next_key(self, stream: _Stream, key: tuple[int, int], ended: bool) -> tuple[int, int] | None:
        if not ended:
            return (key[0], key[1] + 1)
        later = [k for k in stream.slots if k[0] > key[0] and k[1] == 0]
        return min(later) if later else None

    def _step_ready(self, stream: _Stream, key: tuple[int, int]) -> bool | str:
        """True: slot ``key`` is a complete step; False: not yet; a counter name: it cannot be learnt from (cut,
        counted under that name)."""
        slot = stream.slots.get(key)
        if slot is None or not slot.observed or not slot.answers:
            return False
        state, answer = self._executed(stream, key)      # the next feedback decides, digest or not
        if state != "ok":
            return False if state == "wait" else answer
        if self.require_learning_fields and version(answer) == 0:
            return "not_learning"
        return True

    def _named(self, stream: _Stream, key: tuple[int, int]) -> tuple[Any, bytes]:
        """The feedback of period key + 1, which names the answer of slot ``key`` that ran, and that digest."""
        following = stream.slots.get((key[0], key[1] + 1))
        feedback = None if following is None else following.feedback
        return feedback, b"" if feedback is None else bytes(getattr(feedback, "action_digest", b""))

    def _executed(self, stream: _Stream, key: tuple[int, int]) -> tuple[str, Any]:
        """The answer of slot ``key`` that its period ran: ("ok", Action), ("wait", None) while that is not known
        yet (no feedback, or the named answer has not arrived), or ("cut", counter) when no answer is learnt."""
        slot = stream.slots.get(key)
        feedback, named = self._named(stream, key)
        if slot is None or not slot.answers or feedback is None:
            return "wait", None
        if named:
            for digest, answer in slot.answers:
                if digest == named:
                    if not slot.resolved:
                        slot.resolved = True
                        self.counts["rivals_resolved"] += len(slot.answers) > 1
                    slot.answer = answer
                    return "ok", answer
            return "wait", None
        if stream.digests_seen:                 # a simulator that names actions ran none of these
            return "cut", "not_executed"
        if slot.contested:
            return "cut", "contested_cuts"
        return "ok", slot.answer

    def _unmatched(self, stream: _Stream, key: tuple[int, int]) -> bool:
        """The feedback names an answer of slot ``key`` the stream never got."""
        slot = stream.slots.get(key)
        _, named = self._named(stream, key)
        return bool(named) and slot is not None and all(d != named for d, _ in slot.answers)

    def _bootstrap_answer(self, stream: _Stream, key: tuple[int, int]) -> Any:
        """The answer whose value is V of a sequence's last observation (slot ``key``), or None while unknown: the
        one that ran; without digests, the slot's answer as it stands; an answer that did not run (the robot acted
        by default) when it is the slot's only one — its value is still the policy's estimate."""
        slot = stream.slots.get(key)
        if slot is None or not slot.observed or not slot.answers:
            return None
        state, answer = self._executed(stream, key)
        if state == "ok":
            return answer
        if not stream.digests_seen:
            return slot.answer
        if state == "cut" and len(slot.answers) == 1:
            return slot.answer
        return None

    def _shown(self, stream: _Stream, key: tuple[int, int]) -> Any:
        """The answer of slot ``key`` as the previous action the next observation shows (the policy shows what it
        sent): the one that ran, else the slot's only answer (or, without digests, its uncontested one); None:
        unknown (idle is shown)."""
        state, answer = self._executed(stream, key)
        if state == "ok":
            return answer
        slot = stream.slots.get(key)
        if slot is None or not slot.answers:
            return None
        if len(slot.answers) == 1 or (not stream.digests_seen and not slot.contested):
            return slot.answer
        return None

    def _advance(self, source: str, robot: str, stream: _Stream) -> None:
        if stream.cursor is None:         # the stream starts at its first observed slot; answers and feedback of
            observed = [k for k, slot in stream.slots.items() if slot.observed]    # older ones (a writer's
            if not observed:                                                     # history) are not experience
                return
            stream.cursor = min(observed)
            for old in [k for k in stream.slots if k < (stream.cursor[0], stream.cursor[1] - 1)]:
                del stream.slots[old]
                self.counts["before_start"] += 1
        while True:
            if stream.restart_after is not None:
                after = [k for k, s in stream.slots.items() if k > stream.restart_after and s.observed]
                if not after:
                    return
                stream.cursor, stream.restart_after = min(after), None
            key = stream.chain[-1] if stream.chain else stream.cursor
            if not stream.chain and self._final(stream, key):   # an episode's final observation: not a step
                stream.restart_after = key
                continue
            if not stream.chain and self._awaits_own_feedback(stream, key):
                if not self._give_up(stream, key):
                    return
                self.counts["missing"] += 1
                self.last_missing = f"{source or '/'} {robot} episode {key[0]} period {key[1]}: its own feedback"
                self._cut(stream, key)
                continue
            if len(stream.chain) == self.steps:               # the chain has its T steps; key is slot T
                bootstrap = self._bootstrap_answer(stream, key)
                if bootstrap is not None:
                    self._emit(source, robot, stream, bootstrap)
                    continue
                if not self._give_up(stream, key):
                    return
                self.counts["unmatched_action"] += self._unmatched(stream, key)
                self._cut(stream, key)
                continue
            ready = self._step_ready(stream, key)
            if ready is True:
                ended = self._ended(stream, key)
                following = self._next_key(stream, key, ended)
                if following is None:                          # the next episode has not begun yet
                    if not self._give_up(stream, key):
                        return
                    self._cut(stream, key)
                    continue
                stream.chain.append(following)
                continue
            if ready is not False:                             # a counter: no step can be learnt here
                self.counts[ready] += 1
                self._cut(stream, key)
                continue
            if not self._give_up(stream, key):
                return
            self.counts["unmatched_action" if self._unmatched(stream, key) else "missing"] += 1
            self.last_missing = f"{source or '/'} {robot} episode {key[0]} period {key[1]}: {self._lacks(stream, key)}"
            self._cut(stream, key)

    def _awaits_own_feedback(self, stream: _Stream, key: tuple[int, int]) -> bool:
        """Per-agent ends: a chain's first slot after period 0 is a step only once its own feedback says the agent's
        episode goes on (module docstring)."""
        if not self.scenario.per_agent_ends or key[1] == 0:
            return False
        slot = stream.slots.get(key)
        return slot is None or slot.feedback is None

    def _lacks(self, stream: _Stream, key: tuple[int, int]) -> str:
        """What a step still lacks (diagnostics: ``last_missing``)."""
        slot = stream.slots.get(key, Slot())
        following = stream.slots.get((key[0], key[1] + 1))
        lacking = [f"frames {sorted(slot.frames)}" if not slot.observed else "",
                   "answer" if not slot.answers else "",
                   "the answer its feedback names" if self._unmatched(stream, key) else "",
                   "next period's feedback" if following is None or following.feedback is None else ""]
        return ", ".join(x for x in lacking if x)

    def _final(self, stream: _Stream, key: tuple[int, int]) -> bool:
        slot = stream.slots.get(key)
        return slot is not None and slot.feedback is not None and bool(slot.feedback.terminated
                                                                       or slot.feedback.truncated)

    def _ended(self, stream: _Stream, key: tuple[int, int]) -> bool:
        feedback = stream.slots[(key[0], key[1] + 1)].feedback
        return bool(feedback.terminated or feedback.truncated)

    def _give_up(self, stream: _Stream, key: tuple[int, int]) -> bool:
        """The stream has moved ``patience`` periods past ``key``: that many later slots have messages (counted
        across episode boundaries, however short the episodes)."""
        return sum(1 for k in stream.slots if k > key) > self.patience

    def _cut(self, stream: _Stream, key: tuple[int, int]) -> None:
        """Drop the chain gathered so far and restart at the first slot after ``key`` that has its frames."""
        self.counts["steps_discarded"] += len(stream.chain)
        self.counts["cuts"] += 1
        for old in [k for k in stream.slots if k < (key[0], key[1] - 1)]:
            del stream.slots[old]
        stream.chain, stream.restart_after = [], key
        stream.chain_starts_episode, stream.continues = True, False

    def _emit(self, source: str, robot: str, stream: _Stream, bootstrap: Any) -> None:
        """The chain's sequence; ``bootstrap``: slot T's answer (``_bootstrap_answer``), whose value is V(s_T)."""
        keys = [stream.cursor] + stream.chain            # T + 1 observation slots
        slots = [stream.slots[k] for k in keys]
        T = self.steps
        previous, starts = [], np.zeros(T + 1, bool)
        for t, key in enumerate(keys):
            if key[1] == 0 or (t == 0 and stream.chain_starts_episode):
                starts[t] = True
            answer = self._shown(stream, (key[0], key[1] - 1)) if key[1] > 0 else None
            previous.append(self.scenario.idle if answer is None else self.scenario.previous_row(answer))
        periods = [[s.frames[k] for k in range(s.frames_per_period)] for s in slots]
        stats: Counter[str] = Counter()
        obs, dropped = pack_messages(periods, previous, self.layout.max_landmarks, self.layout.max_objects, stats,
                                     self.layout.spec)
        self.counts["detections_dropped"] += dropped
        self.counts.update(stats)
        kind = self.scenario
        actions = np.array([kind.action_row(s.answer) for s in slots[:T]], kind.action_dtype)
        self.counts["actions_rounded"] += sum(kind.off_grid(s.answer) for s in slots[:T])
        log_probs = np.array([getattr(s.answer, "log_prob", 0.0) for s in slots[:T]], np.float32)
        values = np.array([getattr(s.answer, "value", 0.0) for s in slots[:T]] + [getattr(bootstrap, "value", 0.0)],
                          np.float32)
        versions = np.array([version(s.answer) for s in slots[:T]], np.int64)
        feedback = [stream.slots[(k[0], k[1] + 1)].feedback for k in keys[:T]]
        terms = np.array([(f.reward_primary, f.reward_rule, f.reward_auxiliary, f.reward_observation)
                          for f in feedback], np.float32)
        episode_end = np.array([f.terminated or f.truncated for f in feedback], bool)
        truncated = np.array([f.truncated and not f.terminated for f in feedback], bool)
        final_values = np.zeros(T, np.float32)
        for t in np.flatnonzero(truncated):
            final = stream.slots.get((keys[t][0], keys[t][1] + 1))     # never runs: no feedback names its answer
            sure = final is not None and (len(final.answers) == 1 or (not stream.digests_seen and final.answers
                                                                      and not final.contested))
            if sure and version(final.answer):
                final_values[t] = final.answer.value
            else:       # a stepped policy node often skips the final observation (the next episode is already
                final_values[t] = values[t]     # there): V(s) of the last step stands in, counted
                self.counts["bootstrap_estimated"] += 1
        targets = self._targets(source, robot, keys, slots) if self.with_targets else {}
        sequence = Sequence(obs=obs, actions=actions, log_probs=log_probs, values=values, rewards=terms.sum(-1),
                            reward_terms=terms, episode_end=episode_end, truncated=truncated,
                            final_values=final_values, starts=starts, can_act=kind.can_act(obs["proprioception"]),
                            stream=(source, robot), targets=targets, versions=versions, continues=stream.continues,
                            index=stream.emitted, keys=keys)
        self.ready.append(sequence)
        stream.emitted += 1
        self.counts["sequences"] += 1
        self.counts["steps"] += T
        # Slot T is the next sequence's slot 0; everything before it (and the final observations of episodes
        # that ended inside this sequence) is done.
        last = keys[-1]
        for old in [k for k in stream.slots if k < (last[0], last[1] - 1)]:     # keep slot T's previous action
            del stream.slots[old]
        stream.cursor, stream.chain = last, []
        stream.chain_starts_episode, stream.continues = bool(starts[-1]), True

    def _targets(self, source: str, robot: str, keys: list, slots: list[Slot]) -> dict[str, np.ndarray]:
        """The self-supervised targets of each observation (``envs.learning_targets``), from the ground truth at
        its last frame and what the robot truly saw during its period; unknown truth gives zeros (counted)."""
        n = 2 * self.players
        row = self.names.index(robot)
        out = empty_targets(self.players, len(keys))
        known = {"ball_known": np.zeros(len(keys), np.float32),
                 "robots_known": np.zeros((len(keys), n - 1), np.float32)}
        store = self.truth.get(source, {})
        for t, (key, slot) in enumerate(zip(keys, slots)):
            world = store.get((key[0], slot.last_stamp))
            if world is None or slot.feedback is None:
                self.counts["targets_missing"] += 1
                continue
            robots = {o.id: o for o in world.objects if o.id < n}
            ball = next((o for o in world.objects if o.id == n), None)
            if len(robots) != n or ball is None:
                self.counts["targets_missing"] += 1
                continue
            ordered = [robots[i] for i in range(n)]
            x = np.array([o.x for o in ordered] + [ball.x])
            y = np.array([o.y for o in ordered] + [ball.y])
            seen = np.zeros((n, n + 1), bool)
            ids = [i for i in slot.feedback.seen_object_ids if i <= n]
            seen[row, ids] = True
            owner = np.zeros(n)
            owner[row] = getattr(slot.frames[slot.frames_per_period - 1], "ball_owner", 0)
            one = self.targets.compute(x, y, np.array([o.yaw for o in ordered]),
                                       np.array([o.head_yaw for o in ordered]),
                                       np.array([bool(o.status & STATUS_FALLEN) for o in ordered]), owner, seen)
            for name, value in one.items():
                out[name][t] = value[row]
        # Seen at least once since the episode began (the in-process collector's memory), within this sequence
        # and carried over from the previous one of the stream.
        carried = self._known.get((source, robot))
        ball_known, robots_known = (carried if carried is not None
                                    else (np.float32(0), np.zeros(n - 1, np.float32)))
        starts_episode = [k[1] == 0 for k in keys]
        for t in range(len(keys)):
            if starts_episode[t]:
                ball_known, robots_known = np.float32(0), np.zeros(n - 1, np.float32)
            ball_known = max(ball_known, out["ball_seen"][t])
            robots_known = np.maximum(robots_known, out["robots_seen"][t])
            known["ball_known"][t], known["robots_known"][t] = ball_known, robots_known
        self._known[(source, robot)] = (known["ball_known"][-2], known["robots_known"][-2]) if len(keys) > 1 \
            else (ball_known, robots_known)
        out.update(known)
        return out


def batch(sequences: Iterable[Sequence]) -> dict[str, Any]:
    """Sequences of one length → ``Rollout``-shaped numpy arrays with a robot axis (T, B, ...), without the
    recurrent state (the learner adds it)."""
    sequences = list(sequences)
    out: dict[str, Any] = {"obs": {k: np.stack([s.obs[k] for s in sequences], 1) for k in sequences[0].obs}}
    for name in (*STEP_ARRAYS, "versions"):
        out[name] = np.stack([getattr(s, name) for s in sequences], 1)
    out["targets"] = ({k: np.stack([s.targets[k] for s in sequences], 1) for k in sequences[0].targets}
                      if sequences[0].targets else {})
    return out
