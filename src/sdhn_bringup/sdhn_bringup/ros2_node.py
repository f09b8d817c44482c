"""``ros2 node list|info``, on rclpy's graph API, with ros2cli's flags and output.

- ``list [-a] [-c]``: full node names, sorted; hidden ones (a part starting with '_', like this
  tool's own node) only with ``-a``.
- ``info NODE [--include-hidden]``: the node's subscribers, publishers, service servers and
  clients, action servers and clients, each ``name: type``, in ros2cli's layout.
"""

from __future__ import annotations

import argparse
import sys

from rclpy.action import (
    get_action_client_names_and_types_by_node,
    get_action_server_names_and_types_by_node,
)

from sdhn_base.ros.graph import DEFAULT_SPIN_TIME_S, GraphNode, absolute_name, split_node_name
from sdhn_bringup.ros2_topic import hidden


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ros2 node")
    sub = p.add_subparsers(dest="verb", required=True)
    ls = sub.add_parser("list", help="the nodes of the graph")
    ls.add_argument("-a", "--all", action="store_true", help="also hidden nodes")
    ls.add_argument("-c", "--count-nodes", action="store_true")
    info = sub.add_parser("info", help="a node's endpoints")
    info.add_argument("node_name")
    info.add_argument("--include-hidden", action="store_true")
    for s in (ls, info):
        s.add_argument("--spin-time", type=float, default=DEFAULT_SPIN_TIME_S)
    return p


def node_names(g: GraphNode, include_hidden: bool) -> list[str]:
    names = {(ns.rstrip("/") + "/" + name) for name, ns in g.node.get_node_names_and_namespaces()}
    return sorted(n for n in names if include_hidden or not hidden(n))


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    with GraphNode(args.spin_time) as g:
        if args.verb == "list":
            names = node_names(g, args.all)
            if args.count_nodes:
                print(len(names))
            else:
                for name in names:
                    print(name)
            return 0
        return node_info(g, absolute_name(args.node_name), args.include_hidden)


def _section(title: str, entries: list[tuple[str, list[str]]], include_hidden: bool) -> None:
    print(f"  {title}:")
    # As ros2cli's print(*lines, sep='\n'): an empty section is one empty line.
    print("\n".join(f"    {name}: {', '.join(types)}" for name, types in sorted(entries)
                    if include_hidden or not hidden(name)))


def node_info(g: GraphNode, full: str, include_hidden: bool) -> int:
    if not g.wait_for(lambda: full in node_names(g, True)):
        print(f"Unable to find node '{full}'", file=sys.stderr)
        return 1
    ns, name = split_node_name(full)
    n = g.node
    print(full)
    _section("Subscribers", n.get_subscriber_names_and_types_by_node(name, ns), include_hidden)
    _section("Publishers", n.get_publisher_names_and_types_by_node(name, ns), include_hidden)
    _section("Service Servers", n.get_service_names_and_types_by_node(name, ns), include_hidden)
    _section("Service Clients", n.get_client_names_and_types_by_node(name, ns), include_hidden)
    _section("Action Servers", get_action_server_names_and_types_by_node(n, name, ns),
             include_hidden)
    _section("Action Clients", get_action_client_names_and_types_by_node(n, name, ns),
             include_hidden)
    return 0
