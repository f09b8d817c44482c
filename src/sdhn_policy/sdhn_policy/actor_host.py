"""Actor host ``python -m sdhn_policy.actor_host``: several robots' actor nodes in one process.

    python -m sdhn_policy.actor_host --team-ns /sdhn --robots 0:25 \\
        --ros-args --params-file params.yaml

Opt-in, for fleets where an interpreter per robot costs too much (~64 MB and a DDS participant
each): one :class:`sdhn_policy.actor_node.ActorNode` per robot (node ``actor`` in
``<team_ns>/robot_<i>``, the names a process per robot has), all on one events executor, in the
ROS 2 composition style. Each node reads its own parameters from the parameters file by its full
name, runs the same :class:`sdhn_policy.actor_core.ActorCore` and so answers an observation
exactly as the process of that robot would; each also holds its obs subscription until its own
action writer has matched ``action_readers`` (one ``-p action_readers:=K`` sets it for every node
of the process). The robots share the process's one DDS participant
and its one thread: a robot's decision waits for the others' of the same step, which costs
latency, not actions. One process per robot stays the default and what the decentralised tests
run; the launcher starts hosts with ``actor_hosts: K``.

Unmanaged only: a lifecycle ``shutdown`` of one robot would end every robot of the process.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from rclpy.context import Context

from sdhn_base.ros import topics
from sdhn_base.ros.runner import ConfigError, run_node
from sdhn_policy.actor_node import ActorNode, _on_stop, make_actor


def parse_robots(text: str) -> range:
    """``A:B`` (robots A..B-1) or ``A`` (robot A alone); ConfigError naming ``--robots``."""
    try:
        first, sep, end = text.partition(":")
        robots = range(int(first), int(end) if sep else int(first) + 1)
    except ValueError:
        robots = range(0)
    if not robots or robots.start < 0:
        raise ConfigError(f"--robots: got {text!r}; allowed: A:B with 0 <= A < B (robots A..B-1) "
                          "or one id A")
    return robots


def make_host(context: Context, args: list[str]) -> list[ActorNode]:
    p = argparse.ArgumentParser(prog="actor_host", add_help=False)
    p.add_argument("--team-ns", default=topics.DEFAULT_TEAM_NS)
    p.add_argument("--robots", default="0")
    known, extra = p.parse_known_args(args)
    if extra:
        raise ConfigError(f"unknown arguments {extra}; allowed: --team-ns NS --robots A:B")
    ns = topics.check_team_ns(known.team_ns)
    nodes: list[ActorNode] = []
    try:
        for robot in parse_robots(known.robots):
            node = make_actor(context, [], topics.absolute(ns, topics.robot(robot)))
            if node.params["managed"]:
                raise ConfigError("managed: an actor host runs unmanaged actors only (a "
                                  "lifecycle shutdown would stop every robot of the process); "
                                  "allowed: false")
            if node.robot_id != robot:
                raise ConfigError(f"robot_id: the node in {node.get_namespace()} has robot_id "
                                  f"{node.robot_id}; allowed: {robot} (its namespace's)")
            nodes.append(node)
    except BaseException:
        for node in nodes:
            node.destroy_node()
        raise
    return nodes


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(make_host, argv, _on_stop)


if __name__ == "__main__":
    raise SystemExit(main())
