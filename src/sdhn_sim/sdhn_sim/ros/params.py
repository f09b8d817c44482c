"""Typed parameter declarations (ros2/demos style): a ``ParameterDescriptor`` per parameter, with
type, description and range, so ROS itself rejects a wrong type or an out-of-range value.

    p = declare(self, {
        "episodes": (0, integer("episodes to run, then stop; 0 = until stopped", 0)),
        "step_deadline": (1.0, floating("seconds to wait for all N actions", 0.001, 3600.0)),
    })

A rejected value becomes a :class:`~sdhn_sim.ros.runner.ConfigError` naming the parameter, so the
node exits 2 with one line before it creates any topic.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

from sdhn_sim.ros.runner import ConfigError

INT_MAX = 2**31 - 1


def integer(description: str, lo: int = -INT_MAX, hi: int = INT_MAX) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_INTEGER, description=description,
        integer_range=[IntegerRange(from_value=lo, to_value=hi, step=1)])


def floating(description: str, lo: float, hi: float) -> ParameterDescriptor:
    return ParameterDescriptor(
        type=ParameterType.PARAMETER_DOUBLE, description=description,
        floating_point_range=[FloatingPointRange(from_value=lo, to_value=hi, step=0.0)])


def string(description: str) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_STRING, description=description)


def boolean(description: str) -> ParameterDescriptor:
    return ParameterDescriptor(type=ParameterType.PARAMETER_BOOL, description=description)


def allowed(d: ParameterDescriptor) -> str:
    """What a descriptor allows, in words (for error messages)."""
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
            raise ConfigError(f"{name}: {e}; allowed: {allowed(descriptor)}") from e
    return values
