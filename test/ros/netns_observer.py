"""The test's observer as a node on one of the test network's hosts (run inside its namespace:
``python -m ros.netns_observer`` with ``test/`` on the path). Records every action with its arrival
time and every episode summary until EPISODES episodes ended, then writes them as JSON."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from sdhn_base.ros import topics

from .deploy_helpers import observer


class TimedActions(dict[tuple[int, int, int], tuple[int, int]]):
    """The observer's action table, also noting when (wall clock) each action arrived."""

    def __init__(self) -> None:
        super().__init__()
        self.at: dict[tuple[int, int, int], float] = {}

    def __setitem__(self, key: tuple[int, int, int], value: tuple[int, int]) -> None:
        self.at[key] = time.time()
        super().__setitem__(key, value)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", type=int, required=True)
    ap.add_argument("--ns", required=True)
    ap.add_argument("--episodes", type=int, required=True)
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--stop-file", type=Path, help="stop (and write) once this file exists")
    a = ap.parse_args(argv)
    with observer(a.robots, a.ns) as (node, seen, spin):
        timed = TimedActions()
        seen.actions = timed
        names = [topics.absolute(a.ns, topics.robot_action(i)) for i in range(a.robots)]
        spin(60, lambda: all(node.count_publishers(t) >= 1 for t in names))
        print("observer: actors seen", flush=True)
        ok = spin(a.timeout, lambda: len(seen.episodes) >= a.episodes
                   or (a.stop_file is not None and a.stop_file.exists()))
        eps: list[dict[str, Any]] = [
            {"length": int(m.length), "missed_actions": int(m.missed_actions)}
            for m in seen.episodes]
        a.out.write_text(json.dumps({
            "complete": ok, "episodes": eps,
            "actions": [[*k, v[0], timed.at[k]] for k, v in sorted(timed.items())]}))
    print("observer: done", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
