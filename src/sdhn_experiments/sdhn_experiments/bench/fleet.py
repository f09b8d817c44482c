"""The fleet cost curve (prints figures; not a test): whole deploy graphs started by the launcher
at N robots, one actor process per robot or actor hosts, simple discovery or the Fast DDS
discovery server. Run with the venv's python (``scripts/bench_ros.py --fleet`` runs the same):

    .venv/bin/python scripts/bench_fleet.py --robots 4 10 20 40 --steps 200 \\
        --discovery simple server --hosts 0 2 [--record [node | sim | both]]

Per run: start-up (launch -> every child's ready file), discovery (launch -> the simulator's
'started' event, i.e. every obs/action endpoint matched both ways), lock-step rounds/s over the
simulator's own window, CPU (utime + stime from /proc) per round of the whole graph and per
robot-round, CPU per second of each actor process in the loop, RSS per actor process and in all,
missed actions; with ``--record`` the same graph again with the recorder node (``node``, the
default) or with the simulator recording in its own process (``sim``: ``recorder.where=sim``) or
both, and the recording's share of the graph's CPU: the recorder process's CPU, or the simulator's
writer thread's (marked ``w``; what the simulator's hot path adds, queueing and the state message
it serialises every step, shows only against the unrecorded row's CPU per round). Weights are
random (the cost of a step does not depend on the policy).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from sdhn_experiments.bench import CHECKOUT as ROOT
from sdhn_experiments.bench.processes import cpu_seconds, make_weights
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS

ENVS = {c.num_robots: name for name, c in MAIF_CONFIGS.items() if name != "maif-solo"}


def rss_mb(pid: int) -> float:
    try:
        m = re.search(r"VmRSS:\s+(\d+)", Path(f"/proc/{pid}/status").read_text())
    except OSError:
        return float("nan")
    return int(m.group(1)) / 1024 if m else float("nan")


@dataclass
class FleetRun:
    n: int
    discovery: str
    hosts: int
    record: str  # '' (none), 'node' (the recorder node) or 'sim' (in the simulator)
    ok: bool = False
    ready_s: float = float("nan")  # launch -> every child ready
    matched_s: float = float("nan")  # launch -> the simulator's 'started'
    rounds: int = 0
    wall_s: float = float("nan")
    cpu_s: float = float("nan")  # whole graph, in the window (sim + actors + recorder)
    actors_cpu_s: float = float("nan")
    recorder_cpu_s: float = 0.0
    actor_procs: int = 0
    rss_actor_mb: float = float("nan")  # mean over actor processes
    rss_total_mb: float = float("nan")
    missed: int = -1
    load: float = 0.0
    note: str = ""

    @property
    def rate(self) -> float:
        return self.rounds / self.wall_s if self.rounds else 0.0

    @property
    def cpu_ms_round(self) -> float:
        return 1e3 * self.cpu_s / self.rounds if self.rounds else float("nan")

    @property
    def cpu_us_robot_round(self) -> float:
        return 1e6 * self.cpu_s / (self.rounds * self.n) if self.rounds else float("nan")


def run_graph(n: int, steps: int, weights: Path, tmp: Path, *, discovery: str, hosts: int,
              record: str, timeout: float) -> FleetRun:
    out = FleetRun(n, discovery, hosts, record)
    run_dir = tmp / f"n{n}-{discovery}-h{hosts}-r{record or 'none'}-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "sdhn_bringup", str(ROOT / "configs/launch/deploy-tiny.yaml"),
           "--set", f"env={ENVS[n]}", "--set", f"weights={weights}", "--set", "episodes=1",
           "--set", f"max_steps={steps}", "--set", f"recorder={str(bool(record)).lower()}",
           *(["--set", f"recorder.where={record}"] if record else []),
           "--set", f"discovery={discovery}", "--set", f"actor_hosts={hosts}",
           "--set", f"run_dir={run_dir}", "--set", f"start_timeout={timeout}",
           "--set", "step_deadline=5", "--set", "status_interval=5"]
    t0 = time.time()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=ROOT)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or []), daemon=True)
    reader.start()
    pids: dict[str, int] = {}
    before: dict[str, float] = {}
    events = run_dir / "status" / "sim-events.jsonl"
    seen = 0
    end = time.monotonic() + timeout + 120
    try:
        while proc.poll() is None and time.monotonic() < end:
            for line in list(lines):
                if "pids:" in line:
                    pids.update({k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", line)})
            if events.exists():
                evs = [json.loads(x) for x in events.read_text().splitlines() if x.strip()]
                for e in evs[seen:]:
                    if e["event"] == "started":
                        out.matched_s = e["time"] - t0
                        before = {k: cpu_seconds(p) for k, p in pids.items()}
                        actors = [p for k, p in pids.items() if k.startswith("actor")]
                        out.actor_procs = len(actors)
                        out.rss_actor_mb = sum(rss_mb(p) for p in actors) / max(len(actors), 1)
                        out.rss_total_mb = sum(rss_mb(p) for p in pids.values())
                    elif e["event"] == "done":
                        after = {k: cpu_seconds(p) for k, p in pids.items()}
                        d = {k: after[k] - before.get(k, 0.0) for k in after}
                        out.rounds, out.wall_s = int(e["steps"]), float(e["elapsed_s"])
                        out.cpu_s = sum(v for k, v in d.items() if k != DISCOVERY)
                        out.actors_cpu_s = sum(v for k, v in d.items() if k.startswith("actor"))
                        out.recorder_cpu_s = d.get("recorder", 0.0)
                        out.load = os.getloadavg()[0]
                    elif e["event"] == "stopped":
                        out.missed = int(e["missed"])
                seen = len(evs)
            time.sleep(0.05)
        if proc.poll() is None:
            proc.send_signal(2)
        proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(timeout=5)
    readies = [json.loads(f.read_text()).get("time", 0.0)
               for f in (run_dir / "status").glob("*.ready")
               if f.stem != DISCOVERY] if (run_dir / "status").exists() else []
    out.ready_s = max(readies) - t0 if readies else float("nan")
    out.ok = proc.returncode == 0 and out.rounds > 0
    if record == "sim":  # the simulator's closing line: its writer thread's CPU (whole run)
        log = run_dir / "logs" / "sim.log"
        found = WRITER_CPU.findall(log.read_text(errors="replace")) if log.exists() else []
        out.recorder_cpu_s = float(found[-1]) / 1e3 if found else float("nan")
    if not out.ok:
        out.note = next((x.strip() for x in reversed(lines) if "failed" in x or "error" in x),
                        f"exit {proc.returncode}")[:160]
    return out


DISCOVERY = "discovery"
WRITER_CPU = re.compile(r"writer thread ([0-9.]+) ms of CPU")


def header() -> str:
    return (f"{'N':>3} {'discovery':>9} {'layout':>9} {'ready s':>7} {'matched s':>9} "
            f"{'rounds/s':>8} {'CPU ms/round':>12} {'CPU us/robot-round':>18} "
            f"{'actor CPU/s':>11} {'RSS/actor MB':>12} {'RSS all MB':>10} {'rec. CPU':>8} "
            f"{'missed':>6} {'load':>5}")


def row(r: FleetRun) -> str:
    layout = f"{r.hosts} hosts" if r.hosts else "process"
    per_actor = (r.actors_cpu_s / r.wall_s / max(r.actor_procs, 1)) if r.rounds else float("nan")
    mark = "w" if r.record == "sim" else ""
    rec = (f"{f'{r.recorder_cpu_s / r.cpu_s:.1%}{mark}':>8}" if r.record and r.rounds
           else f"{'-':>8}")
    line = (f"{r.n:>3} {r.discovery:>9} {layout:>9} {r.ready_s:>7.1f} {r.matched_s:>9.1f} "
            f"{r.rate:>8.1f} {r.cpu_ms_round:>12.2f} {r.cpu_us_robot_round:>18.0f} "
            f"{per_actor:>11.3f} {r.rss_actor_mb:>12.0f} {r.rss_total_mb:>10.0f} {rec} "
            f"{r.missed:>6} {r.load:>5.1f}")
    return line + (f"  FAILED: {r.note}" if not r.ok else "")


def plot_table(text: str, figure: Path) -> None:
    """The cost curve from this script's printed table (its own output, saved): CPU per
    robot-round and RSS per actor process against N, one line per discovery mode and layout."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series: dict[str, list[tuple[int, float, float]]] = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) < 14 or not parts[0].isdigit() or "FAILED" in line:
            continue
        layout = "process" if parts[2] == "process" else f"{parts[2]} hosts"
        rest = parts[3:] if layout == "process" else parts[4:]  # ready s, matched s, ...
        if rest[8] != "-":  # a recorded run
            continue
        series.setdefault(f"{parts[1]}, {layout}", []).append(
            (int(parts[0]), float(rest[4]), float(rest[6])))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for label, pts in sorted(series.items()):
        pts.sort()
        ns = [p[0] for p in pts]
        ax1.plot(ns, [p[1] for p in pts], marker="o", label=label)
        ax2.plot(ns, [p[2] for p in pts], marker="o", label=label)
    ax1.set(xlabel="robots N", ylabel="CPU µs per robot-round (whole graph)", xscale="log")
    ax2.set(xlabel="robots N", ylabel="RSS per actor or actor-host process (MB)",
            xscale="log")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figure, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="+", default=[4, 10, 20, 40],
                    choices=sorted(ENVS))
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--discovery", nargs="+", default=["simple", "server"],
                    choices=["simple", "server"])
    ap.add_argument("--hosts", type=int, nargs="+", default=[0, 2],
                    help="actor_hosts values (0 = one process per robot)")
    ap.add_argument("--record", nargs="?", const="node", default="",
                    choices=["node", "sim", "both"],
                    help="also each graph recorded: by the recorder node (node, the default), "
                         "inside the simulator (sim), or both")
    ap.add_argument("--timeout", type=float, default=240.0, help="start_timeout per run (s)")
    ap.add_argument("--plot", nargs=2, type=Path, metavar=("TABLE", "FIGURE"),
                    help="only draw FIGURE (png) from a saved TABLE this script printed")
    args = ap.parse_args(argv)
    if args.plot:
        plot_table(args.plot[0].read_text(), args.plot[1])
        return 0
    os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 90 + 10))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    tmp = Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    os.environ.setdefault("ROS_LOG_DIR", str(tmp / "ros_logs"))
    weights = make_weights(tmp)
    print(f"# bench_fleet: {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f} at the start, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {args.steps} steps per run")
    print(header(), flush=True)
    for n in args.robots:
        for discovery in args.discovery:
            for hosts in args.hosts:
                if hosts > n:
                    continue
                kinds = {"": [], "node": ["node"], "sim": ["sim"], "both": ["node", "sim"]}
                for record in ["", *kinds[args.record]]:
                    r = run_graph(n, args.steps, weights, tmp, discovery=discovery,
                                  hosts=hosts, record=record, timeout=args.timeout)
                    print(row(r), flush=True)
    print(f"# load at the end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
