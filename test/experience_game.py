"""A short game played through ``SoccerSession`` (``play``) or ``DrivingSession`` (``play_driving``), no ROS graph,
with actions carrying learning fields, as the messages a trainer would receive — and the record of what was sent and
what the game answered, to check the experience assembled from those messages against."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from dynenv_msgs.msg import Action

from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.perception.params import load_preset
from dynenv_ros.ros.conversions import detection_array, sim_time, step_feedback, world_state
from dynenv_ros.soccer.config import SoccerConfig

HEAD_MAX = math.radians(37.5)      # the default head turn limit per period, 3 steps each way
HEAD_UNITS = 3


@dataclass
class Game:
    players: int
    frames: int
    messages: list[tuple[str, str, object]] = field(default_factory=list)   # (kind, robot, message)
    actions: dict[tuple[str, int, int], Action] = field(default_factory=dict)   # (robot, episode, addressed period)
    rewards: dict[tuple[str, int, int], float] = field(default_factory=dict)    # (robot, episode, period)
    ends: dict[tuple[int, int], tuple[bool, bool]] = field(default_factory=dict)  # (episode, period) → term., trunc.
    truth: dict[tuple[int, int], object] = field(default_factory=dict)          # (episode, period) → last WorldState


def play(episodes: int = 3, players: int = 1, seed: int = 0, episode_seconds: float = 3.0,
         version: int = 5) -> Game:
    config = SoccerConfig.from_mapping({"players_per_team": players, "episode_seconds": episode_seconds})
    session = SoccerSession(config, load_preset("realistic"), seed=seed)
    rng = np.random.default_rng(seed + 1)
    game = Game(players, config.rates.frames_per_period)
    names = config.robot_names

    def emit(output) -> None:
        for frame in output.frames:
            stamp = sim_time(frame.tick, frame.snapshot.tick_period)
            game.messages.append(("world", "", world_state(frame.snapshot, stamp)))
            for i, seen in enumerate(frame.robots):
                game.messages.append(("frame", names[i], detection_array(
                    seen.detections, robot_id=i, robot_name=names[i], episode_id=output.episode_id,
                    motion_period=output.motion_period, frame_index=frame.frame_index,
                    frames_per_period=len(output.frames), head_yaw=seen.head_yaw, fallen=seen.fallen,
                    penalized=seen.penalized, kicking=seen.kicking, ball_owner=seen.ball_owner,
                    ball_owner_seconds=seen.ball_owner_seconds, game_seconds_remaining=seen.game_seconds_remaining,
                    stamp=stamp)))
        game.truth[(output.episode_id, output.motion_period)] = game.messages[-1 - len(names)][2]
        end = sim_time(output.frames[-1].tick, 0.01)
        for i, feedback in enumerate(output.feedback):
            game.messages.append(("feedback", names[i], step_feedback(
                robot_id=i, episode_id=output.episode_id, motion_period=output.motion_period,
                rewards=feedback.rewards, terminated=output.terminated, truncated=output.truncated,
                seen_object_ids=feedback.seen_object_ids, landmarks_seen=feedback.landmarks_seen, stamp=end)))
            game.rewards[(names[i], output.episode_id, output.motion_period)] = sum(feedback.rewards.values())
        game.ends[(output.episode_id, output.motion_period)] = (output.terminated, output.truncated)

    def answer(episode: int, period: int, submit: bool) -> None:
        """Every robot's action for ``period`` with learning fields; submitted to the game unless it has ended."""
        for i, name in enumerate(names):
            head_index = int(rng.integers(0, 2 * HEAD_UNITS + 1))
            msg = Action(robot_id=i, episode_id=episode, motion_period=period, walk=int(rng.integers(0, 5)),
                         turn=int(rng.integers(0, 3)), kick=int(rng.integers(0, 3)),
                         head_yaw_delta=float((head_index - HEAD_UNITS) * HEAD_MAX / HEAD_UNITS),
                         policy_version=version, log_prob=float(-rng.uniform(0.5, 6.0)),
                         value=float(rng.normal()))
            game.actions[(name, episode, period)] = msg
            game.messages.append(("action", name, msg))
            if submit:
                ok, reason = session.submit(i, episode, period, msg.walk, msg.turn, msg.kick, msg.head_yaw_delta)
                assert ok, reason

    _play_episodes(session, emit, answer, (int(rng.integers(0, 2**31)) for _ in range(episodes)))
    return game


def _play_episodes(session, emit, answer, seeds) -> None:
    """One episode per world seed (drawn lazily, in turn with the answers' draws): every period's frames and
    feedback through ``emit``, the answers for the next period through ``answer``, and the ignored final answer."""
    for seed in seeds:
        session.reset(seed=seed)
        output = session.initial()
        emit(output)
        while True:
            answer(output.episode_id, output.motion_period + 1, submit=True)
            output = session.step()
            emit(output)
            if output.terminated or output.truncated:
                answer(output.episode_id, output.motion_period + 1, submit=False)    # the ignored final answer
                break


# -- driving ----------------------------------------------------------------------------------------------------------
W = 0.3490658503988659          # the default steering limit, rad/s (2° per 100 ms)
RECKLESS = (2, 0)               # car 0: full gas, steering right: off the road at period 20 with the seeds below
CRASH_SEEDS = (0, 2)            # world seeds where RECKLESS car 0 crashes at period 20 of 40


@dataclass
class DrivingGame:
    n_cars: int
    action_mode: str
    messages: list[tuple[str, str, object]] = field(default_factory=list)   # (kind, car, message)
    actions: dict[tuple[str, int, int], Action] = field(default_factory=dict)   # (car, episode, addressed period)
    chosen: dict[tuple[str, int, int], tuple] = field(default_factory=dict)     # the same key → the agent's action
    rewards: dict[tuple[str, int, int], float] = field(default_factory=dict)    # (car, episode, period)
    ends: dict[tuple[str, int, int], tuple[bool, bool]] = field(default_factory=dict)  # per car: term., trunc.
    seconds: dict[tuple[str, int, int], float] = field(default_factory=dict)    # game seconds remaining


def play_driving(action_mode: str = "discrete", episodes: int = 2, version: int = 3,
                 episode_seconds: float = 4.0) -> DrivingGame:
    """Two cars through ``DrivingSession``: car 0 drives off the road (its own episode ends at period 20, the game
    goes on to 40), car 1 at random until the time limit. Every action carries learning fields, including the
    answers to a finished car's periods (a policy node answers every car it sees) and to the final observation.
    ``chosen`` holds what the agent chose — discrete [acceleration, steering], continuous the normalised
    [throttle, brake, steering / limit] (some exactly on their bounds) — as the learner should store it."""
    from dynenv_ros.driving.cars import discrete_action
    from dynenv_ros.driving.config import DrivingConfig
    from dynenv_ros.envs.driving_session import DrivingSession

    config = DrivingConfig(n_cars=2, action_mode=action_mode, episode_seconds=episode_seconds)
    assert config.cars.max_yaw_rate == W
    session = DrivingSession(config, "realistic")
    rng = np.random.default_rng(11)
    game = DrivingGame(2, action_mode)
    names = config.car_names

    def emit(output) -> None:
        for frame in output.frames:
            stamp = sim_time(frame.tick, frame.snapshot.tick_period)
            for i, seen in enumerate(frame.robots):
                game.messages.append(("frame", names[i], detection_array(
                    seen.detections, robot_id=i, robot_name=names[i], episode_id=output.episode_id,
                    motion_period=output.motion_period, frame_index=frame.frame_index,
                    frames_per_period=len(output.frames), head_yaw=0.0, fallen=seen.fallen,
                    penalized=seen.penalized, kicking=False, ball_owner=0, ball_owner_seconds=0.0,
                    game_seconds_remaining=seen.game_seconds_remaining, stamp=stamp)))
                game.seconds[(names[i], output.episode_id, output.motion_period)] = seen.game_seconds_remaining
        end = sim_time(output.frames[-1].tick, 0.01)
        for i, feedback in enumerate(output.feedback):
            game.messages.append(("feedback", names[i], step_feedback(
                robot_id=i, episode_id=output.episode_id, motion_period=output.motion_period,
                rewards=feedback.rewards, terminated=feedback.terminated, truncated=feedback.truncated,
                seen_object_ids=feedback.seen_object_ids, landmarks_seen=feedback.landmarks_seen, stamp=end)))
            key = (names[i], output.episode_id, output.motion_period)
            game.rewards[key] = sum(feedback.rewards.values())
            game.ends[key] = (feedback.terminated, feedback.truncated)

    def choose(car: int) -> tuple[tuple, tuple]:
        """(the agent's action, the command [throttle, brake, steering] it becomes)."""
        if action_mode == "discrete":
            a, s = RECKLESS if car == 0 else (int(rng.integers(0, 3)), int(rng.integers(0, 3)))
            command = discrete_action(a, s, W)
            return (a, s), (command.throttle, command.brake, command.steering)
        if car == 0:
            u = (1.0, 0.0, -1.0)                                  # every value on a bound
        else:
            u = (float(rng.uniform(-1, 1)), float(rng.choice([0.0, rng.uniform(0, 1)])),
                 float(rng.choice([1.0, rng.uniform(-1, 1)])))
        return u, (u[0], u[1], u[2] * W)

    def answer(episode: int, period: int, submit: bool) -> None:
        for i, name in enumerate(names):
            chosen, (throttle, brake, steering) = choose(i)
            msg = Action(robot_id=i, episode_id=episode, motion_period=period, throttle=throttle, brake=brake,
                         steering=steering, policy_version=version, log_prob=float(-rng.uniform(0.5, 6.0)),
                         value=float(rng.normal()))
            game.actions[(name, episode, period)] = msg
            game.chosen[(name, episode, period)] = chosen
            game.messages.append(("action", name, msg))
            if submit:
                ok, reason = session.submit(i, episode, period, msg.throttle, msg.brake, msg.steering)
                assert ok, reason

    _play_episodes(session, emit, answer, (CRASH_SEEDS[e % len(CRASH_SEEDS)] for e in range(episodes)))
    return game


def shuffled_in_windows(messages: list, window: int, seed: int) -> list:
    """The messages with their order shuffled inside consecutive windows of ``window`` (the disorder a transport
    may bring within a period or so)."""
    rng = np.random.default_rng(seed)
    out = list(messages)
    for start in range(0, len(out), window):
        part = out[start:start + window]
        rng.shuffle(part)
        out[start:start + window] = part
    return out
