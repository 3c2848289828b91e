"""(b) Every interface arrives intact from a publisher (and service server) in another process."""
from __future__ import annotations

import subprocess
import sys

import pytest

from dynenv_ros.ros.interfaces import field_differences, message_types, sample_message, service_types
from dynenv_ros.ros.qos import latched
from dynenv_ros.ros.selfcheck import expected_message, expected_response, sample_seed, service_name_for, \
    topic_for
from ros_harness import call_idempotent, spin_until

SEED, SAMPLES = 11, 4


@pytest.fixture
def talker_process():
    process = subprocess.Popen([sys.executable, "-m", "dynenv_ros.nodes.selfcheck_talker", "--ros-args",
                                "-p", f"seed:={SEED}", "-p", f"samples_per_type:={SAMPLES}"],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    yield process
    process.terminate()
    try:
        process.wait(10)
    except subprocess.TimeoutExpired:
        process.kill()


def test_every_message_type_arrives_from_another_process(talker_process, make_node, executor):
    node = make_node("receiver")
    received = {t.name: [] for t in message_types()}
    for interface in message_types():
        node.create_subscription(interface.cls, topic_for(interface), received[interface.name].append,
                                 latched(SAMPLES))
    executor.add_node(node)
    arrived = spin_until(executor, lambda: all(len(v) == SAMPLES for v in received.values()), 30.0)
    assert arrived, {name: len(messages) for name, messages in received.items()}
    for interface in message_types():
        for index, message in enumerate(received[interface.name]):
            assert field_differences(expected_message(interface, SEED, index), message) == [], interface.name


@pytest.mark.parametrize("name", sorted(service_types()))
def test_every_service_answers_from_another_process(name, talker_process, make_node, executor):
    service_cls = service_types()[name]
    node = make_node("caller")
    client = node.create_client(service_cls, service_name_for(name))
    executor.add_node(node)
    assert spin_until(executor, client.service_is_ready, 30.0)
    request = sample_message(service_cls.Request, sample_seed(SEED, 0))
    response = call_idempotent(executor, client, request)       # the echo server answers any number of calls
    assert response is not None
    assert field_differences(expected_response(service_cls, request), response) == []
