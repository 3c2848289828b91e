"""(c) Every interface round-trips through CDR with rosbags, using a typestore built from the .msg/.srv files."""
from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from dynenv_msgs.msg import Detection, DetectionArray, WorldState
from dynenv_ros.bags.typestore import dynenv_typestore, interface_definitions, interface_source_dirs
from dynenv_ros.ros.interfaces import all_interface_types, field_differences, generated_type_hash, sample_message

INTERFACES = all_interface_types()
IDS = [t.name.split("/", 1)[1] for t in INTERFACES]


def test_typestore_covers_every_generated_interface():
    defined = set(interface_definitions(interface_source_dirs()[0]))
    assert defined == {t.name for t in INTERFACES}


@pytest.mark.parametrize("interface", INTERFACES, ids=IDS)
def test_rclpy_cdr_decodes_in_rosbags_and_back(interface):
    store = dynenv_typestore()
    for seed in range(5):
        message = sample_message(interface.cls, seed)
        decoded = store.deserialize_cdr(serialize_message(message), interface.name)
        assert field_differences(message, decoded) == []
        # rosbags' own encoding must decode in rclpy to the same values (bytes may differ in padding only).
        again = deserialize_message(bytes(store.serialize_cdr(decoded, interface.name)), interface.cls)
        assert field_differences(message, again) == []


@pytest.mark.parametrize("interface", INTERFACES, ids=IDS)
def test_rosbags_type_hash_equals_generated_hash(interface):
    assert dynenv_typestore().hash_rihs01(interface.name) == generated_type_hash(interface.name)


def test_messages_survive_an_mcap_bag(tmp_path):
    store = dynenv_typestore()
    messages = [t for t in INTERFACES if "/msg/" in t.name]
    written = {t.name: sample_message(t.cls, 5) for t in messages}
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for index, interface in enumerate(messages):
            connection = writer.add_connection(f"/{interface.short_name}", interface.name, typestore=store)
            writer.write(connection, 1_000 + index, serialize_message(written[interface.name]))
    with Reader(tmp_path / "bag") as reader:
        seen = {}
        for connection, _, raw in reader.messages():
            seen[connection.msgtype] = deserialize_message(raw, next(t.cls for t in messages
                                                                     if t.name == connection.msgtype))
    assert set(seen) == set(written)
    for name, message in written.items():
        assert field_differences(message, seen[name]) == []


# ---- The comparator every round-trip test relies on must see differences, or those tests prove nothing.

def _detection_array():
    """A DetectionArray with three detections, and an independent copy of it (through CDR)."""
    message = sample_message(DetectionArray, 1)
    message.robot_id, message.self_fallen = 5, True
    message.header.stamp.sec, message.header.frame_id = 12, "team_b_0/camera"
    message.detections = [sample_message(Detection, k) for k in range(3)]
    for k, detection in enumerate(message.detections):
        detection.confidence, detection.yaw = 0.5 + 0.125 * k, 0.25 * k
        detection.position.x = 1.0 + k
    copy = deserialize_message(serialize_message(message), DetectionArray)
    assert field_differences(message, copy) == []
    return message, copy


def test_comparator_reports_a_changed_scalar():
    message, copy = _detection_array()
    copy.robot_id = 6
    assert field_differences(message, copy) == ["<msg>.robot_id: 5 != 6"]
    message, copy = _detection_array()
    copy.self_fallen = False
    assert field_differences(message, copy) == ["<msg>.self_fallen: True != False"]
    message, copy = _detection_array()
    copy.header.frame_id = "team_b_1/camera"
    assert field_differences(message, copy) == ["<msg>.header.frame_id: 'team_b_0/camera' != 'team_b_1/camera'"]


def test_comparator_reports_a_changed_nested_field():
    message, copy = _detection_array()
    copy.header.stamp.sec = 13
    assert field_differences(message, copy) == ["<msg>.header.stamp.sec: 12 != 13"]
    message, copy = _detection_array()
    copy.detections[2].position.x = 3.5
    assert field_differences(message, copy) == ["<msg>.detections[2].position.x: 3.0 != 3.5"]


def test_comparator_reports_a_changed_array_element():
    message, copy = _detection_array()
    copy.detections[1].confidence = 0.75
    assert field_differences(message, copy) == ["<msg>.detections[1].confidence: 0.625 != 0.75"]
    world, other = sample_message(WorldState, 0), sample_message(WorldState, 0)
    world.last_touch_robot_ids, other.last_touch_robot_ids = [3, 0, 2], [3, 1, 2]     # a primitive sequence
    assert field_differences(world, other) == ["<msg>.last_touch_robot_ids[1]: 0 != 1"]


def test_comparator_reports_a_changed_array_length():
    message, copy = _detection_array()
    copy.detections = copy.detections[:2]
    assert field_differences(message, copy) == ["<msg>.detections: length 3 != 2"]
    message, copy = _detection_array()
    copy.detections = []
    assert field_differences(message, copy) == ["<msg>.detections: length 3 != 0"]
    world, other = sample_message(WorldState, 0), sample_message(WorldState, 0)
    world.last_touch_robot_ids, other.last_touch_robot_ids = [3, 0], [3, 0, 2]
    assert field_differences(world, other) == ["<msg>.last_touch_robot_ids: length 2 != 3"]


def test_comparator_tells_nan_from_a_number_and_matches_nan_with_nan():
    message, copy = _detection_array()
    message.detections[0].yaw = float("nan")
    assert field_differences(message, copy) == ["<msg>.detections[0].yaw: nan != 0.0"]
    assert field_differences(copy, message) == ["<msg>.detections[0].yaw: 0.0 != nan"]
    copy.detections[0].yaw = float("nan")                # NaN means "undefined": it must round-trip as NaN
    assert field_differences(message, copy) == []


def test_comparator_reports_every_difference_and_works_across_rclpy_and_rosbags():
    message, _ = _detection_array()
    decoded = dynenv_typestore().deserialize_cdr(serialize_message(message), "dynenv_msgs/msg/DetectionArray")
    assert field_differences(message, decoded) == []
    decoded.robot_id = 7
    decoded.detections[1].confidence = 0.0
    decoded.detections = decoded.detections + [decoded.detections[0]]
    assert field_differences(message, decoded) == ["<msg>.robot_id: 5 != 7", "<msg>.detections: length 3 != 4"]
    decoded.detections = decoded.detections[:3]
    assert field_differences(message, decoded) == ["<msg>.robot_id: 5 != 7",
                                                   "<msg>.detections[1].confidence: 0.625 != 0.0"]
