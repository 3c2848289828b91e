"""Declaring node parameters with descriptors and ranges, so bad values are refused with a reason."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node


def declare_int(node: Node, name: str, default: int, low: int, high: int, description: str,
                read_only: bool = False) -> int:
    descriptor = ParameterDescriptor(description=description, read_only=read_only,
                                     integer_range=[IntegerRange(from_value=low, to_value=high, step=1)])
    return node.declare_parameter(name, default, descriptor).value


def declare_float(node: Node, name: str, default: float, low: float, high: float, description: str,
                  read_only: bool = False) -> float:
    _integer_override_to_double(node, name)
    descriptor = ParameterDescriptor(description=description, read_only=read_only,
                                     floating_point_range=[FloatingPointRange(from_value=low, to_value=high)])
    return node.declare_parameter(name, default, descriptor).value


def declare_str(node: Node, name: str, default: str, description: str, read_only: bool = False,
                choices: tuple[str, ...] = ()) -> str:
    """A string parameter; with ``choices`` the allowed values are listed in the descriptor and checked now
    (later changes are checked by the node's on-set callback, see ``check_choice``)."""
    constraints = f"one of: {', '.join(choices)}" if choices else ""
    value = node.declare_parameter(name, default, ParameterDescriptor(
        description=description, read_only=read_only, additional_constraints=constraints)).value
    if choices and value not in choices:
        from rclpy.exceptions import ParameterException
        raise ParameterException(f"'{value}' is not {constraints}", [name])
    return value


def declare_bool(node: Node, name: str, default: bool, description: str, read_only: bool = False) -> bool:
    return node.declare_parameter(name, default, ParameterDescriptor(description=description,
                                                                     read_only=read_only)).value


def declare_str_list(node: Node, name: str, default: list[str], description: str, read_only: bool = False
                     ) -> list[str]:
    from rcl_interfaces.msg import ParameterType
    descriptor = ParameterDescriptor(description=description, read_only=read_only,
                                     type=ParameterType.PARAMETER_STRING_ARRAY)
    value = node.declare_parameter(name, default or [""], descriptor).value
    return [v for v in value if v]


def refuse_other_scenario(node: Node, scenario: str, parameters: dict[str, tuple[str, ...]]) -> None:
    """Refuse (ParameterException naming them) the parameters given to ``node`` (``-p``, a params file,
    ``parameter_overrides``) that belong to a scenario other than ``scenario``: each scenario's are declared so
    ``--help`` lists them all, but one set for the other scenario would silently change nothing."""
    given = set(getattr(node, "_parameter_overrides", {}) or {})
    for other, names in parameters.items():
        wrong = sorted(given & (set(names) - set(parameters.get(scenario, ()))))
        if other != scenario and wrong:
            from rclpy.exceptions import ParameterException
            raise ParameterException(f"{', '.join(wrong)}: a parameter of scenario '{other}', not of '{scenario}' "
                                     f"(it uses {', '.join(parameters.get(scenario, ())) or 'none of them'})", wrong)


def _integer_override_to_double(node: Node, name: str) -> None:
    """``-p rate:=2`` arrives as an integer and rclpy refuses it for a double parameter; take it as 2.0."""
    from rclpy.parameter import Parameter
    overrides = getattr(node, "_parameter_overrides", None)
    if not isinstance(overrides, dict) or name not in overrides:
        return
    override = overrides[name]
    if override.type_ == Parameter.Type.INTEGER:
        overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(override.value))
