"""The driving world served to asynchronous controllers (the ROS simulator node, tests): the driving counterpart of
``soccer_session.SoccerSession``, on the same mailbox (``session.ActionSession``).

Actions are the driving fields of dynenv_msgs/Action — throttle [−1, 1], brake [0, 1], steering (yaw rate, rad/s,
|·| ≤ ``cars.max_yaw_rate``) — checked before they touch the world. In ``action_mode='discrete'`` an action must be
one of the nine commands the original's ``MultiDiscrete([3, 3])`` becomes (``driving.cars.discrete_action``:
throttle −1 / 0 / +1 with brake 1 exactly when throttle is 0, steering −w / 0 / +w), to float32 round-off; in
``'continuous'`` any command within the bounds. A car without an action brakes (``missing_action='none'``) or
repeats its last command (``'hold'``). Per period: every car's detections per vision frame (the driving perception,
``driving.vision.DrivingVision``, in the car's frame: x forward, y left, its SELF row first), the ground truth, and
per car its reward terms and whether it can earn nothing more (crashed, or home with its team's bonus decided:
``driving_v0``'s per-car termination). ROS-free.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from dynenv_ros.core.object_classes import ObjectStatus
from dynenv_ros.driving.cars import ACCELERATION_CHOICES, BRAKE, STEERING_CHOICES, DrivingAction, discrete_action
from dynenv_ros.driving.config import DrivingConfig
from dynenv_ros.driving.vision import DrivingVision
from dynenv_ros.driving.world import DrivingWorld
from dynenv_ros.envs.session import ActionSession, FrameOutput, PeriodOutput, RobotFeedback, RobotFrame
from dynenv_ros.perception.driving_params import DrivingPerceptionParams
from dynenv_ros.sim.reward_terms import RewardTerm
from dynenv_ros.sim.seeding import checked_seed

BOUND_TOLERANCE = 1e-6        # beyond a bound by float round-off: accepted and clamped (driving.cars)
DISCRETE_TOLERANCE = 1e-5     # a discrete command carried in float32 fields


class DrivingSession(ActionSession):
    """One driving world, its perception, and a mailbox of actions per 100 ms motion period."""

    agent_word = "car"
    logged_events = ("goal", "crash", "pedestrian_hit")

    def __init__(self, config: DrivingConfig, perception: DrivingPerceptionParams | str = "realistic",
                 seed: int | None = None, missing_action: str = "none", controlled: list[int] | None = None) -> None:
        super().__init__(config.n_cars, missing_action, controlled)
        self.config = config
        self.names = config.car_names
        self.world = DrivingWorld(config, seed=seed)
        self.vision = DrivingVision(self.world, perception)
        self.max_yaw_rate = config.cars.max_yaw_rate
        self._discrete = [discrete_action(a, s, self.max_yaw_rate)
                          for a in range(ACCELERATION_CHOICES) for s in range(STEERING_CHOICES)]
        self.returns = np.zeros(config.n_cars)         # this episode's total reward per car
        self.pedestrians_hit = 0
        self.episodes: list[dict[str, Any]] = []       # a summary of each finished episode (``summary``)

    # -- episode -----------------------------------------------------------------------------------------------
    def report_extra(self) -> dict[str, Any]:
        """The finished episodes' summaries, then the one running (if any period ran)."""
        episodes = list(self.episodes)
        if not self.finished and self.world.period > 0:
            episodes.append(self.summary())
        return {"episodes": episodes}

    def reset(self, seed: int | None = None) -> int:
        seed = checked_seed(seed)
        self._begin_episode()
        self.world.reset(seed=seed)
        self.vision.reset()
        self._episode_started()
        self.returns[:] = 0.0
        self.pedestrians_hit = 0
        return self.world.episode_id

    def summary(self) -> dict[str, Any]:
        """The episode so far: cars home and crashed, pedestrians hit, reward per car, sim seconds."""
        cars = self.world.cars
        return {"episode": self.episode_id, "periods": self.world.period,
                "sim_seconds": round(self.world.game_time, 6),
                "cars_home": sum(1 for c in cars if c.at_goal), "crashed": sum(1 for c in cars if c.crashed),
                "pedestrians_hit": self.pedestrians_hit,
                "reward_per_car": {n: round(float(r), 4) for n, r in zip(self.names, self.returns)}}

    # -- actions -------------------------------------------------------------------------------------------------
    def submit(self, robot_id: int, episode_id: int, motion_period: int, throttle: float, brake: float,
               steering: float) -> tuple[bool, str]:
        """Accept one car's action for the current period, or refuse it with a reason (counted)."""
        return super().submit(robot_id, episode_id, motion_period, throttle, brake, steering)

    def check(self, robot_id: int, episode_id: int, motion_period: int, throttle: float, brake: float,
              steering: float) -> str:
        """Why this action would be refused now ("" if it would be accepted); changes nothing."""
        return super().check(robot_id, episode_id, motion_period, throttle, brake, steering)

    def _check_fields(self, throttle, brake, steering) -> str:
        values = (("throttle", throttle), ("brake", brake), ("steering", steering))
        for name, value in values:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                return f"malformed: {name} is {value}"
        w = self.max_yaw_rate
        for name, value, low, high in (("throttle", throttle, -1.0, 1.0), ("brake", brake, 0.0, 1.0),
                                       ("steering", steering, -w, w)):
            if value < low - BOUND_TOLERANCE or value > high + BOUND_TOLERANCE:
                return f"out_of_range: {name}={value:.6g} outside [{low:.6g}, {high:.6g}]"
        if self.config.action_mode == "discrete" and self._discrete_index(throttle, brake, steering) is None:
            return (f"out_of_range: (throttle, brake, steering)=({throttle:.6g}, {brake:.6g}, {steering:.6g}) is "
                    f"not a discrete action (throttle -1/0/1, brake 1 exactly when throttle is 0, steering "
                    f"-{w:.6g}/0/{w:.6g})")
        return ""

    def _discrete_index(self, throttle: float, brake: float, steering: float) -> int | None:
        for k, command in enumerate(self._discrete):
            if (abs(command.throttle - throttle) <= DISCRETE_TOLERANCE
                    and abs(command.brake - brake) <= DISCRETE_TOLERANCE
                    and abs(command.steering - steering) <= DISCRETE_TOLERANCE):
                return k
        return None

    def _action(self, throttle, brake, steering) -> DrivingAction:
        if self.config.action_mode == "discrete":
            return self._discrete[self._discrete_index(throttle, brake, steering)]   # the exact command
        w = self.max_yaw_rate
        return DrivingAction(min(1.0, max(-1.0, float(throttle))), min(1.0, max(0.0, float(brake))),
                             min(w, max(-w, float(steering))))

    def idle(self) -> DrivingAction:
        return BRAKE

    # -- one period ----------------------------------------------------------------------------------------------
    def initial(self) -> PeriodOutput:
        """Period 0: every frame shows the reset state (each perceived anew), no rewards yet."""
        frames = self.config.rates.frames_per_period
        snapshot = self.world.snapshot()
        perceptions = [self.vision.perceive() for _ in range(frames)]
        n = self.config.n_cars
        return self._output(0, [snapshot] * frames, [self.world.tick] * frames, perceptions,
                            np.zeros((len(RewardTerm), n)), False, False, [])

    def step(self) -> PeriodOutput:
        """Run the current period with the actions received; missing ones follow ``missing_action``."""
        actions = self._period_actions()
        snapshots, ticks, perceptions = [], [], []

        def on_frame(k: int) -> None:
            perceptions.append(self.vision.perceive())
            snapshots.append(self.world.snapshot())
            ticks.append(self.world.tick)

        result = self.world.step(actions, on_frame=on_frame, names=self.names)
        self.finished = result.terminated or result.truncated
        self.returns += result.rewards.sum(axis=0)
        self.pedestrians_hit += sum(1 for e in result.events if e.kind == "pedestrian_hit")
        output = self._output(self.world.period, snapshots, ticks, perceptions, result.rewards, result.terminated,
                              result.truncated, result.events)
        if self.finished:
            self.episodes.append(self.summary())
        return output

    def _output(self, period, snapshots, ticks, perceptions, rewards, terminated, truncated, events) -> PeriodOutput:
        n = self.config.n_cars
        frames = []
        for k, (snapshot, p) in enumerate(zip(snapshots, perceptions)):
            cars = snapshot.objects[:n]
            frames.append(FrameOutput(ticks[k], k, snapshot, [
                RobotFrame(p.of_view(i), 0.0, bool(cars[i].status & ObjectStatus.CRASHED),
                           bool(cars[i].status & ObjectStatus.FINISHED), False, 0, 0.0, snapshot.time_remaining,
                           self._missed(snapshot, p, i) if i == self.missed_for else None)
                for i in range(n)]))
        seen = np.zeros_like(perceptions[0].seen)
        lanes = np.zeros(n)
        for p in perceptions:
            seen |= p.seen
            lanes += p.lanes_seen
        lanes /= len(perceptions)
        ended = self.world.cars_done()
        feedback = []
        for i in range(n):
            car_terminated = terminated or ended[i]
            feedback.append(RobotFeedback({t.name.lower(): float(rewards[t, i]) for t in RewardTerm},
                                          [int(j) for j in np.flatnonzero(seen[i])], float(lanes[i]),
                                          car_terminated, truncated and not car_terminated))
        return PeriodOutput(self.episode_id, period, frames, feedback, terminated, truncated, events)

    @staticmethod
    def _missed(snapshot, perception, view: int) -> np.ndarray:
        """Map positions of the objects in the car's view that it did not report as what they are."""
        missed = np.flatnonzero(perception.visible[view] & ~perception.seen[view])
        objects = snapshot.objects
        rows = [(objects[j].x, objects[j].y) for j in missed.tolist() if j < len(objects) and j != view]
        return np.asarray(rows, float).reshape(-1, 2)


__all__ = ["DrivingSession"]
