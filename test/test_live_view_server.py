"""The Foxglove live view (docs/ros_graph.md, "Live view in Foxglove"): a client speaking the Foxglove WebSocket
protocol, as the Foxglove app does, gets the channels advertised, subscribes, and decodes what it receives — the
field, every body where the simulator has it (metres, map frame), each robot's detections, the TF tree and the score.
Then the simulator node and the main job switch it on, and refuse bad ports with a one-line reason.

The protocol: the server sends ``serverInfo`` and ``advertise`` (JSON text); the client sends ``subscribe``
(subscription id → channel id); each message comes as a binary frame: opcode 0x01, uint32 LE subscription id,
uint64 LE log time (ns), the payload (JSON for /game_state, protobuf for the foxglove.* schemas, whose
FileDescriptorSet the advertisement carries). foxglove-sdk 0.30 names it ``foxglove.sdk.v1``, the protocol known as
``foxglove.websocket.v1`` under its new name.
"""
from __future__ import annotations

import base64
import json
import math
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import ClientConnection, connect

from dynenv_ros.core.object_classes import ObjectClass
from dynenv_ros.envs.soccer_session import SoccerSession
from dynenv_ros.live_view.server import SUBPROTOCOL, LiveView, LiveViewError, check_port, detections_topic
from dynenv_ros.perception.params import load_preset
from dynenv_ros.soccer.config import SoccerConfig, robot_names

REPO = Path(__file__).resolve().parent.parent
LAYOUT = REPO / "config" / "foxglove" / "dynenv_layout.json"
MESSAGE_DATA = 0x01
EXPECTED_SCHEMAS = {"/scene/field": "foxglove.SceneUpdate", "/scene/ground_truth": "foxglove.SceneUpdate",
                    "/scene/team_a_0/detections": "foxglove.SceneUpdate",
                    "/scene/team_b_0/detections": "foxglove.SceneUpdate", "/tf": "foxglove.FrameTransforms",
                    "/game_state": "dynenv.GameState", "/events": "foxglove.Log"}


class FoxgloveClient:
    """The Foxglove app's side of the protocol, enough to subscribe and decode."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.server_info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}        # topic → advertised channel
        self._by_subscription: dict[int, str] = {}
        self.received: dict[str, list[tuple[int, bytes]]] = {}  # topic → (log time ns, payload)
        self._classes: dict[str, Any] = {}
        deadline = time.monotonic() + 10.0
        while not (self.server_info and self.channels) and time.monotonic() < deadline:
            self._handle(self.ws.recv(timeout=max(0.01, deadline - time.monotonic())))
        assert self.server_info and self.channels, "no serverInfo / advertise from the server"

    def _handle(self, frame: str | bytes) -> None:
        if isinstance(frame, bytes):
            opcode, subscription, log_time = struct.unpack_from("<BIQ", frame)
            assert opcode == MESSAGE_DATA, opcode
            topic = self._by_subscription[subscription]
            self.received.setdefault(topic, []).append((log_time, frame[13:]))
            return
        message = json.loads(frame)
        if message["op"] == "serverInfo":
            self.server_info = message
        elif message["op"] == "advertise":
            self.channels.update({c["topic"]: c for c in message["channels"]})

    def subscribe(self, topics: list[str]) -> None:
        subscriptions = []
        for i, topic in enumerate(topics):
            self._by_subscription[i] = topic
            subscriptions.append({"id": i, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def receive_until(self, done: Callable[[], bool], timeout_s: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            try:
                self._handle(self.ws.recv(timeout=min(left, 0.5)))
            except TimeoutError:
                pass
        return True

    def decode(self, topic: str, payload: bytes) -> Any:
        """JSON channels: the object; protobuf channels: the message, from the advertised FileDescriptorSet."""
        channel = self.channels[topic]
        if channel["encoding"] == "json":
            return json.loads(payload)
        assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
        name = channel["schemaName"]
        if name not in self._classes:
            pool = descriptor_pool.DescriptorPool()
            for file in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"])).file:
                pool.Add(file)
            self._classes[name] = message_factory.GetMessageClass(pool.FindMessageTypeByName(name))
        return self._classes[name].FromString(payload)

    def last(self, topic: str) -> Any:
        return self.decode(topic, self.received[topic][-1][1])


@contextmanager
def foxglove_client(url: str) -> Iterator[FoxgloveClient]:
    """Connected to ``url`` with the protocol's subprotocol, past serverInfo and the first advertisement."""
    with connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
        yield FoxgloveClient(ws)


def _wait(condition: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _soccer(preset: str = "none", seed: int = 5) -> tuple[SoccerConfig, SoccerSession]:
    config = SoccerConfig.from_mapping({"players_per_team": 1, "falls": {"enabled": False}})
    session = SoccerSession(config, load_preset(preset), seed=seed)
    session.reset(seed=seed, kickoff_team=1)
    return config, session


def _yaw(q: Any) -> float:
    return 2.0 * math.atan2(q.z, q.w)


def _angle_difference(a: float, b: float) -> float:
    return (a - b + math.pi) % (2 * math.pi) - math.pi


# -- the streamer, in-process and without ROS ------------------------------------------------------------------------

def test_channels_are_advertised_and_the_stream_decodes_to_the_simulated_world():
    config, session = _soccer()
    names = robot_names(1)
    outputs = [session.initial()]
    with LiveView(config.field, names, port=0) as view:
        with foxglove_client(view.url) as client:
            assert client.ws.subprotocol == SUBPROTOCOL
            assert client.server_info["name"] == "dynenv_ros"
            assert {t: c["schemaName"] for t, c in client.channels.items()} == EXPECTED_SCHEMAS
            assert client.channels["/game_state"]["encoding"] == "json"
            assert json.loads(client.channels["/game_state"]["schema"])["title"] == "dynenv.GameState"
            client.subscribe(sorted(client.channels))
            assert _wait(lambda: view.ground_truth.has_sinks() and all(c.has_sinks() for c in view.detections))
            # Walk and turn both robots and their heads for a few periods, so no transform is the identity.
            for period in range(1, 4):
                for robot in range(2):
                    session.submit(robot, session.episode_id, period, walk=1, turn=1 + robot, kick=0,
                                   head_yaw_delta=0.3 if robot else -0.3)
                outputs.append(session.step())
            stamps = []
            for output in outputs:
                frame = output.frames[-1]
                stamp_ns = round(frame.tick * config.rates.tick_seconds * 1e9)
                stamps.append(stamp_ns)
                view.publish_frame(frame.snapshot, frame.robots, stamp_ns, motion_period=output.motion_period)
            assert client.receive_until(lambda: len(client.received.get("/scene/ground_truth", [])) == 4
                                        and len(client.received.get("/tf", [])) == 4
                                        and len(client.received.get("/game_state", [])) == 4
                                        and len(client.received.get(detections_topic("team_a_0"), [])) == 4
                                        and "/scene/field" in client.received)
            assert [t for t, _ in client.received["/scene/ground_truth"]] == stamps      # logged at sim time

            snapshot = outputs[-1].frames[-1].snapshot
            # The field, sent as the client subscribed: its four goalposts where the geometry has them.
            field = client.last("/scene/field")
            assert [e.id for e in field.entities] == ["field"]
            posts = [v for c in field.entities[0].cylinders for v in (c.pose.position.x, c.pose.position.y)]
            assert posts == pytest.approx([float(v) for post in config.field.goalposts for v in post])
            # Ground truth: every body at its simulated position, in metres, in the map frame.
            truth = client.last("/scene/ground_truth")
            assert [d.type for d in truth.deletions] == [1]                 # ALL: the picture is replaced
            entities = {e.id: e for e in truth.entities}
            assert set(entities) == {"team_a_0", "team_b_0", "ball", "score"}
            assert all(e.frame_id == "map" for e in entities.values())
            for body in snapshot.objects:
                entity = entities["ball" if body.class_id == ObjectClass.BALL else names[body.id]]
                shape = (entity.spheres or entity.cylinders)[0]
                assert (shape.pose.position.x, shape.pose.position.y) == pytest.approx((body.x, body.y), abs=1e-9)
                if body.class_id == ObjectClass.ROBOT:
                    assert _angle_difference(_yaw(shape.pose.orientation), body.yaw) == pytest.approx(0, abs=1e-9)
                    head = entity.arrows[1]
                    assert _angle_difference(_yaw(head.pose.orientation), body.yaw + body.head_yaw) == \
                        pytest.approx(0, abs=1e-9)
            assert entities["score"].texts[0].text.startswith(f"A {snapshot.score_team_a} : {snapshot.score_team_b} B")
            # TF: map → base_link at the truth (no estimates given), base_link → camera by the head's yaw, and the
            # static team frames in every message.
            tf = {(t.parent_frame_id, t.child_frame_id): t for t in client.last("/tf").transforms}
            assert set(tf) == {("map", "team_a_0/base_link"), ("team_a_0/base_link", "team_a_0/camera"),
                               ("map", "team_b_0/base_link"), ("team_b_0/base_link", "team_b_0/camera"),
                               ("map", "team_a/field"), ("map", "team_b/field")}
            for i, name in enumerate(names):
                body, base = snapshot.objects[i], tf[("map", f"{name}/base_link")]
                assert (base.translation.x, base.translation.y, base.translation.z) == \
                    pytest.approx((body.x, body.y, 0.0), abs=1e-9)
                assert _angle_difference(_yaw(base.rotation), body.yaw) == pytest.approx(0, abs=1e-9)
                camera = tf[(f"{name}/base_link", f"{name}/camera")]
                assert _yaw(camera.rotation) == pytest.approx(body.head_yaw, abs=1e-9)
            assert abs(snapshot.objects[0].head_yaw) > 0.5
            # The game state, JSON, with the schema's required keys.
            state = client.last("/game_state")
            schema = json.loads(client.channels["/game_state"]["schema"])
            assert set(schema["required"]) <= set(state)
            assert state["scenario"] == "robocup" and state["motion_period"] == 3
            assert (state["score_a"], state["score_b"], state["episode"]) == \
                (snapshot.score_team_a, snapshot.score_team_b, snapshot.episode_id)
            assert state["sim_time_s"] == pytest.approx(stamps[-1] * 1e-9)
            # Detections (the exact preset): each true sighting drawn where its object is.
            by_id = {o.id: o for o in snapshot.objects}
            robot = outputs[-1].frames[-1].robots[0]
            detections = client.last(detections_topic("team_a_0")).entities[0]
            assert detections.id == "team_a_0/detections" and detections.frame_id == "map"
            ball_rows = [r for r in robot.detections if r["class_id"] == ObjectClass.BALL and r["true_id"] >= 0]
            assert ball_rows, "the ball was not in team_a_0's view: choose another seed"
            ball = by_id[int(ball_rows[0]["true_id"])]
            assert [v for s in detections.spheres for v in (s.pose.position.x, s.pose.position.y)] == \
                pytest.approx([ball.x, ball.y], abs=1e-3)
            metadata = {kv.key: kv.value for kv in detections.metadata}
            assert metadata["detections"] == str(len(robot.detections))


def test_events_and_the_driving_world_stream_too():
    from dynenv_ros.driving.config import DrivingConfig
    from dynenv_ros.envs.driving_session import DrivingSession

    config = DrivingConfig(n_cars=2, episode_seconds=5.0)
    session = DrivingSession(config, "realistic", seed=3)
    session.reset(seed=3)
    output = session.initial()
    frame = output.frames[-1]
    with LiveView(session.world.map, config.car_names, port=0) as view:
        with foxglove_client(view.url) as client:
            assert detections_topic("car_1") in client.channels
            client.subscribe(["/scene/field", "/scene/ground_truth", "/game_state", "/events", "/tf",
                              detections_topic("car_0")])
            assert _wait(lambda: view.ground_truth.has_sinks() and view.detections[0].has_sinks())
            view.log_event("episode 1 started", 1_000)
            view.publish_frame(frame.snapshot, frame.robots, 2_000)
            assert client.receive_until(lambda: all(t in client.received for t in (
                "/scene/field", "/scene/ground_truth", "/game_state", "/events", "/tf", detections_topic("car_0"))))
            assert client.last("/events").message == "episode 1 started"
            assert [e.id for e in client.last("/scene/field").entities] == ["map"]
            entities = {e.id: e for e in client.last("/scene/ground_truth").entities}
            for body in frame.snapshot.objects:
                entity_id = (config.car_names[body.id] if body.class_id == ObjectClass.CAR
                             else f"object_{body.id}")
                shape = (entities[entity_id].cubes or entities[entity_id].cylinders)[0]
                assert (shape.pose.position.x, shape.pose.position.y) == pytest.approx((body.x, body.y), abs=1e-9)
            assert any(o.class_id == ObjectClass.PEDESTRIAN for o in frame.snapshot.objects)
            state = client.last("/game_state")
            assert state["scenario"] == "driving" and state["cars"] == 2 and "cars_home" in state
            tf = {(t.parent_frame_id, t.child_frame_id) for t in client.last("/tf").transforms}
            assert ("map", "car_0/base_link") in tf and ("map", "team_a/field") not in tf


def _taken_port() -> socket.socket:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    return listener


def test_bad_ports_and_a_port_in_use_are_refused_in_one_line():
    config, _ = _soccer()
    for bad in (-1, 65536, 8765.0, True, "8765"):
        with pytest.raises(LiveViewError, match=r"foxglove_port must be an integer in \[0, 65535\]"):
            check_port(bad)
    taken = _taken_port()
    try:
        port = taken.getsockname()[1]
        with pytest.raises(LiveViewError) as refused:
            LiveView(config.field, robot_names(1), port=port)
        assert str(refused.value) == (f"foxglove_port {port} is in use on 127.0.0.1 (another live view or "
                                      "foxglove_bridge?): choose another port, or 0 for any free one")
    finally:
        taken.close()
    with pytest.raises(LiveViewError, match="cannot listen on no.such.host.invalid:0") as refused:
        LiveView(config.field, robot_names(1), port=0, host="no.such.host.invalid")
    assert "\n" not in str(refused.value)
    # Two live views in one process: separate contexts, separate ports, nobody else's channels.
    with LiveView(config.field, robot_names(1)) as a, LiveView(config.field, robot_names(2)) as b:
        assert a.port != b.port
        with foxglove_client(a.url) as client:
            assert detections_topic("team_a_1") not in client.channels


def test_the_live_view_imports_no_ros():
    probe = ("import sys\nimport dynenv_ros.live_view.server, dynenv_ros.live_view.scene, dynenv_ros.sim.frames\n"
             "print(sorted(m for m in sys.modules if m.split('.')[0] in "
             "('rclpy', 'dynenv_msgs', 'rosidl_parser', 'torch', 'geometry_msgs')))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]", result.stdout


def test_the_shipped_layout_shows_the_live_view():
    """config/foxglove/dynenv_layout.json (Foxglove's "Import from file…" format): every panel of the arrangement
    is configured, the 3D panel follows map and shows the scene topics, the others the game state and events."""
    layout = json.loads(LAYOUT.read_text())
    assert set(layout) >= {"configById", "layout", "globalVariables", "userNodes", "playbackConfig"}

    def panels(node: Any) -> list[str]:
        return [node] if isinstance(node, str) else panels(node["first"]) + panels(node["second"])

    placed = panels(layout["layout"])
    assert sorted(placed) == sorted(layout["configById"])
    by_type = {panel.split("!")[0]: layout["configById"][panel] for panel in placed}
    assert set(by_type) == {"3D", "RawMessages", "RosOut"}
    three_d = by_type["3D"]
    assert three_d["followTf"] == "map"
    config, _ = _soccer()
    with LiveView(config.field, robot_names(2)) as view:
        with foxglove_client(view.url) as client:
            soccer_topics = set(client.channels)
    scene_topics = set(three_d["topics"])
    assert {"/scene/field", "/scene/ground_truth", "/scene/team_a_0/detections"} <= scene_topics
    assert scene_topics - soccer_topics == {"/scene/car_0/detections"}          # the driving scenario's
    assert by_type["RawMessages"]["topicPath"] == "/game_state" in soccer_topics
    assert by_type["RosOut"]["topicToRender"] == "/events" in soccer_topics


# -- the simulator node and the main job switch it on ----------------------------------------------------------------

def _sim_node(make_node, **params):
    from rclpy.parameter import Parameter

    from dynenv_ros.nodes.sim_node import SimNode
    values = {"seed": 7, "wait_for_subscribers": 0}
    if params.get("scenario", "robocup") == "robocup":
        values.update(players_per_team=1, falls_enabled=False)
    values.update(params)
    return make_node(SimNode, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def test_the_sim_node_streams_each_frame_with_its_tf_tree(make_node):
    from dynenv_msgs.srv import StepSimulation

    sim = _sim_node(make_node, foxglove_port=0)
    view = sim.live_view
    assert view is not None and view.port > 0 and view.host == "127.0.0.1"
    with foxglove_client(view.url) as client:
        assert client.server_info["name"] == "/sim_node"
        client.subscribe(sorted(client.channels))
        assert _wait(lambda: view.ground_truth.has_sinks())
        published = view.frames_published
        reply = sim._on_step(StepSimulation.Request(ticks=0), StepSimulation.Response())     # one motion period
        assert reply.success and view.frames_published == published + 5                     # its 5 vision frames
        assert client.receive_until(lambda: len(client.received.get("/tf", [])) == 5
                                    and len(client.received.get("/scene/ground_truth", [])) == 5)
        state = client.last("/game_state")
        assert (state["episode"], state["motion_period"]) == (sim.session.episode_id, 1)
        # The tree /tf carries (localization on: REP 105's map → odom → base_link at the estimate, the truth
        # beside it), and the ground truth drawn where the truth frame is.
        tf = {(t.parent_frame_id, t.child_frame_id): t for t in client.last("/tf").transforms}
        assert {("map", "team_a_0/odom"), ("team_a_0/odom", "team_a_0/base_link"),
                ("map", "team_a_0/ground_truth/base_link"), ("team_a_0/base_link", "team_a_0/camera")} <= set(tf)
        truth = tf[("map", "team_a_0/ground_truth/base_link")].translation
        robot = {e.id: e for e in client.last("/scene/ground_truth").entities}["team_a_0"]
        assert (robot.cylinders[0].pose.position.x, robot.cylinders[0].pose.position.y) == \
            pytest.approx((truth.x, truth.y), abs=1e-9)
        assert client.received["/tf"][-1][0] == client.received["/scene/ground_truth"][-1][0] > 0
    sim.destroy_node()                       # stops the server: a simulator started again gets the port back
    config, _ = _soccer()

    def restarted() -> bool:
        try:
            LiveView(config.field, robot_names(1), port=view.port).stop()
            return True
        except LiveViewError:
            return False

    assert _wait(restarted, timeout_s=5.0)


def test_the_driving_sim_node_streams_its_cars(make_node):
    from dynenv_msgs.srv import StepSimulation

    sim = _sim_node(make_node, scenario="driving", n_cars=2, foxglove_port=0)
    with foxglove_client(sim.live_view.url) as client:
        client.subscribe(sorted(client.channels))
        assert _wait(lambda: sim.live_view.ground_truth.has_sinks())
        assert sim._on_step(StepSimulation.Request(ticks=0), StepSimulation.Response()).success
        assert client.receive_until(lambda: all(t in client.received for t in (
            "/scene/field", "/scene/ground_truth", "/tf", "/game_state", detections_topic("car_1"))))
        assert {"car_0", "car_1"} <= {e.id for e in client.last("/scene/ground_truth").entities}
        assert [e.id for e in client.last("/scene/field").entities] == ["map"]
        tf = {(t.parent_frame_id, t.child_frame_id) for t in client.last("/tf").transforms}
        assert {("map", "car_0/base_link"), ("map", "car_1/base_link")} <= tf
        assert client.last("/game_state")["scenario"] == "driving"


def test_the_sim_node_refuses_a_bad_or_taken_port(make_node):
    from rclpy.exceptions import ParameterException

    with pytest.raises(ParameterException, match="foxglove_port"):
        _sim_node(make_node, foxglove_port=70000)
    taken = _taken_port()
    try:
        port = taken.getsockname()[1]
        with pytest.raises(ParameterException, match=f"foxglove_port {port} is in use"):
            _sim_node(make_node, foxglove_port=port)
        # As a process: one line on stderr, exit status 2 (run_node's parameter error).
        result = subprocess.run([sys.executable, "-m", "dynenv_ros.nodes.sim_node", "--ros-args", "-p",
                                 f"foxglove_port:={port}", "-p", "wait_for_subscribers:=0"],
                                capture_output=True, text=True, timeout=120)
    finally:
        taken.close()
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if "parameter error" in line]
    assert errors == [f"parameter error: foxglove_port {port} is in use on 127.0.0.1 (another live view or "
                      "foxglove_bridge?): choose another port, or 0 for any free one: ['foxglove_port', "
                      "'foxglove_host']"]


def test_the_main_job_passes_foxglove_port_to_the_simulator(tmp_path):
    from dynenv_ros.main_job import REPO_CONFIG, ConfigError, MainJobConfig, load_config, soccer_graph

    assert MainJobConfig().foxglove_port == -1                        # off unless asked for
    for scenario in ("robocup", "driving"):
        overrides = {"foxglove_port": 8765} if scenario == "robocup" else {"scenario": scenario, "foxglove_port": 0}
        config = load_config(REPO_CONFIG, overrides)
        sim = next(n for n in soccer_graph(config, tmp_path) if n.name == "sim_node")
        assert sim.parameters["foxglove_port"] == config.foxglove_port
    with pytest.raises(ConfigError, match=r"foxglove_port must be -1 \(off\), 0 \(any free port\) or a port in "
                                          r"\[1, 65535\], got 65536"):
        load_config(REPO_CONFIG, {"foxglove_port": 65536})
    with pytest.raises(ConfigError, match="foxglove_port: not used by graph 'train'"):
        load_config(REPO_CONFIG, {"graph": "train", "foxglove_port": 8765})
