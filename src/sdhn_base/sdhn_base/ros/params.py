"""Typed parameter declarations (ros2/demos style), the one way every node declares: a
``ParameterDescriptor`` per parameter, with type, description and range, so ROS itself rejects a
wrong type or an out-of-range value.

    PARAMETERS = {
        "episodes": (0, integer("episodes to run, then stop; 0 = until stopped", 0)),
        "step_deadline": (1.0, floating("seconds to wait for all N actions", 0.001, 3600.0)),
        "env": ("maif-10", string("environment", constraints="one of maif-10, ...")),
    }
    p = declare(self, PARAMETERS)

``constraints`` says in words what a check beyond the type allows (the node checks it after
declaring); ``read_only`` parameters cannot be set on a running node. A rejected value becomes a
:class:`~sdhn_base.errors.ConfigError` naming the parameter and what is allowed, in one bounded
line, so the node exits 2 before it creates any topic.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

from sdhn_base.errors import ConfigError

INT_MAX = 2**31 - 1
DETAIL_CHARS = 160  # rclpy's reason for a rejected value quotes the value: keep the line short


def integer(description: str, lo: int = -INT_MAX, hi: int = INT_MAX, *, constraints: str = "",
            read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_INTEGER, description=description,
        additional_constraints=constraints, read_only=read_only,
        integer_range=[IntegerRange(from_value=lo, to_value=hi, step=1)])


def floating(description: str, lo: float, hi: float, *, constraints: str = "",
             read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE, description=description,
        additional_constraints=constraints, read_only=read_only,
        floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi, step=0.0)])


def string(description: str, *, constraints: str = "", read_only: bool = False
           ) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_STRING, description=description,
                               additional_constraints=constraints, read_only=read_only)


def any_number(description: str, *, constraints: str = "") -> ParameterDescriptor:
    """Dynamically typed: ``:=0`` and ``:=0.5`` both pass (a double descriptor refuses an
    integer); the node checks the value itself and names ``constraints`` when it refuses."""
    return ParameterDescriptor(dynamic_typing=True, description=description,
                               additional_constraints=constraints)


def boolean(description: str, *, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_BOOL, description=description,
                               read_only=read_only)


def allowed(d: ParameterDescriptor) -> str:
    """What a descriptor allows, in words (for error messages)."""
    if d.additional_constraints:
        return str(d.additional_constraints)
    if d.integer_range:
        r = d.integer_range[0]
        return f"integers in [{r.from_value}, {r.to_value}]"
    if d.floating_point_range:
        r = d.floating_point_range[0]
        return f"numbers in [{r.from_value}, {r.to_value}] (write 1.0, not 1)"
    return {ParameterType.PARAMETER_STRING: "a string", ParameterType.PARAMETER_BOOL:
            "true or false"}.get(d.type, "a value of the declared type")


def declare(node: Node, spec: Mapping[str, tuple[Any, ParameterDescriptor]]) -> dict[str, Any]:
    """Declare every parameter of ``spec`` (name -> (default, descriptor)); returns the values."""
    values: dict[str, Any] = {}
    for name, (default, descriptor) in spec.items():
        try:
            values[name] = node.declare_parameter(name, default, descriptor).value
        except (InvalidParameterTypeException, InvalidParameterValueException) as e:
            detail = str(e).splitlines()[0].split("Reason: ")[-1].removesuffix(f": {name}")
            raise ConfigError(f"{name}: {detail[:DETAIL_CHARS]}; allowed: {allowed(descriptor)}"
                              ) from None
    return values
