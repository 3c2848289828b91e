"""The generated Python class of a ROS message type name, as the bag tools need it for raw subscriptions and
republishing."""
from __future__ import annotations

import importlib


def message_class(type_name: str) -> type:
    """The generated Python class of "pkg/msg/Name" (what rosidl_runtime_py.utilities.get_message does; that
    package is not among our PyPI wheels)."""
    try:
        package, kind, name = type_name.split("/")
    except ValueError:
        raise ValueError(f"not a ROS message type name: {type_name!r} (expected pkg/msg/Name)") from None
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError) as error:
        raise ImportError(f"message type {type_name} is not installed: {error}") from error


__all__ = ["message_class"]
