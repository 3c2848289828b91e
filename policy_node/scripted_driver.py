"""Scripted drivers as one ROS 2 node (``ros2 run dynenv_ros scripted_driver --ros-args -p n_cars:=2``): the
driving counterpart of ``scripted_policy``, driving every car it is given with ``driving.scripted.ScriptedDriver``
(a lane-keeping route follower that yields to pedestrians) from the ``/world_state`` ground truth.

For each car it acts once per motion period: when the car's last detection frame of a period and the ground truth
of the same instant have both arrived, it publishes the car's action for the next period on ``/<car>/action`` (the
driving fields: throttle, brake, steering), stamped with that frame's time and framed in ``<car>/base_link``.
Waiting for both keeps stepped runs deterministic whatever order DDS delivers them in. The decisions of one
instant are made once for all cars (the driver plans every car's route to settle who enters the crossing first).
``action_mode`` must be the simulator's: discrete actions are sent as the command the discrete choice becomes.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

from dynenv_msgs.msg import Action, DetectionArray, WorldState
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.driving.cars import discrete_action
from dynenv_ros.driving.config import MAX_CARS, DrivingConfig, car_names, is_driving_world
from dynenv_ros.driving.scripted import ScriptedDriver
from dynenv_ros.ros import conversions as cv
from dynenv_ros.ros import topics
from dynenv_ros.ros.authentication import action_tagger
from dynenv_ros.ros.diagnostics import Heartbeat
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_float, declare_int, declare_str, declare_str_list
from dynenv_ros.ros.qos import action_stream, sim_stream
from dynenv_ros.ros.tf import base_frame

KEEP = 50                      # instants of ground truth / waiting frames kept


class ScriptedDriverNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("scripted_driver", **node_options)
        n_cars = declare_int(self, "n_cars", 2, 1, MAX_CARS, "Cars in the game (the simulator's n_cars).",
                             read_only=True)
        cars = declare_str_list(self, "cars", [], "Cars to drive (car_0, …); empty: all n_cars.", read_only=True)
        mode = declare_str(self, "action_mode", "discrete", "The simulator's action_mode.",
                           choices=("discrete", "continuous"), read_only=True)
        cruise = declare_float(self, "cruise_speed", 10.0, 1.0, 30.0, "Speed on straights, m/s.", read_only=True)
        names = car_names(n_cars)
        unknown = [c for c in cars if c not in names]
        if unknown:
            raise ParameterException(f"unknown cars {unknown}; cars are {names}", ["cars"])
        self.cars = cars or names
        self.tag_action = action_tagger(self, self.cars)       # secrets_dir: cars.secret (issue 27)
        self.config = DrivingConfig(n_cars=n_cars, action_mode=mode)
        self.driver = ScriptedDriver(self.config, cruise_speed=cruise)
        self._truth: OrderedDict[tuple[int, int, int], WorldState] = OrderedDict()
        self._waiting: OrderedDict[tuple[int, int, int], dict[str, DetectionArray]] = OrderedDict()
        self._decided: OrderedDict[tuple[int, int, int], list[Any]] = OrderedDict()
        self.actions_sent = 0
        self.heartbeat = Heartbeat(self, "scripted driver", lambda: {"cars": " ".join(self.cars),
                                                                     "actions_sent": self.actions_sent})
        qos = sim_stream()
        self.action_pubs = {c: self.create_publisher(Action, topics.local(topics.action(c)), action_stream())
                            for c in self.cars}
        self.create_subscription(WorldState, topics.local(topics.WORLD_STATE), self._on_truth, qos)
        for car in self.cars:
            self.create_subscription(DetectionArray, topics.local(topics.detections(car)),
                                     lambda msg, car=car: self._on_detections(car, msg), qos)

    @staticmethod
    def _key(episode: int, stamp) -> tuple[int, int, int]:
        """Episodes restart the clock at 0, so an instant is (episode, sec, nanosec)."""
        return (episode, stamp.sec, stamp.nanosec)

    def _on_truth(self, msg: WorldState) -> None:
        if not is_driving_world(msg.scenario):
            self.get_logger().error("the ground truth is not a driving world: is the simulator's scenario "
                                    "'driving'?", throttle_duration_sec=5.0)
            return
        key = self._key(msg.episode_id, msg.header.stamp)
        self._truth[key] = msg
        self._truth.move_to_end(key)
        while len(self._truth) > KEEP:
            self._truth.popitem(last=False)
        for car, frame in self._waiting.pop(key, {}).items():
            self._act(car, frame, msg, key)

    def _on_detections(self, car: str, msg: DetectionArray) -> None:
        if msg.frame_index != msg.frames_per_period - 1:
            return
        key = self._key(msg.episode_id, msg.header.stamp)
        truth = self._truth.get(key)
        if truth is None:
            self._waiting.setdefault(key, {})[car] = msg
            while len(self._waiting) > KEEP:        # a ground truth that never came: forget the oldest wait
                self._waiting.popitem(last=False)
        else:
            self._act(car, msg, truth, key)

    def _decisions(self, key: tuple[int, int, int], truth: WorldState) -> list[Any]:
        decided = self._decided.get(key)
        if decided is None:
            decided = self._decided[key] = self.driver.actions(cv.snapshot_from_msg(truth))
            while len(self._decided) > KEEP:
                self._decided.popitem(last=False)
        return decided

    def _act(self, car: str, frame: DetectionArray, truth: WorldState, key: tuple[int, int, int]) -> None:
        actions = self._decisions(key, truth)
        if frame.robot_id >= len(actions):
            self.get_logger().error(f"{car}: no car {frame.robot_id} in the ground truth", throttle_duration_sec=5.0)
            return
        raw = actions[frame.robot_id]
        if self.config.action_mode == "discrete":
            command = discrete_action(int(raw[0]), int(raw[1]), self.config.cars.max_yaw_rate)
            throttle, brake, steering = command.throttle, command.brake, command.steering
        else:
            throttle, brake, steering = (float(v) for v in raw)
        msg = Action(robot_id=frame.robot_id, episode_id=frame.episode_id, motion_period=frame.motion_period + 1,
                     throttle=throttle, brake=brake, steering=steering)
        msg.header.stamp = frame.header.stamp            # the observation it answers (sim time)
        msg.header.frame_id = base_frame(car)
        self.tag_action(car, msg, self.action_pubs[car])
        self.action_pubs[car].publish(msg)
        self.actions_sent += 1


def main(args: Sequence[str] | None = None) -> int:
    return run_node(ScriptedDriverNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
