"""The live view's Foxglove WebSocket server: one per simulator, streaming each vision frame to any Foxglove app.

``LiveView`` starts ``foxglove-sdk``'s server on its own ``foxglove.Context`` (two simulators in one process never
share channels) and advertises these channels (docs/ros_graph.md, "Live view in Foxglove"):

- ``/scene/field`` (``foxglove.SceneUpdate``): the field or the driving map, sent to each client that subscribes.
- ``/scene/ground_truth`` (``foxglove.SceneUpdate``): robots (cars, pedestrians, obstacles), ball, score line.
- ``/scene/<robot>/detections`` (``foxglove.SceneUpdate``): one per robot (car), its detections in ``map``.
- ``/tf`` (``foxglove.FrameTransforms``): the TF tree of ``sim/frames.py``, the one ROS's ``/tf`` carries, with the
  static team frames (soccer) in every message, so a late client has them.
- ``/game_state`` (JSON, schema ``dynenv.GameState``): score, phase and clock (driving: the counts).
- ``/events`` (``foxglove.Log``): goals, penalties, episode starts, as the simulator logs them.

Messages are stamped and logged at sim time (ns), as ``/clock`` runs. A scene is built only for channels a client
subscribed to (``has_sinks``), so a server nobody watches costs next to nothing. The server listens on loopback by
default: anyone who can reach the port sees the game (the protocol has no authentication).
"""
from __future__ import annotations

from collections.abc import Sequence
from types import TracebackType

import foxglove
from foxglove.channels import FrameTransformsChannel, LogChannel, SceneUpdateChannel
from foxglove.messages import Log, LogLevel
from foxglove.websocket import ChannelView, Client, ServerListener

from dynenv_ros.driving.roads import DrivingMap
from dynenv_ros.envs.session import RobotFrame
from dynenv_ros.live_view import scene
from dynenv_ros.sim.frames import PlanarTransform, robot_frames, static_frames
from dynenv_ros.sim.ground_truth import WorldSnapshot
from dynenv_ros.soccer.field import FieldGeometry

FIELD_TOPIC = "/scene/field"
GROUND_TRUTH_TOPIC = "/scene/ground_truth"
TF_TOPIC = "/tf"
GAME_STATE_TOPIC = "/game_state"
EVENTS_TOPIC = "/events"
DEFAULT_HOST = "127.0.0.1"      # loopback: the protocol has no authentication
OFF = -1                        # the nodes' and the main job's foxglove_port value for "no live view"
MAX_PORT = 65535
SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk 0.30 speaks (foxglove.websocket.v1 under its new name)


def detections_topic(robot: str) -> str:
    return f"/scene/{robot}/detections"


class LiveViewError(ValueError):
    """The live view cannot start: a bad port or host, or the port is taken. One line, for a parameter error."""


def check_port(port: object, name: str = "foxglove_port") -> int:
    """A port the live view can listen on: 0 (any free one) to 65535."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= MAX_PORT:
        raise LiveViewError(f"{name} must be an integer in [0, {MAX_PORT}] (0: any free port), got {port!r}")
    return port


class _Listener(ServerListener):
    """Sends the static scene to each client as it subscribes to it (the channel keeps no history)."""

    def __init__(self, view: "LiveView") -> None:
        self.view = view

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        if channel.topic == FIELD_TOPIC:
            self.view.send_static()


class LiveView:
    """Stream a simulator's frames to Foxglove over WebSocket. ``geometry``: the soccer field or the driving map;
    ``names``: the robots (cars) in object-id order. ``port`` 0 takes any free port (read it back from ``port``)."""

    def __init__(self, geometry: FieldGeometry | DrivingMap, names: Sequence[str], *, port: int = 0,
                 host: str = DEFAULT_HOST, server_name: str = "dynenv_ros") -> None:
        check_port(port)
        if not isinstance(host, str) or not host.strip():
            raise LiveViewError(f"foxglove_host must name an interface to listen on, got {host!r}")
        self.names = list(names)
        self.soccer = isinstance(geometry, FieldGeometry)
        self._static = scene.static_scene(geometry)
        if self.soccer:
            self._text_position = (0.0, geometry.half_width + geometry.border + 0.3, 1.0)
        else:
            self._text_position = (geometry.width / 2, geometry.height + 4.0, 2.0)
        self._last_stamp_ns = 0
        self.frames_published = 0
        self.context = foxglove.Context()
        # Channels before the server: the first advertisement a client gets lists them all.
        self.field = SceneUpdateChannel(FIELD_TOPIC, context=self.context)
        self.ground_truth = SceneUpdateChannel(GROUND_TRUTH_TOPIC, context=self.context)
        self.detections = [SceneUpdateChannel(detections_topic(n), context=self.context) for n in self.names]
        self.tf = FrameTransformsChannel(TF_TOPIC, context=self.context)
        self.game_state = foxglove.Channel(GAME_STATE_TOPIC, schema=scene.GAME_STATE_SCHEMA, context=self.context)
        self.events = LogChannel(EVENTS_TOPIC, context=self.context)
        try:
            self._server = foxglove.start_server(name=server_name, host=host.strip(), port=port,
                                                 context=self.context, server_listener=_Listener(self))
        except (RuntimeError, OverflowError) as error:
            reason = str(error).replace("FoxgloveError: ", "").replace("Failed to bind port: ", "")
            if "in use" in reason:
                raise LiveViewError(f"foxglove_port {port} is in use on {host} (another live view or "
                                    "foxglove_bridge?): choose another port, or 0 for any free one") from None
            raise LiveViewError(f"cannot listen on {host}:{port} for the Foxglove live view: {reason}") from None
        self.host = host.strip()
        self.port = self._server.port

    @property
    def url(self) -> str:
        """What to open in the Foxglove app (Open connection → Foxglove WebSocket)."""
        return f"ws://{self.host}:{self.port}"

    def send_static(self) -> None:
        self.field.log(self._static, log_time=self._last_stamp_ns)

    def publish_frame(self, snapshot: WorldSnapshot, robots: Sequence[RobotFrame], stamp_ns: int, *,
                      motion_period: int = 0, transforms: Sequence[PlanarTransform] | None = None) -> None:
        """One vision frame. ``stamp_ns``: its sim time; ``transforms``: the robots' part of the TF tree (the sim
        node passes the one it publishes on ``/tf``; default: the truth, ``sim.frames.robot_frames``)."""
        self._last_stamp_ns = stamp_ns
        self.frames_published += 1
        robots_truth = snapshot.objects[:len(self.names)]
        # every message is built only for a channel somebody watches: with no viewer a frame costs next to nothing
        if self.tf.has_sinks():
            if transforms is None:
                transforms = robot_frames(self.names, [(o.x, o.y, o.yaw, o.head_yaw) for o in robots_truth])
            all_transforms = list(transforms) + (static_frames() if self.soccer else [])
            self.tf.log(scene.frame_transforms(all_transforms, stamp_ns), log_time=stamp_ns)
        if self.game_state.has_sinks():
            self.game_state.log(scene.game_state(snapshot, motion_period=motion_period,
                                                 sim_time_s=stamp_ns * 1e-9), log_time=stamp_ns)
        if self.ground_truth.has_sinks():
            self.ground_truth.log(scene.ground_truth_scene(snapshot, self.names, stamp_ns,
                                                           text_position=self._text_position), log_time=stamp_ns)
        for channel, me, robot, name in zip(self.detections, robots_truth, robots, self.names):
            if not channel.has_sinks():
                continue
            missed = [] if robot.missed is None else [tuple(p) for p in robot.missed.tolist()]
            channel.log(scene.detection_scene(name, robot.detections, (me.x, me.y, me.yaw + me.head_yaw), stamp_ns,
                                              missed=missed, observer_team=me.team if me.team in (1, -1) else 1),
                        log_time=stamp_ns)

    def log_event(self, text: str, stamp_ns: int, level: LogLevel = LogLevel.Info) -> None:
        """A line for the Log panel (goals, penalties, episode starts)."""
        self.events.log(Log(timestamp=scene.timestamp(stamp_ns), level=level, message=text, name="dynenv_sim"),
                        log_time=stamp_ns)

    def stop(self) -> None:
        """Close the server (clients see the connection end); safe to call twice."""
        self._server.stop()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.stop()
