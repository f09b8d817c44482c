"""A ``ros2 run``-compatible entry for pip installs, where ros2cli has no wheels.

``ros2 run <package> <executable> [args ...] [--ros-args ...]`` looks the executable up among the
package's console scripts and runs it in this process with the remaining arguments, exactly as
``ros2 run`` would run ``lib/<package>/<executable>``. ``ros2 pkg executables [<package>]`` lists
them. ``ros2 lifecycle get <node>`` and ``ros2 lifecycle set <node> <transition>`` drive a managed
node through the standard ``lifecycle_msgs`` services, as ros2cli's verbs do
(:mod:`sdhn_base.ros.lifecycle_client`). ``ros2 topic``, ``node``, ``param`` and ``bag`` are
the everyday verbs, each in its own module (:mod:`sdhn_bringup.ros2_topic`,
:mod:`sdhn_bringup.ros2_node`, :mod:`sdhn_bringup.ros2_param`, :mod:`sdhn_bringup.ros2_bag`;
docs/ros2-tools.md). Only these verbs exist; anything else fails with the list.
"""

from __future__ import annotations

import importlib
import sys
from importlib import metadata

PACKAGES = ("sdhn_sim", "sdhn_policy", "sdhn_train")
USAGE = ("usage: ros2 run <package> <executable> [args ...] | ros2 pkg executables [<package>] | "
         "ros2 lifecycle get <node> | ros2 lifecycle set <node> <transition> | "
         "ros2 topic list|echo|hz|info ... | ros2 node list|info ... | "
         "ros2 param list|get|set|dump ... | ros2 bag info|play|record ...")
VERB_MODULES = {"topic": "sdhn_bringup.ros2_topic", "node": "sdhn_bringup.ros2_node",
                "param": "sdhn_bringup.ros2_param", "bag": "sdhn_bringup.ros2_bag"}
LIFECYCLE_TIMEOUT_S = 10.0


def executables(package: str) -> dict[str, metadata.EntryPoint]:
    """Console scripts of one installed package, by executable name."""
    try:
        dist = metadata.distribution(package)
    except metadata.PackageNotFoundError:
        return {}
    return {ep.name: ep for ep in dist.entry_points if ep.group == "console_scripts"}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args[:2] == ["pkg", "executables"]:
        for package in args[2:] or PACKAGES:
            for name in sorted(executables(package)):
                print(f"{package} {name}")
        return 0
    if args[:1] == ["lifecycle"]:
        return lifecycle(args[1:])
    if args[:1] and args[0] in VERB_MODULES:
        # Imported on use: `ros2 run` must not pay for rclpy graph code it does not need.
        module = importlib.import_module(VERB_MODULES[args[0]])
        return int(module.main(args[1:]))
    if len(args) < 3 or args[0] != "run":
        print(USAGE, file=sys.stderr)
        return 2
    package, executable, rest = args[1], args[2], args[3:]
    found = executables(package)
    if not found:
        print(
            f"ros2: package '{package}' not found (known: {', '.join(PACKAGES)})", file=sys.stderr
        )
        return 2
    if executable not in found:
        print(
            f"ros2: no executable '{executable}' in package '{package}' "
            f"(known: {', '.join(sorted(found))})",
            file=sys.stderr,
        )
        return 2
    sys.argv = [executable, *rest]
    result = found[executable].load()()
    return int(result or 0)


def lifecycle(args: list[str]) -> int:
    """``get <node>``: print its state; ``set <node> <transition>``: exit 0 when it succeeded,
    1 when the node refused it, 2 for bad arguments or no answer within LIFECYCLE_TIMEOUT_S."""
    from sdhn_base.ros.lifecycle_client import (
        TRANSITIONS,
        LifecycleClient,
        change_state,
        get_state,
    )

    verb = args[0] if args else ""
    if not ((verb == "get" and len(args) == 2) or (verb == "set" and len(args) == 3)):
        print(USAGE, file=sys.stderr)
        return 2
    node = args[1] if args[1].startswith("/") else "/" + args[1]
    if verb == "set" and args[2] not in TRANSITIONS:
        print(f"ros2: transition: {args[2]!r}; allowed: {', '.join(TRANSITIONS)}", file=sys.stderr)
        return 2
    client = LifecycleClient()
    try:
        if verb == "get":
            state = get_state(client, node, LIFECYCLE_TIMEOUT_S)
            if state is not None:
                print(state)
                return 0
        else:
            ok = change_state(client, node, args[2], LIFECYCLE_TIMEOUT_S)
            if ok is not None:
                print("Transitioning successful" if ok else "Transitioning failed")
                return 0 if ok else 1
        print(f"ros2: {node}: no lifecycle service answered within {LIFECYCLE_TIMEOUT_S}s",
              file=sys.stderr)
        return 2
    finally:
        client.close()


if __name__ == "__main__":
    sys.exit(main())
