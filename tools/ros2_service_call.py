#!/usr/bin/env python3
"""``ros2 service call`` for the venv: the PyPI wheels have rclpy but no ros2cli.

Usage (the arguments of ``ros2 service call``)::

    .venv/bin/python tools/ros2_service_call.py /policy_node/load_policy dynenv_msgs/srv/LoadPolicy \\
        "{checkpoint_path: new.onnx, runtime: onnxruntime}"
    .venv/bin/python tools/ros2_service_call.py /policy_node/accept_older_weights std_srvs/srv/Trigger

VALUES is YAML, as for ros2cli: a mapping of request fields (nested mappings for nested messages). The call waits
for the service (``--timeout``), prints the response's fields as YAML and exits 0; a service that does not appear or
answer exits 1, a type or field that does not exist exits 2, each with a one-line reason. It joins the ROS domain
of ``ROS_DOMAIN_ID``, like every node here.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import Any

import yaml


class CallError(Exception):
    """A bad type or request (exit 2)."""


def service_type(name: str) -> Any:
    """``pkg/srv/Name`` -> the generated service class."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] != "srv":
        raise CallError(f"{name}: not a service type (pkg/srv/Name)")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.srv"), parts[2])
    except (ImportError, AttributeError) as error:
        raise CallError(f"service type {name} does not import: {error}") from None


def fill(message: Any, values: dict[str, Any], where: str = "") -> Any:
    """Set ``values`` on ``message`` (nested mappings on nested messages); an unknown field or a value of the
    wrong type is refused with its name."""
    fields = message.get_fields_and_field_types()
    for key, value in values.items():
        if key not in fields:
            raise CallError(f"{type(message).__name__} has no field {where}{key} (it has: {', '.join(fields)})")
        if isinstance(value, dict):
            fill(getattr(message, key), value, f"{where}{key}.")
            continue
        try:
            setattr(message, key, value)
        except (AssertionError, TypeError, ValueError) as error:
            raise CallError(f"{where}{key} = {value!r}: {error}") from None
    return message


def as_plain(message: Any) -> Any:
    """A response as plain data (nested messages as mappings) for printing."""
    if hasattr(message, "get_fields_and_field_types"):
        return {key: as_plain(getattr(message, key)) for key in message.get_fields_and_field_types()}
    if isinstance(message, (list, tuple)) or type(message).__name__ in ("ndarray", "array"):
        return [as_plain(item) for item in message]
    return message


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ros2_service_call.py", description=__doc__.splitlines()[0])
    parser.add_argument("service", help="service name, e.g. /policy_node/load_policy")
    parser.add_argument("type", help="service type, e.g. dynenv_msgs/srv/LoadPolicy")
    parser.add_argument("values", nargs="?", default="{}", help="request fields as YAML (default: {})")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the service and its answer")
    args = parser.parse_args(argv)
    try:
        kind = service_type(args.type)
        values = yaml.safe_load(args.values) or {}
        if not isinstance(values, dict):
            raise CallError(f"VALUES must be a YAML mapping of request fields, got {args.values!r}")
        request = fill(kind.Request(), values)
    except (CallError, yaml.YAMLError) as error:
        print(f"ros2_service_call.py: {error}", file=sys.stderr)
        return 2
    import rclpy
    rclpy.init()
    node = rclpy.create_node("ros2_service_call")
    try:
        client = node.create_client(kind, args.service)
        if not client.wait_for_service(timeout_sec=args.timeout):
            print(f"ros2_service_call.py: service {args.service} not available after {args.timeout:.0f} s",
                  file=sys.stderr)
            return 1
        print(f"requester: making request: {request}")
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
        if not future.done():
            print(f"ros2_service_call.py: no answer from {args.service} within {args.timeout:.0f} s", file=sys.stderr)
            return 1
        print("response:")
        print(yaml.safe_dump(as_plain(future.result()), sort_keys=False).rstrip())
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
