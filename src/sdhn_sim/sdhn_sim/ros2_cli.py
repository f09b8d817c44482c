"""A ``ros2 run``-compatible entry for pip installs, where ros2cli has no wheels.

``ros2 run <package> <executable> [args ...] [--ros-args ...]`` looks the executable up among the
package's console scripts and runs it in this process with the remaining arguments, exactly as
``ros2 run`` would run ``lib/<package>/<executable>``. ``ros2 pkg executables [<package>]`` lists
them. Only these two verbs exist; anything else fails with the list of verbs.
"""

from __future__ import annotations

import sys
from importlib import metadata

PACKAGES = ("sdhn_sim", "sdhn_policy", "sdhn_train")
USAGE = "usage: ros2 run <package> <executable> [args ...] | ros2 pkg executables [<package>]"


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


if __name__ == "__main__":
    sys.exit(main())
