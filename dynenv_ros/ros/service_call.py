"""``ros2 service call`` for the venv (the PyPI wheels have rclpy but no ros2cli): a service type by name, a request
filled from a YAML mapping, one call and the response as plain data. Used by ``tools/ros2_service_call.py`` and by
``dynenv-keys call`` (which signs the request first, issue 43)."""
from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


class CallError(Exception):
    """A bad type or request (exit status 2)."""


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


def request_from_yaml(type_name: str, values_yaml: str) -> tuple[Any, Any]:
    """(service class, its request filled from a YAML mapping of fields), as ``ros2 service call`` reads them;
    CallError for an unknown type, YAML that is no mapping, or a field the request lacks."""
    import yaml
    kind = service_type(type_name)
    try:
        values = yaml.safe_load(values_yaml) or {}
    except yaml.YAMLError as error:
        raise CallError(f"VALUES is not YAML: {error}") from None
    if not isinstance(values, dict):
        raise CallError(f"VALUES must be a YAML mapping of request fields, got {values_yaml!r}")
    return kind, fill(kind.Request(), values)


def as_plain(message: Any) -> Any:
    """A message as plain data (nested messages as mappings, sequences as lists) for printing."""
    if hasattr(message, "get_fields_and_field_types"):
        return {key: as_plain(getattr(message, key)) for key in message.get_fields_and_field_types()}
    if isinstance(message, (list, tuple)) or type(message).__name__ in ("ndarray", "array"):
        return [as_plain(item) for item in message]
    if type(message).__module__ == "numpy":
        return message.item()
    return message


def call(service: str, kind: Any, request: Any, timeout_s: float,
         prepare: Callable[[Any], Any] | None = None) -> tuple[Any | None, str]:
    """Call ``service`` once; (response, "") or (None, why not). ``prepare`` turns the request into the one sent
    once the service is there (``dynenv-keys call`` signs then, so waiting for discovery does not age the
    signature). Joins the domain of ``ROS_DOMAIN_ID``."""
    import rclpy
    rclpy.init()
    node = rclpy.create_node("service_call")
    try:
        client = node.create_client(kind, service)
        if not client.wait_for_service(timeout_sec=timeout_s):
            return None, f"service {service} not available after {timeout_s:.0f} s"
        future = client.call_async(prepare(request) if prepare else request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=timeout_s)
        if not future.done():
            return None, f"no answer from {service} within {timeout_s:.0f} s"
        return future.result(), ""
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
