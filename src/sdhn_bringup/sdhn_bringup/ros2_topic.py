"""``ros2 topic list|echo|hz|info``, on rclpy's graph API, with ros2cli's flags and output.

- ``list [-t] [-c] [--include-hidden-topics]``: one name a line, sorted; ``-t`` adds
  ``[pkg/msg/Type]``.
- ``echo TOPIC [TYPE] [--once] [--qos-reliability R] [--qos-durability D] [--qos-depth N]
  [--field a.b] [--no-arr] [--no-str] [--truncate-length N | --full-length]``: each message as
  YAML then ``---``. Without a --qos flag the profile is chosen as ros2cli does: depth 10, reliable
  when every publisher is, transient-local when every publisher is; with one, the others start
  from the sensor-data profile (best effort, volatile, depth 5).
- ``hz TOPIC [--window N]``: every second ``average rate``, min/max/std dev of the intervals and
  the window, until Ctrl-C.
- ``info TOPIC [-v]``: type and endpoint counts; ``-v`` also each endpoint (node, GID, QoS).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time
from typing import Any

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.serialization import deserialize_message

from sdhn_base.ros.graph import (
    DEFAULT_SPIN_TIME_S,
    GraphNode,
    absolute_name,
    check_message_type,
    message_class,
)
from sdhn_bringup.ros2_yaml import DEFAULT_TRUNCATE, convert, field_value, to_yaml

RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT,
               "system_default": ReliabilityPolicy.SYSTEM_DEFAULT}
DURABILITY = {"volatile": DurabilityPolicy.VOLATILE,
              "transient_local": DurabilityPolicy.TRANSIENT_LOCAL,
              "system_default": DurabilityPolicy.SYSTEM_DEFAULT}
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"  # Fast DDS's name of an endpoint whose node is not known yet
HZ_PERIOD_S = 1.0  # ros2 topic hz prints once a second
DEFAULT_WINDOW = 10000


def hidden(name: str) -> bool:
    """A hidden topic or node name: one of its parts starts with '_' (ros2cli's rule)."""
    return any(part.startswith("_") for part in name.split("/"))


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ros2 topic")
    sub = p.add_subparsers(dest="verb", required=True)
    ls = sub.add_parser("list", help="the topics of the graph")
    ls.add_argument("-t", "--show-types", action="store_true")
    ls.add_argument("-c", "--count-topics", action="store_true")
    ls.add_argument("--include-hidden-topics", action="store_true")
    echo = sub.add_parser("echo", help="print the messages of a topic")
    echo.add_argument("topic_name")
    echo.add_argument("message_type", nargs="?", default=None)
    echo.add_argument("--once", action="store_true", help="print the first message and exit")
    echo.add_argument("--qos-reliability", choices=sorted(RELIABILITY))
    echo.add_argument("--qos-durability", choices=sorted(DURABILITY))
    echo.add_argument("--qos-depth", type=int, default=None)
    echo.add_argument("--field", default=None, help="print only this (nested) field, a.b")
    echo.add_argument("--no-arr", action="store_true", help="print arrays' types, not values")
    echo.add_argument("--no-str", action="store_true", help="print strings' lengths only")
    echo.add_argument("-l", "--truncate-length", type=int, default=DEFAULT_TRUNCATE)
    echo.add_argument("-f", "--full-length", action="store_true", help="never truncate")
    hz = sub.add_parser("hz", help="print the rate of a topic")
    hz.add_argument("topic_name")
    hz.add_argument("-w", "--window", type=int, default=DEFAULT_WINDOW)
    info = sub.add_parser("info", help="type, publishers and subscriptions of a topic")
    info.add_argument("topic_name")
    info.add_argument("-v", "--verbose", action="store_true")
    for s in (ls, echo, hz, info):
        s.add_argument("--spin-time", type=float, default=DEFAULT_SPIN_TIME_S,
                       help="seconds to wait for discovery first (ros2cli's, without a daemon)")
    return p


def main(argv: list[str]) -> int:
    args = parser().parse_args(argv)
    if args.verb == "echo" and args.message_type is not None:
        # The command line is checked before a node starts: a refused type imports nothing.
        try:
            check_message_type(args.message_type, "message_type")
        except ValueError as e:
            print(f"ros2 topic echo: error: {e}", file=sys.stderr)
            return 2
    with GraphNode(args.spin_time) as g:
        if args.verb == "list":
            return topic_list(g, args)
        if args.verb == "info":
            return topic_info(g, absolute_name(args.topic_name), args.verbose)
        # echo and hz run until Ctrl-C, which ends them with exit code 0, as in ros2cli.
        signal.signal(signal.SIGINT, lambda *_: g.context.try_shutdown())
        signal.signal(signal.SIGTERM, lambda *_: g.context.try_shutdown())
        if args.verb == "echo":
            return echo(g, args)
        return hz(g, absolute_name(args.topic_name), args.window)


def topic_list(g: GraphNode, args: argparse.Namespace) -> int:
    found = sorted((name, types) for name, types in g.node.get_topic_names_and_types()
                   if args.include_hidden_topics or not hidden(name))
    if args.count_topics:
        print(len(found))
        return 0
    for name, types in found:
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def topic_types(g: GraphNode, topic: str, wait: bool = True) -> list[str]:
    """The topic's types, waiting up to NAMED_WAIT_S for it to be discovered."""
    def lookup() -> list[str]:
        return next((t for name, t in g.node.get_topic_names_and_types() if name == topic), [])

    return g.wait_for(lookup) if wait else lookup()


def topic_info(g: GraphNode, topic: str, verbose: bool) -> int:
    types = topic_types(g, topic)
    if not types:
        print(f"Unknown topic '{topic}'", file=sys.stderr)
        return 1
    end = "\n\n" if verbose else "\n"
    if verbose:
        # An endpoint is discovered before its participant's node names arrive: Fast DDS names
        # it _NODE_NAME_UNKNOWN_ meanwhile. Wait (bounded) for the names rather than print that.
        g.wait_for(lambda: not any(
            e.node_name == UNKNOWN_NODE for e in (*g.node.get_publishers_info_by_topic(topic),
                                                   *g.node.get_subscriptions_info_by_topic(topic))))
    print(f"Type: {types[0] if len(types) == 1 else types}", end=end)
    print(f"Publisher count: {g.node.count_publishers(topic)}", end=end)
    if verbose:
        for endpoint in g.node.get_publishers_info_by_topic(topic):
            print(endpoint, end=end)
    print(f"Subscription count: {g.node.count_subscribers(topic)}", end=end)
    if verbose:
        for endpoint in g.node.get_subscriptions_info_by_topic(topic):
            print(endpoint, end=end)
    return 0


def choose_qos(g: GraphNode, topic: str, reliability: str | None, durability: str | None,
               depth: int | None) -> QoSProfile:
    """ros2cli's rule: explicit flags start from sensor data; otherwise match the publishers."""
    if reliability is not None or durability is not None or depth is not None:
        base = qos_profile_sensor_data
        return QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=depth if depth is not None else base.depth,
            reliability=RELIABILITY[reliability] if reliability else base.reliability,
            durability=DURABILITY[durability] if durability else base.durability)
    profile = QoSProfile(depth=10)
    publishers = g.node.get_publishers_info_by_topic(topic)
    if not publishers:
        return profile
    reliable = sum(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers)
    latched = sum(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                  for p in publishers)
    profile.reliability = (ReliabilityPolicy.RELIABLE if reliable == len(publishers)
                           else ReliabilityPolicy.BEST_EFFORT)
    profile.durability = (DurabilityPolicy.TRANSIENT_LOCAL if latched == len(publishers)
                          else DurabilityPolicy.VOLATILE)
    if 0 < reliable < len(publishers):
        print("Some, but not all, publishers are offering RELIABLE reliability. Falling back to "
              "BEST_EFFORT as it will connect to all publishers. Some messages from Reliable "
              "publishers could be dropped.", file=sys.stderr)
    if 0 < latched < len(publishers):
        print("Some, but not all, publishers are offering TRANSIENT_LOCAL durability. Falling "
              "back to VOLATILE as it will connect to all publishers. Previously-published "
              "latched messages will not be retrieved.", file=sys.stderr)
    return profile


def echo(g: GraphNode, args: argparse.Namespace) -> int:
    topic = absolute_name(args.topic_name)
    type_name = args.message_type or next(iter(topic_types(g, topic)), None)
    if type_name is None:
        print(f"Could not determine the type for the passed topic '{topic}'", file=sys.stderr)
        return 1
    try:
        cls = message_class(type_name)
    except ValueError as e:
        print(f"ros2 topic echo: {e}", file=sys.stderr)
        return 1
    truncate = None if args.full_length else args.truncate_length
    printed = 0

    def on_message(data: bytes) -> None:
        nonlocal printed
        if args.once and printed:
            return
        msg = deserialize_message(data, cls)
        if args.field is not None:
            value = convert(field_value(msg, args.field), "", truncate, args.no_arr, args.no_str)
            text = to_yaml_value(value)
        else:
            text = to_yaml(msg, truncate, args.no_arr, args.no_str)
        sys.stdout.write(text + "---\n")
        sys.stdout.flush()
        printed += 1
        if args.once:
            g.context.try_shutdown()

    qos = choose_qos(g, topic, args.qos_reliability, args.qos_durability, args.qos_depth)
    if args.field is not None:
        try:
            field_value(cls(), args.field)
        except ValueError as e:
            print(f"ros2 topic echo: {e}", file=sys.stderr)
            return 1
    g.node.create_subscription(cls, topic, on_message, qos, raw=True)
    g.spin(math.inf)
    return 0


def to_yaml_value(value: Any) -> str:
    import yaml

    return yaml.dump(value, allow_unicode=True, width=sys.maxsize, sort_keys=False,
                     default_flow_style=False)


class RateWindow:
    """The arrival times of the last ``window`` messages and ros2 topic hz's statistics."""

    def __init__(self, window: int) -> None:
        self.window = window
        self.times: list[float] = []
        self.new = False

    def add(self, t: float) -> None:
        self.times.append(t)
        del self.times[:-(self.window + 1)]
        self.new = True

    def report(self) -> str:
        """ros2 topic hz's line for the current window (``no new messages`` when none came)."""
        if not self.new or len(self.times) < 2:
            return "no new messages"
        self.new = False
        deltas = [b - a for a, b in zip(self.times, self.times[1:], strict=False)]
        mean = sum(deltas) / len(deltas)
        std = math.sqrt(sum((d - mean) ** 2 for d in deltas) / len(deltas))
        rate = 1.0 / mean if mean > 0 else 0.0
        return (f"average rate: {rate:.3f}\n\tmin: {min(deltas):.3f}s max: {max(deltas):.3f}s "
                f"std dev: {std:.5f}s window: {len(deltas) + 1}")


def hz(g: GraphNode, topic: str, window: int) -> int:
    types = topic_types(g, topic)
    if not types:
        print(f"WARNING: topic [{topic}] does not appear to be published yet", file=sys.stderr)
        # ros2cli waits for it; the subscription below needs a type, so look again until found.
        while g.context.ok() and not types:
            g.spin(0.2)
            types = topic_types(g, topic, wait=False)
        if not types:
            return 0
    try:  # the type any publisher advertised: one of ours, or refused in one line
        cls = message_class(types[0])
    except ValueError as e:
        print(f"ros2 topic hz: {e}", file=sys.stderr)
        return 1
    rates = RateWindow(window)
    g.node.create_subscription(cls, topic,
                               lambda _data: rates.add(time.monotonic()),
                               choose_qos(g, topic, None, None, None), raw=True)
    while g.context.ok():
        g.spin(HZ_PERIOD_S)
        if g.context.ok() and len(rates.times) >= 2:
            print(rates.report(), flush=True)
    return 0
