"""(a) Every message type round-trips through a publisher/subscriber pair in one process; every service answers."""
from __future__ import annotations

import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy

from dynenv_ros.ros.interfaces import field_differences, message_types, sample_message, service_types
from ros_harness import spin_until

MESSAGES = message_types()


@pytest.mark.parametrize("interface", MESSAGES, ids=[t.short_name for t in MESSAGES])
def test_message_round_trips_in_one_process(interface, make_node, executor):
    sent = [sample_message(interface.cls, seed) for seed in range(3)]
    received = []
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    publisher_node, subscriber_node = make_node("pub"), make_node("sub")
    subscriber_node.create_subscription(interface.cls, "roundtrip", received.append, qos)
    publisher = publisher_node.create_publisher(interface.cls, "roundtrip", qos)
    for node in (publisher_node, subscriber_node):
        executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1, 10.0)
    for message in sent:
        publisher.publish(message)
    assert spin_until(executor, lambda: len(received) == len(sent), 10.0), f"received {len(received)} of 3"
    for expected, actual in zip(sent, received):
        assert field_differences(expected, actual) == []


def test_nan_marks_undefined_yaw_and_survives_transport(make_node, executor):
    from dynenv_msgs.msg import Detection
    received = []
    node = make_node("nan")
    node.create_subscription(Detection, "nan", received.append, 10)
    publisher = node.create_publisher(Detection, "nan", 10)
    executor.add_node(node)
    assert spin_until(executor, lambda: publisher.get_subscription_count() == 1)
    publisher.publish(Detection(class_id=Detection.CLASS_BALL, yaw=float("nan")))
    assert spin_until(executor, lambda: received)
    assert received[0].yaw != received[0].yaw  # NaN


@pytest.mark.parametrize("name", sorted(service_types()))
def test_service_round_trips_in_one_process(name, make_node, executor):
    service_cls = service_types()[name]
    requests = []
    answer = sample_message(service_cls.Response, 7)

    def handle(request, response):
        requests.append(request)
        return answer

    server, client_node = make_node("server"), make_node("client")
    server.create_service(service_cls, "service", handle)
    client = client_node.create_client(service_cls, "service")
    for node in (server, client_node):
        executor.add_node(node)
    assert spin_until(executor, client.service_is_ready)
    request = sample_message(service_cls.Request, 3)
    future = client.call_async(request)
    assert spin_until(executor, future.done)
    assert field_differences(request, requests[0]) == []
    assert field_differences(answer, future.result()) == []
