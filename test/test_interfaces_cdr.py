"""(c) Every interface round-trips through CDR with rosbags, using a typestore built from the .msg/.srv files."""
from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

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
