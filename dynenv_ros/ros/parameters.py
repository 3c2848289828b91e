"""Declaring node parameters with descriptors and ranges, so bad values are refused with a reason."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node


def declare_int(node: Node, name: str, default: int, low: int, high: int, description: str) -> int:
    descriptor = ParameterDescriptor(description=description,
                                     integer_range=[IntegerRange(from_value=low, to_value=high, step=1)])
    return node.declare_parameter(name, default, descriptor).value


def declare_float(node: Node, name: str, default: float, low: float, high: float, description: str) -> float:
    descriptor = ParameterDescriptor(description=description,
                                     floating_point_range=[FloatingPointRange(from_value=low, to_value=high)])
    return node.declare_parameter(name, default, descriptor).value


def declare_str(node: Node, name: str, default: str, description: str) -> str:
    return node.declare_parameter(name, default, ParameterDescriptor(description=description)).value
