"""Decision latency of the actor processes, read from their own /diagnostics (prints figures; not
a test). Run niced with the venv's python:

    nice -n 10 .venv/bin/python scripts/bench_decision_latency.py [--robots 4 10 20] [--seconds 20]

For each team size N: the simulator (MAIF with N robots, lock-step, step deadline 1 s) and N actor
processes with random weights (the cost of a decision does not depend on how good the policy is),
as ``bench_ros.py`` starts them. Once stepping, it listens to ``/diagnostics`` for ``--seconds``
and prints, from each actor's last report (its last 1000 decisions), the median over actors of
p50 and of p99, and the worst actor's p99, of *observation received -> action sent* (the actor's
callback: CDR read, policy, publish; DDS transport not included); and the simulator's step rate
and missed actions over the window. The load average is printed with every row: on a shared
machine latencies move with it.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_base.ros import topics
from sdhn_experiments.bench.processes import ENVS, ROS2, make_weights, spawn, stop

NS = "/sdhn"


def measure(n: int, seconds: float, weights: Path,
            spin: Callable[[float], None], latest: dict[str, dict[str, str]]) -> dict[str, Any]:
    latest.clear()
    actors = [spawn([*ROS2, "sdhn_policy", "actor", "--ros-args", "-r", f"__ns:={NS}/robot_{i}",
                     "-p", f"robot_id:={i}", "-p", f"num_robots:={n}", "-p",
                     f"weights_file:={weights}", "-p", "greedy:=true"]) for i in range(n)]
    sim = spawn([*ROS2, "sdhn_sim", "sim", "--ros-args", "-r", f"__ns:={NS}", "-p",
                 f"env:={ENVS[n]}", "-p", "episodes:=0", "-p", "step_deadline:=1.0"])
    sim_name = f"{NS}/sim"
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and float(latest.get(sim_name, {}).get("steps", 0)) < 50:
            spin(0.1)
        if float(latest.get(sim_name, {}).get("steps", 0)) < 50:
            raise RuntimeError(f"N={n}: the simulator did not reach 50 steps in 120 s")
        steps0, missed0 = (float(latest[sim_name][k]) for k in ("steps", "missed_actions"))
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            spin(0.1)
        elapsed = time.monotonic() - t0
        steps1, missed1 = (float(latest[sim_name][k]) for k in ("steps", "missed_actions"))
        actor_names = [f"{NS}/robot_{i}/actor" for i in range(n)]
        p50 = [float(latest[a]["decision_latency_p50_ms"]) for a in actor_names if a in latest]
        p99 = [float(latest[a]["decision_latency_p99_ms"]) for a in actor_names if a in latest]
        return {"n": n, "actors_reporting": len(p50), "steps_per_s": (steps1 - steps0) / elapsed,
                "missed": int(missed1 - missed0), "p50_ms": float(np.median(p50)),
                "p99_ms": float(np.median(p99)), "p99_worst_ms": max(p99),
                "load": os.getloadavg()}
    finally:
        stop([sim, *actors])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="*", default=[4, 10, 20], choices=sorted(ENVS))
    ap.add_argument("--seconds", type=float, default=20.0, help="measured window per team size")
    args = ap.parse_args()
    os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 90 + 10))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    tmp = Path(tempfile.mkdtemp(prefix="bench-latency-"))
    os.environ.setdefault("ROS_LOG_DIR", str(tmp / "ros_logs"))

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from sdhn_base.ros.qos import DIAGNOSTICS

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("bench_latency", context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    latest: dict[str, dict[str, str]] = {}

    def on_diag(m: Any) -> None:
        for s in m.status:
            latest[s.name] = {kv.key: kv.value for kv in s.values}

    node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diag, DIAGNOSTICS)
    weights = make_weights(tmp)
    print(f"# bench_decision_latency: {os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d %H:%M')} "
          f"UTC, {args.seconds:.0f} s per team size, ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}")
    print("| N | steps/s | missed | p50 ms (median actor) | p99 ms (median actor) | "
          "p99 ms (worst actor) | load average (1, 5, 15 min) |")
    print("|---|---|---|---|---|---|---|")
    try:
        for n in args.robots:
            r = measure(n, args.seconds, weights, lambda s: ex.spin_once(timeout_sec=s), latest)
            load = ", ".join(f"{x:.1f}" for x in r["load"])
            print(f"| {n} | {r['steps_per_s']:.0f} | {r['missed']} | {r['p50_ms']:.2f} | "
                  f"{r['p99_ms']:.2f} | {r['p99_worst_ms']:.2f} | {load} |", flush=True)
    finally:
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


if __name__ == "__main__":
    sys.exit(main())
