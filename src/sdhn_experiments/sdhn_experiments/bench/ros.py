"""Benchmark of the ROS deployment stack (prints figures; not a test). Run with the venv's python:

    .venv/bin/python scripts/bench_ros.py [--robots 4 10 20 40 100] [--steps 300]
        [--record [node | sim | both]]
    .venv/bin/python scripts/bench_ros.py --fleet --robots 4 10 20 40 --hosts 0 2  # the fleet

1. Lock-step team-steps/s in deploy mode (``sdhn_sim sim`` + N ``sdhn_policy actor`` processes,
   MAIF with N robots, greedy NumPy policy) next to a minimal rclpy ping-pong ceiling measured in
   the same run: a bare lock-step master publishing the same RobotObservation messages to N bare
   echo processes, one per robot, which answer with a RobotAction at once (no env, no policy).
2. Actor process RSS and time-to-ready (Popen -> "ready" log line) with a weights file.
3. Recording overhead (``--record``): steps/s and CPU with the recorder node beside the loop
   (``node``, the default), with the simulator recording in its own process (``sim``: the
   simulator's ``recording`` parameter), or both, each against the unrecorded deploy of the same
   repeat. The recorder node's share is its CPU / (loop + its CPU); the in-simulator recording's is
   (loop CPU recorded - loop CPU unrecorded) / loop CPU recorded (everything it adds: queueing,
   the state message it serialises every step, the writer thread), beside which the sim's writer
   thread's own CPU is printed.

Beside every wall rate it prints the CPU time per team step (round) of each role over the measured
window (utime + stime from ``/proc/<pid>/stat`` before and after, divided by the rounds made): the
simulator or the bare master, the sum over the N actors or echo processes, and the recorder. On a
machine where other jobs hold the cores, wall rates move with their load, but CPU per round does
not: ``bare CPU / deploy CPU`` is the ratio a CPU-bound loop would reach, and
``loop CPU / (loop CPU + recorder CPU)`` the rate it keeps with a recorder beside it.

Weights are random (NumPy ``encode_actor``), so no training is needed; the cost of a step does not
depend on how good the policy is. Every process runs on localhost in a private ROS domain.
"""

from __future__ import annotations

import argparse
import array
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sdhn_base.ros import cdr, topics
from sdhn_base.ros.status import EventReader
from sdhn_experiments.bench import CHECKOUT
from sdhn_experiments.bench.processes import (
    ENVS,
    ROS2,
    cpu_seconds,
    make_weights,
    spawn,
    stop,
    wait_line,
)

ROOT = CHECKOUT


@dataclass
class Window:
    """One measured lock-step window: wall rate and CPU per round of each role."""

    rounds: int
    wall_s: float
    loop_cpu_s: float  # the simulator, or the bare master
    peers_cpu_s: float  # the N actors, or the N echo processes, summed
    recorder_cpu_s: float | None = None
    writer_cpu_s: float | None = None  # in-sim recording: the sim's writer thread (whole run)
    load: float = 0.0  # 1-minute load average at the end of the window

    @property
    def rate(self) -> float:
        return self.rounds / self.wall_s

    def ms(self, cpu_s: float | None) -> float:
        return float("nan") if cpu_s is None else 1e3 * cpu_s / self.rounds

    @property
    def cpu_ms(self) -> float:
        """Loop CPU per round (master/sim + peers), without the recorder."""
        return self.ms(self.loop_cpu_s + self.peers_cpu_s)


# --- 1a. the ceiling: bare lock-step master + N bare echo processes ------------------------------


def echo_main(robot: int, ns: str) -> int:
    import rclpy
    from rclpy.experimental import EventsExecutor

    from sdhn_base.ros.qos import STEP
    from sdhn_msgs.msg import RobotAction, RobotObservation

    rclpy.init()
    node = rclpy.create_node("echo", namespace=topics.absolute(ns, topics.robot(robot)))
    pub = node.create_publisher(RobotAction, topics.absolute(ns, topics.robot_action(robot)), STEP)
    a = RobotAction()  # built once: the echo does no Python work per message beyond the answer
    a.robot_id = robot

    def on_obs(data: bytes) -> None:
        # Raw CDR, read at its offsets, as the actor reads it: cheaper than letting rclpy build a
        # message (118-143 against 159-217 us of CPU per echo and step, measured at N=10).
        m = cdr.read_observation(data)
        a.episode, a.step = m.episode, m.step
        pub.publish(a)

    node.create_subscription(RobotObservation, topics.absolute(ns, topics.robot_obs(robot)), on_obs,
                             STEP, raw=True)
    ex = EventsExecutor()
    ex.add_node(node)
    print("ready", flush=True)
    try:
        while rclpy.ok():
            ex.spin_once(timeout_sec=0.05)
    except KeyboardInterrupt:
        pass
    return 0


def ceiling(n: int, steps: int) -> Window:
    import rclpy
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor

    from sdhn_base.ros.qos import STEP
    from sdhn_msgs.msg import RobotAction, RobotObservation

    ns = "/pingpong"
    echoes = [spawn([sys.executable, "-m", "sdhn_experiments.bench.ros", "--echo", str(i),
                     "--ns", ns]) for i in range(n)]
    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("master", context=ctx)
    pubs = [node.create_publisher(RobotObservation, topics.absolute(ns, topics.robot_obs(i)), STEP)
            for i in range(n)]
    got: set[int] = set()
    step = [0]
    resent = [0]
    obs = array.array("f", np.zeros(57, np.float32).tobytes())
    msgs = []  # built once: per step only the step field changes
    for i in range(n):
        m = RobotObservation()
        m.robot_id, m.num_robots, m.obs = i, n, obs
        msgs.append(m)

    def publish() -> None:
        for m, p in zip(msgs, pubs, strict=True):
            m.step = step[0]
            p.publish(m)

    def on_action(data: bytes) -> None:
        m = cdr.read_action(data)  # raw CDR, as the simulator reads actions
        if m.step != step[0]:
            return
        got.add(m.robot_id)
        if len(got) == n:
            got.clear()
            step[0] += 1
            publish()

    subs = [node.create_subscription(RobotAction, topics.absolute(ns, topics.robot_action(i)),
                                     on_action, STEP, raw=True)
            for i in range(n)]
    ex = EventsExecutor(context=ctx)
    ex.add_node(node)
    try:
        end = time.monotonic() + 120
        while not (all(p.get_subscription_count() >= 1 for p in pubs)
                   and all(s.get_publisher_count() >= 1 for s in subs)):
            if time.monotonic() > end:
                raise RuntimeError(f"ceiling: {n} echo processes not matched within 120 s")
            ex.spin_once(timeout_sec=0.02)

        def run_until(target: int) -> None:
            # Matching is only visible from this side: an echo may not yet receive from us when
            # we already see it, and a volatile step sent then is lost. So a round with no
            # answer for 0.5 s is sent again (to every echo; the answers are idempotent), as the
            # simulator re-sends its first step. This was the N=20 stall at step 0.
            last, t_last, t_sent = step[0], time.monotonic(), time.monotonic()
            while step[0] < target:
                ex.spin_once(timeout_sec=0.05)
                now = time.monotonic()
                if step[0] != last:
                    last, t_last, t_sent = step[0], now, now
                elif now - t_last > 20.0:
                    raise RuntimeError(f"ceiling: stalled at step {step[0]}")
                elif now - t_sent > 0.5:
                    t_sent = now
                    resent[0] += 1
                    publish()

        publish()
        run_until(min(50, steps // 5))
        # The master is this process (nothing else runs in it meanwhile): process_time is its CPU.
        t0, s0, c0 = time.perf_counter(), step[0], time.process_time()
        e0 = sum(cpu_seconds(p.pid) for p in echoes)
        run_until(s0 + steps)
        wall, master = time.perf_counter() - t0, time.process_time() - c0
        peers = sum(cpu_seconds(p.pid) for p in echoes) - e0
        window = Window(step[0] - s0, wall, master, peers, load=os.getloadavg()[0])
    finally:
        ex.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        stop(echoes)
    return window


# --- 1b. the real stack ---------------------------------------------------------------------


WRITER_CPU = re.compile(r"writer thread ([0-9.]+) ms of CPU")


def deploy_rate(n: int, steps: int, weights: Path, record: str, tmp: Path) -> Window:
    """One deploy run; ``record``: '' (none), 'node' (the recorder node) or 'sim' (in-sim)."""
    env = ENVS[n]
    procs = []
    in_sim = ["-p", f"recording:={tmp / f'rec-sim-{n}-{time.monotonic_ns()}.mcap'}"]
    if record == "node":
        procs.append(spawn([*ROS2, "sdhn_sim", "recorder", "--ros-args", "-r", "__ns:=/sdhn",
                            "-p", f"output:={tmp / f'rec-{n}.mcap'}"]))
    # action readers: the simulator, and the recorder node (each actor holds its obs subscription
    # until its action writer has matched them, as under the launcher)
    actors = [spawn([*ROS2, "sdhn_policy", "actor", "--ros-args", "-r", f"__ns:=/sdhn/robot_{i}",
                     "-p", f"robot_id:={i}", "-p", f"num_robots:={n}", "-p",
                     f"weights_file:={weights}", "-p", "greedy:=true", "-p",
                     f"action_readers:={1 + int(record == 'node')}"]) for i in range(n)]
    events = tmp / f"sim-events-{n}-{record}.jsonl"
    events.unlink(missing_ok=True)
    # The sim's output goes to a file: nobody reads a pipe while it runs, and a full pipe blocks.
    log = (tmp / f"sim-{n}-{record}.log").open("wb")
    sim = subprocess.Popen([*ROS2, "sdhn_sim", "sim", "--ros-args", "-r", "__ns:=/sdhn", "-p",
                            f"env:={env}", "-p", "episodes:=1", "-p", f"max_steps:={steps}",
                            "-p", f"extra_subscribers:={int(record == 'node')}", "-p",
                            f"events_file:={events}", *(in_sim if record == "sim" else [])],
                           stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    roles = [sim, *actors, *procs]  # procs: the recorder
    try:
        # The window is the sim's own (its 'started' to its 'done' event); each process's CPU is
        # read when the bench sees those events. Polling every 5 ms puts the edges a few rounds
        # off at most, and costs the bench itself well under 1 % of a core.
        reader, before, after, done = EventReader(events), None, None, None
        end = time.monotonic() + 180
        while done is None and time.monotonic() < end:
            exited = sim.poll() is not None
            for e in reader.new():
                if e["event"] == "started":
                    before = [cpu_seconds(p.pid) for p in roles]
                elif e["event"] == "done":
                    after = [cpu_seconds(p.pid) for p in roles]
                    done = e
            if exited:
                break
            time.sleep(0.005)
        sim.wait(timeout=30)
        if done is None or before is None or after is None or sim.returncode != 0:
            lines = Path(log.name).read_text(errors="replace").splitlines()
            raise RuntimeError("sim did not finish:\n" + "\n".join(lines[-20:]))
        cpu = [b - a for a, b in zip(before, after, strict=True)]
        window = Window(int(done["steps"]), float(done["elapsed_s"]), cpu[0], sum(cpu[1:1 + n]),
                        cpu[-1] if record == "node" else None, load=os.getloadavg()[0])
    finally:
        log.close()
        stop(roles)
    if record == "sim":  # the sim has closed its file: its last lines say what the writer cost
        found = WRITER_CPU.findall(Path(log.name).read_text(errors="replace"))
        window.writer_cpu_s = float(found[-1]) / 1e3 if found else None
    return window


# --- 2. actor process footprint --------------------------------------------------------------


def actor_footprint(weights: Path, repeats: int,
                    shim: bool) -> tuple[list[float], list[float]]:
    """Popen -> 'ready' seconds and RSS (MB) of an actor process started as the launcher starts
    it (the console script) or through the ``ros2 run`` shim."""
    readies, rss = [], []
    head = [*ROS2, "sdhn_policy", "actor"] if shim else [str(Path(sys.executable).parent / "actor")]
    for k in range(repeats):
        t0 = time.perf_counter()
        p = spawn([*head, "--ros-args", "-r", f"__ns:=/fp/robot_{k}",
                   "-p", f"robot_id:={k}", "-p", "num_robots:=10", "-p",
                   f"weights_file:={weights}", "-p", "team_ns:=/fp"])
        try:
            ok, lines = wait_line(p, "ready", timeout=30)
            readies.append(time.perf_counter() - t0)
            time.sleep(0.3)
            status = Path(f"/proc/{p.pid}/status").read_text()
            m = re.search(r"VmRSS:\s+(\d+)", status)
            rss.append(int(m.group(1)) / 1024 if m else float("nan"))
        finally:
            stop([p])
        if not ok:
            raise RuntimeError("\n".join(lines))
    return readies, rss


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="*", default=[4, 10, 20], choices=sorted(ENVS),
                    help="team sizes to measure (none: only the actor footprint)")
    ap.add_argument("--steps", type=int, default=300, help="team steps per measurement")
    ap.add_argument("--record", nargs="?", const="node", default="",
                    choices=["node", "sim", "both"],
                    help="also measure recording overhead: the recorder node (node, the default), "
                         "the simulator recording in its own process (sim), or both")
    ap.add_argument("--repeats", type=int, default=2,
                    help="interleaved repeats per figure; the best is shown (other load on the "
                         "machine only ever slows a run down)")
    ap.add_argument("--fleet", action="store_true",
                    help="the fleet cost curve instead: whole graphs through the launcher, "
                         "processes or actor hosts, simple discovery or the server "
                         "(scripts/bench_fleet.py; its options follow --fleet)")
    ap.add_argument("--echo", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--ns", default="/pingpong", help=argparse.SUPPRESS)
    if "--fleet" in sys.argv[1:]:
        from sdhn_experiments.bench.fleet import main as fleet_main

        return fleet_main([a for a in sys.argv[1:] if a != "--fleet"])
    args = ap.parse_args()
    if args.echo is not None:
        return echo_main(args.echo, args.ns)
    os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 90 + 10))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    tmp = Path(tempfile.mkdtemp(prefix="bench-ros-"))
    os.environ.setdefault("ROS_LOG_DIR", str(tmp / "ros_logs"))
    weights = make_weights(tmp)
    print(f"# bench_ros: {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}, "
          f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, {args.steps} steps per figure")
    for how, shim in (("console script", False), ("ros2 run shim", True)):
        readies, rss = actor_footprint(weights, 3, shim)
        print(f"actor process ({how}): ready {np.median(readies):.2f}s (median of "
              f"{len(readies)}: {', '.join(f'{r:.2f}' for r in readies)}), RSS "
              f"{np.median(rss):.0f} MB (goal: < 0.5 s, < 100 MB)")
    print("wall: best of the repeats (other load only ever slows a run down); CPU: ms per round, "
          "median of the repeats, loop = master/sim + the N echoes/actors summed; "
          "CPU-bound = bare CPU / deploy CPU (and loop / (loop + recorder))")
    head = (f"{'N':>3} {'env':>10} {'bare/s':>7} {'deploy/s':>8} {'ratio':>6} | "
            f"{'bare CPU':>14} {'deploy CPU':>15} {'CPU-bound':>9}")
    kinds = {"node": ["node"], "sim": ["sim"], "both": ["node", "sim"], "": []}[args.record]
    if "node" in kinds:
        head += (f" | {'node rec/s':>10} {'overhead':>8} {'recorder CPU':>12} "
                 f"{'CPU share':>9}")
    if "sim" in kinds:
        head += (f" | {'in-sim/s':>8} {'overhead':>8} {'loop CPU':>8} {'added':>6} "
                 f"{'writer':>6} {'CPU share':>9}")
    print(head + " | load")
    for n in args.robots:
        runs: dict[str, list[Window]] = {"ceiling": [], "deploy": [], "node": [], "sim": []}
        for _ in range(args.repeats):
            runs["ceiling"].append(ceiling(n, args.steps))
            runs["deploy"].append(deploy_rate(n, args.steps, weights, "", tmp))
            for kind in kinds:
                runs[kind].append(deploy_rate(n, args.steps, weights, kind, tmp))

        def med(kind: str, part: str, runs: dict[str, list[Window]] = runs) -> float:
            return float(np.median([w.ms(getattr(w, f"{part}_cpu_s")) for w in runs[kind]]))

        ceil = max(w.rate for w in runs["ceiling"])
        real = max(w.rate for w in runs["deploy"])
        bare_loop, bare_peers = med("ceiling", "loop"), med("ceiling", "peers")
        dep_loop, dep_peers = med("deploy", "loop"), med("deploy", "peers")
        bare_cpu, dep_cpu = bare_loop + bare_peers, dep_loop + dep_peers
        line = (f"{n:>3} {ENVS[n]:>10} {ceil:>7.0f} {real:>8.0f} {real / ceil:>6.0%} | "
                f"{bare_cpu:>5.2f} ({bare_loop:.2f}+{bare_peers:.2f}) "
                f"{dep_cpu:>5.2f} ({dep_loop:.2f}+{dep_peers:.2f}) {bare_cpu / dep_cpu:>9.0%}")
        if "node" in kinds:
            rec = max(w.rate for w in runs["node"])
            rec_cpu = med("node", "recorder")
            rec_loop = med("node", "loop") + med("node", "peers")
            line += (f" | {rec:>10.0f} {1 - rec / real:>8.1%} {rec_cpu:>12.2f} "
                     f"{rec_cpu / (rec_loop + rec_cpu):>9.1%}")
        if "sim" in kinds:
            rec = max(w.rate for w in runs["sim"])
            rec_loop = med("sim", "loop") + med("sim", "peers")
            added = rec_loop - dep_cpu
            writer = float(np.median([w.ms(w.writer_cpu_s) for w in runs["sim"]]))
            line += (f" | {rec:>8.0f} {1 - rec / real:>8.1%} {rec_loop:>8.2f} {added:>6.2f} "
                     f"{writer:>6.2f} {added / rec_loop:>9.1%}")
        loads = [w.load for ws in runs.values() for w in ws]
        line += f" | {min(loads):.1f}-{max(loads):.1f}"
        every = "; ".join(f"{k} " + ", ".join(f"{w.rate:.0f}/s {w.cpu_ms:.2f}ms" for w in ws)
                          for k, ws in runs.items() if ws)
        print(f"{line}\n      ({every})", flush=True)
    print("goals: deploy >= 80% of ceiling; recording overhead <= 5%; "
          f"load at the end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
