"""The learned policy as a ROS 2 node (``ros2 run dynenv_ros policy_node``): detections in, one action per robot
per motion period out.

For each controlled robot (all, or one team — so two policies can play each other) it buffers the vision frames of
the current period, and once every controlled robot has all of them it runs the network for all of them in one
batch, keeps each robot's recurrent state and publishes each robot's action for the next period. State resets
at episode boundaries. Weights come from a policy file (safetensors, no pickle: ``agent.checkpoint``) or an ONNX file, at start
or through the LoadPolicy service, swapped between two decisions so no period is dropped.
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from dynenv_msgs.msg import Action, DetectionArray
from dynenv_msgs.srv import LoadPolicy
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from dynenv_ros.envs.padded_layout import PaddedLayout, clamp_features, pack_frames
from dynenv_ros.perception.detections import as_features, rows_from_messages
from dynenv_ros.ros import topics
from dynenv_ros.ros.node_runner import run_node
from dynenv_ros.ros.parameters import declare_bool, declare_int, declare_str
from dynenv_ros.ros.qos import sim_stream
from dynenv_ros.soccer.config import robot_names
from dynenv_ros.agent.checkpoint import load_checkpoint, sha256
from dynenv_ros.agent.export import TorchPolicy
from dynenv_ros.agent.inputs import side_inputs, streams_from_padded
from dynenv_ros.agent.network import DynEnvAgent

RUNTIMES = ("torch", "onnxruntime")


class RobotMemory:
    """What the node keeps per robot between periods."""

    def __init__(self) -> None:
        self.episode: int | None = None
        self.period: int | None = None
        self.frames: dict[int, DetectionArray] = {}
        self.state: tuple | None = None
        self.previous = (0, 0, 0, 0.0)


class PolicyNode(Node):
    def __init__(self, **node_options: Any) -> None:
        super().__init__("policy_node", **node_options)
        players = declare_int(self, "players_per_team", 2, 1, 5, "Robots per team in the game.", read_only=True)
        team = declare_str(self, "team", "", "Control team 'a', team 'b', or both ('').", read_only=True,
                           choices=("", "a", "b"))
        self.runtime_name = declare_str(self, "runtime", "torch", "Inference runtime.", choices=RUNTIMES,
                                        read_only=True)
        checkpoint = declare_str(self, "checkpoint", "", "Weights: a .safetensors policy file (torch) or .onnx file; empty: "
                                 "untrained weights from 'seed' (smoke tests only).", read_only=True)
        seed = declare_int(self, "seed", 0, 0, 2**31 - 1, "Seed of action sampling (and untrained weights).",
                           read_only=True)
        self.greedy = declare_bool(self, "greedy", False, "Take the most likely action instead of sampling.")
        everyone = robot_names(players)
        self.names = [name for name in everyone if team in ("", name[5])]
        self.ids = {name: everyone.index(name) for name in self.names}
        self.generator = torch.Generator().manual_seed(seed)
        try:
            if checkpoint:
                self.policy, self.checkpoint_sha256 = self._load(checkpoint, self.runtime_name)
            else:
                torch.manual_seed(seed)
                self.policy, self.checkpoint_sha256 = TorchPolicy(DynEnvAgent()), ""
                self.get_logger().warning("no checkpoint: acting with untrained weights")
        except ValueError as error:
            raise ParameterException(str(error), ["checkpoint"]) from None
        self.memory = {name: RobotMemory() for name in self.names}
        self.latencies_ms: list[float] = []
        self.actions_sent = 0
        self.dropped_detections = 0          # rows beyond a fixed-shape runtime's maxima, farthest first
        qos = sim_stream()
        self.action_pubs = {n: self.create_publisher(Action, topics.action(n), qos) for n in self.names}
        self.detection_subs = [self.create_subscription(DetectionArray, topics.detections(n), self._receiver(n), qos)
                               for n in self.names]
        self.load_srv = self.create_service(LoadPolicy, "~/load_policy", self._on_load)
        self.get_logger().info(f"controlling {', '.join(self.names)} with {self.runtime_name}")

    # -- weights ---------------------------------------------------------------------------------------------------
    def _load(self, path: str, runtime: str):
        if runtime not in RUNTIMES:
            raise ValueError(f"runtime must be one of {RUNTIMES}, got {runtime!r}")
        if runtime == "torch":
            return TorchPolicy(load_checkpoint(path)), sha256(path)
        from dynenv_ros.agent.export import OnnxPolicy
        try:
            return OnnxPolicy(path), sha256(path)
        except Exception as error:
            raise ValueError(f"cannot load ONNX policy {path}: {error}") from None

    def _on_load(self, request: LoadPolicy.Request, response: LoadPolicy.Response):
        runtime = request.runtime or self.runtime_name
        try:
            policy, digest = self._load(request.checkpoint_path, runtime)
        except ValueError as error:
            response.success, response.message = False, f"kept the current policy: {error}"
            return response
        # Callbacks run one at a time: the swap happens between two decisions. The recurrent states carry over
        # when they fit the new network; a network of another size starts from fresh states.
        if policy.feature_size != self.policy.feature_size:
            for memory in self.memory.values():
                memory.state = None
        self.policy, self.runtime_name, self.checkpoint_sha256 = policy, runtime, digest
        response.success, response.message, response.checkpoint_sha256 = True, f"loaded ({runtime})", digest
        self.get_logger().info(f"loaded {request.checkpoint_path} ({runtime}, sha256 {digest[:12]})")
        return response

    # -- frames and decisions ----------------------------------------------------------------------------------------
    def _receiver(self, name: str):
        def receive(msg: DetectionArray) -> None:
            memory = self.memory[name]
            if memory.episode != msg.episode_id:                 # a new episode: forget everything
                memory.episode, memory.state, memory.previous = msg.episode_id, None, (0, 0, 0, 0.0)
                memory.period, memory.frames = None, {}
            if memory.period != msg.motion_period:
                memory.period, memory.frames = msg.motion_period, {}
            memory.frames[msg.frame_index] = msg
            self._decide_if_ready()
        return receive

    def _complete(self, memory: RobotMemory) -> bool:
        frames = next(iter(memory.frames.values()), None)
        return frames is not None and len(memory.frames) == frames.frames_per_period

    def _decide_if_ready(self) -> None:
        ready = [n for n in self.names if self._complete(self.memory[n])]
        if len(ready) < len(self.names):
            return
        started = time.perf_counter()
        memories = [self.memory[n] for n in ready]
        observation = self._padded(memories)
        landmarks, objects = streams_from_padded(observation)
        previous, proprio = side_inputs(observation, float(self.policy.head_max))
        states = [m.state or self.policy.initial_state(1) for m in memories]
        state = tuple(torch.cat([s[i] for s in states]) for i in range(4))
        step = self.policy(landmarks, objects, previous, proprio, state)
        head_max = float(self.policy.head_max)
        actions = _sample(step, self.policy.head_mode, self.generator, self.greedy, head_max)
        units = (torch.as_tensor(step.head).shape[-1] - 1) // 2 if self.policy.head_mode == "discrete" else 0
        last = [m.frames[max(m.frames)] for m in memories]
        for b, (name, memory, frame) in enumerate(zip(ready, memories, last)):
            walk, turn, kick, head = actions[b]
            # The checkpoint's own head discretisation: index 0..2u ↦ (index − u)·head_max/u rad.
            head_delta = ((int(head) - units) * head_max / units if self.policy.head_mode == "discrete"
                          else float(head))
            self.action_pubs[name].publish(Action(
                robot_id=self.ids[name], episode_id=frame.episode_id, motion_period=frame.motion_period + 1,
                walk=int(walk), turn=int(turn), kick=int(kick), head_yaw_delta=head_delta))
            memory.state = tuple(s[b:b + 1] for s in step.state)
            memory.previous = (int(walk), int(turn), int(kick), head_delta)
            memory.frames = {}
            self.actions_sent += 1
        self.latencies_ms.append(1000 * (time.perf_counter() - started))
        if len(self.latencies_ms) % 100 == 0:
            recent = self.latencies_ms[-100:]
            self.get_logger().info(f"decision latency for {len(ready)} robots: median "
                                   f"{statistics.median(recent):.2f} ms, max {max(recent):.2f} ms")


    def _padded(self, memories: list[RobotMemory]) -> dict[str, np.ndarray]:
        observation, dropped = pack_messages([[m.frames[k] for k in sorted(m.frames)] for m in memories],
                                             [m.previous for m in memories],
                                             getattr(self.policy, "max_landmarks", None),
                                             getattr(self.policy, "max_objects", None))
        self.dropped_detections += dropped
        return observation


def pack_messages(periods: list[list[DetectionArray]], previous: list[tuple], max_landmarks: int | None = None,
                  max_objects: int | None = None) -> tuple[dict[str, np.ndarray], int]:
    """Each robot's DetectionArray messages of one period (frame order) and previous action → the one observation
    layout (``envs.padded_layout``): the same arrays the in-process env gives for the same detections. A
    fixed-shape runtime (ONNX) sets the maxima, else the batch's own longest frame does. Returns the arrays and
    the number of rows dropped (farthest first) beyond the maxima."""
    frames = [[clamp_features(as_features(rows_from_messages(msg.detections))) for msg in period]
              for period in periods]
    observation, dropped = pack_frames(PaddedLayout.fitting(frames, max_landmarks, max_objects), frames)
    for b, period in enumerate(periods):
        for k, msg in enumerate(period):
            observation["proprioception"][b, k] = (msg.head_yaw, msg.self_fallen, msg.self_penalized,
                                                   msg.self_kicking)
        last = period[-1]
        observation["game"][b] = (last.ball_owner, last.ball_owner_seconds, last.game_seconds_remaining)
        observation["previous_action"][b] = previous[b]
    return observation, int(dropped.sum())


def _sample(step, head_mode: str, generator: torch.Generator, greedy: bool, head_max: float) -> np.ndarray:
    """(B, 4) [walk, turn, kick, head] from the network's outputs (either runtime)."""
    columns = []
    for logits in (step.walk, step.turn, step.kick) + ((step.head,) if head_mode == "discrete" else ()):
        logits = torch.as_tensor(logits)
        probs = torch.softmax(logits, dim=-1)
        columns.append(probs.argmax(-1) if greedy else torch.multinomial(probs, 1, generator=generator).squeeze(-1))
    if head_mode != "discrete":
        head = torch.as_tensor(step.head)
        mean, std = head[:, 0], head[:, 1].exp()
        value = mean if greedy else mean + std * torch.randn(mean.shape, generator=generator)
        columns.append(value.clamp(-head_max, head_max))
    return torch.stack([c.float() for c in columns], dim=-1).numpy()


def main(args: Sequence[str] | None = None) -> int:
    return run_node(PolicyNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
