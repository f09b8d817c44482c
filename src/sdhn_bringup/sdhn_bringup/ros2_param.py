"""``ros2 param list|get|set|dump``, through the standard parameter services of each node
(``<node>/list_parameters``, ``get_parameters``, ``set_parameters``; rclpy's
``AsyncParameterClient``), with ros2cli's output.

- ``list [NODE] [--param-type] [--filter REGEX]``: ``/node:`` then the names, indented, sorted
  (with NODE only its names).
- ``get NODE NAME [--hide-type]``: ``Integer value is: 3``, ``Double value is: 0.5``...
- ``set NODE NAME VALUE``: VALUE is read as YAML (``3`` integer, ``3.0`` double, ``true``,
  ``[1, 2]``...), as ros2cli reads it; ``Set parameter successful`` or ``Set parameter failed:
  <the node's reason>`` (exit code 1).
- ``dump NODE``: ``/node: {ros__parameters: {...}}`` as YAML on stdout (a params file that
  ``--ros-args --params-file`` reads back; dotted names nest).
"""

from __future__ import annotations

import argparse
import re
import sys
from typing import Any

import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.parameter import get_parameter_value, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.task import Future

from sdhn_base.ros.graph import DEFAULT_SPIN_TIME_S, GraphNode, absolute_name
from sdhn_bringup.ros2_node import node_names

SERVICE_TIMEOUT_S = 5.0  # waiting for a node's parameter services, then for its answer
TYPE_WORDS = {  # ros2cli's "<Type> value is:" words
    ParameterType.PARAMETER_BOOL: "Boolean value is",
    ParameterType.PARAMETER_INTEGER: "Integer value is",
    ParameterType.PARAMETER_DOUBLE: "Double value is",
    ParameterType.PARAMETER_STRING: "String value is",
    ParameterType.PARAMETER_BYTE_ARRAY: "Byte values are",
    ParameterType.PARAMETER_BOOL_ARRAY: "Boolean values are",
    ParameterType.PARAMETER_INTEGER_ARRAY: "Integer values are",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "Double values are",
    ParameterType.PARAMETER_STRING_ARRAY: "String values are",
}
TYPE_NAMES = {ParameterType.PARAMETER_BOOL: "boolean", ParameterType.PARAMETER_INTEGER: "integer",
              ParameterType.PARAMETER_DOUBLE: "double", ParameterType.PARAMETER_STRING: "string",
              ParameterType.PARAMETER_BYTE_ARRAY: "byte array",
              ParameterType.PARAMETER_BOOL_ARRAY: "boolean array",
              ParameterType.PARAMETER_INTEGER_ARRAY: "integer array",
              ParameterType.PARAMETER_DOUBLE_ARRAY: "double array",
              ParameterType.PARAMETER_STRING_ARRAY: "string array"}


class NoAnswer(RuntimeError):
    """A node's parameter services did not answer within SERVICE_TIMEOUT_S."""


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ros2 param")
    sub = p.add_subparsers(dest="verb", required=True)
    ls = sub.add_parser("list", help="the parameters of one or every node")
    ls.add_argument("node_name", nargs="?", default=None)
    ls.add_argument("--param-type", action="store_true", help="also each parameter's type")
    ls.add_argument("--filter", default=None, help="only names matching this regex")
    get = sub.add_parser("get", help="one parameter's value")
    get.add_argument("node_name")
    get.add_argument("parameter_name")
    get.add_argument("--hide-type", action="store_true")
    put = sub.add_parser("set", help="set one parameter")
    put.add_argument("node_name")
    put.add_argument("parameter_name")
    put.add_argument("value")
    dump = sub.add_parser("dump", help="every parameter of a node, as a params file")
    dump.add_argument("node_name")
    for s in (ls, get, put, dump):
        s.add_argument("--spin-time", type=float, default=DEFAULT_SPIN_TIME_S)
    return p


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    with GraphNode(args.spin_time) as g:
        wanted = [absolute_name(args.node_name)] if args.node_name else []

        def discovered() -> bool:  # the named node, or (none named) any node at all
            names = node_names(g, include_hidden=False)
            return bool(names) and set(wanted) <= set(names)

        g.wait_for(discovered)
        nodes = node_names(g, include_hidden=False)
        wanted = wanted or nodes
        missing = [n for n in wanted if n not in nodes]
        if missing:
            print(f"Node not found: {missing[0]}", file=sys.stderr)
            return 1
        try:
            if args.verb == "list":
                return param_list(g, wanted, args.param_type, args.filter,
                                  header=args.node_name is None)
            client = AsyncParameterClient(g.node, wanted[0])
            if not client.wait_for_services(SERVICE_TIMEOUT_S):
                raise NoAnswer(f"{wanted[0]}: no parameter services")
            if args.verb == "get":
                return param_get(g, client, args.parameter_name, args.hide_type)
            if args.verb == "set":
                return param_set(g, client, args.parameter_name, args.value)
            return param_dump(g, client, wanted[0])
        except NoAnswer as e:
            print(f"ros2 param: {e} within {SERVICE_TIMEOUT_S}s", file=sys.stderr)
            return 1


def wait(g: GraphNode, future: Future, what: str) -> Any:
    g.executor.spin_until_future_complete(future, timeout_sec=SERVICE_TIMEOUT_S)
    if not future.done() or future.result() is None:
        raise NoAnswer(f"no answer to {what}")
    return future.result()


def names_of(g: GraphNode, client: AsyncParameterClient) -> list[str]:
    return sorted(wait(g, client.list_parameters(), "list_parameters").result.names)


def values_of(g: GraphNode, client: AsyncParameterClient, names: list[str]
              ) -> list[ParameterValue]:
    return list(wait(g, client.get_parameters(names), "get_parameters").values)


def param_list(g: GraphNode, nodes: list[str], with_type: bool, pattern: str | None,
               header: bool) -> int:
    regex = re.compile(pattern) if pattern else None
    for node in nodes:
        client = AsyncParameterClient(g.node, node)
        if not client.wait_for_services(SERVICE_TIMEOUT_S):
            print(f"Wait for service timed out waiting for parameter services for node {node}",
                  file=sys.stderr)
            continue
        names = [n for n in names_of(g, client) if regex is None or regex.search(n)]
        types = [v.type for v in values_of(g, client, names)] if with_type else []
        if header:
            print(f"{node}:")
        for i, name in enumerate(names):
            print(f"  {name} (type: {TYPE_NAMES.get(types[i], 'not set')})" if with_type
                  else f"  {name}")
    return 0


def param_get(g: GraphNode, client: AsyncParameterClient, name: str, hide_type: bool) -> int:
    values = values_of(g, client, [name])
    if not values or values[0].type == ParameterType.PARAMETER_NOT_SET:
        print("Parameter not set.")
        return 1
    value = parameter_value_to_python(values[0])
    print(value if hide_type else f"{TYPE_WORDS[values[0].type]}: {value}")
    return 0


def param_set(g: GraphNode, client: AsyncParameterClient, name: str, text: str) -> int:
    msg = ParameterMsg(name=name, value=get_parameter_value(string_value=text))
    result = wait(g, client.set_parameters([msg]), "set_parameters").results[0]
    line = "Set parameter successful" if result.successful else "Set parameter failed"
    line += f": {result.reason}" if result.reason else ""
    print(line, file=sys.stdout if result.successful else sys.stderr)
    return 0 if result.successful else 1


def nest(flat: dict[str, Any]) -> dict[str, Any]:
    """Dotted parameter names as nested mappings, as a params file spells them."""
    out: dict[str, Any] = {}
    for name, value in sorted(flat.items()):
        *parents, leaf = name.split(".")
        here = out
        for part in parents:
            here = here.setdefault(part, {})
        here[leaf] = value
    return out


def plain(value: Any) -> Any:
    """A parameter's Python value as YAML writes it plainly (arrays as lists)."""
    if isinstance(value, bytes | bytearray):
        return list(value)
    if hasattr(value, "tolist"):
        return value.tolist()
    return list(value) if isinstance(value, list | tuple) else value


def param_dump(g: GraphNode, client: AsyncParameterClient, node: str) -> int:
    names = names_of(g, client)
    values = values_of(g, client, names)
    flat = {n: plain(parameter_value_to_python(v)) for n, v in zip(names, values, strict=True)}
    sys.stdout.write(yaml.dump({node: {"ros__parameters": nest(flat)}}, default_flow_style=False,
                               sort_keys=False))
    return 0
