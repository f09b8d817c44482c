"""Soak: a train-mode graph (20 actor processes by default) for a while, killing a random actor
every minute; prints steps, recovery times, dropped messages, every process's RSS at start and
end, and whether the MCAP recording is complete. Not a CI test.

Issue 15's figures, each from data (never log text): the share of the simulator's steps that the
trainer turned into complete transitions (its status file against the recorded TeamStates; the
steps a killed actor did not answer excepted), the simulator's deadline misses outside the kills'
outages, how long after an update's end every live actor acts with the new weights (the weights'
stamp is the update's end; the first recorded action of each actor with that version), and the
trainer's RSS (node + its learner offload process) after warm-up. The load average is printed
with them.

    .venv/bin/python scripts/soak.py --minutes 10          # nice it on a shared machine

Recovery time of a kill = from SIGKILL to the first simulator step that has every action again
(the recorded TeamState stamps and missed_actions, read from the MCAP file after the run).
RSS "start" is taken once the graph is training (after
``--warmup`` seconds), "end" just before the stop; processes restarted in between are compared
with their own first sample.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from sdhn_base.polling import wait_until
from sdhn_experiments.bench import CHECKOUT

REPO = CHECKOUT
LAUNCH = [str(REPO / "scripts" / "launch.sh")]


def rss_kb(pid: int) -> int | None:
    """Resident set size of ``pid`` in kB (None once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def children(parent: int) -> dict[str, int]:
    """The launcher's live children by node name (sim, trainer, recorder, actor_<i>), read from
    /proc: the parent pid and the command line each was started with."""
    out: dict[str, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) != parent or fields[0] == "Z":
                continue
            argv = stat.with_name("cmdline").read_bytes().decode(errors="replace").split("\0")
        except (OSError, IndexError, ValueError):
            continue
        exe = next((Path(a).name for a in argv if a in ("sim", "actor", "trainer", "recorder")
                    or Path(a).name in ("sim", "actor", "trainer", "recorder")), None)
        if exe is None:
            continue
        robot = next((m.group(1) for a in argv if (m := re.match(r"robot_id:=(\d+)$", a))),
                     None)
        out[f"actor_{robot}" if exe == "actor" and robot is not None else exe] = \
            int(stat.parent.name)
    return out


def descendants(pid: int) -> list[int]:
    """Child processes of ``pid`` (the trainer's learner offload process)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                out.append(int(stat.parent.name))
        except (OSError, IndexError, ValueError):
            continue
    return out


def tree_rss_kb(pid: int) -> int | None:
    """RSS of ``pid`` plus its children's (None once it is gone)."""
    own = rss_kb(pid)
    if own is None:
        return None
    return own + sum(rss_kb(c) or 0 for c in descendants(pid))


def percentiles(values: list[float]) -> str:
    if not values:
        return "none"
    q = sorted(values)

    def at(p: float) -> float:
        return q[min(len(q) - 1, int(p * (len(q) - 1) + 0.5))]

    return (f"median {at(0.5) * 1e3:.0f} ms, p90 {at(0.9) * 1e3:.0f} ms, p99 {at(0.99) * 1e3:.0f} "
            f"ms, max {q[-1] * 1e3:.0f} ms, {sum(v <= 1.0 for v in q)}/{len(q)} within 1 s")


def weights_latency(rec: Any, kills: list[tuple[str, float]]) -> list[float]:
    """Per (version, live actor): seconds from the update's end (the weights' stamp) to that
    actor's first recorded action with the version. An actor killed in between is not live."""
    updates = sorted({int(m.version): stamp(m) for _, m in rec.decoded("policy/weights")
                      if int(m.version) > 1}.items())
    first: dict[tuple[int, int], float] = {}  # (robot, version) -> first log time with >= it
    acts = sorted(((raw.log_time_ns * 1e-9, int(a.robot_id), int(a.policy_version))
                   for raw, a in rec.decoded("/action")))
    best: dict[int, int] = {}
    for t, robot, version in acts:
        if version > best.get(robot, 0):
            for v in range(best.get(robot, 0) + 1, version + 1):
                first.setdefault((robot, v), t)
            best[robot] = version
    robots = sorted(best)
    out = []
    for version, t_end in updates:
        for robot in robots:
            t = first.get((robot, version))
            killed = any(name == f"actor_{robot}" and t_end - 5 <= tk <= (t or t_end + 5)
                         for name, tk in kills)
            if t is not None and not killed:
                out.append(t - t_end)
    return out


def parse() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--minutes", type=float, default=10.0, help="soak duration after warm-up")
    p.add_argument("--env", default="maif-20", help="environment (maif-20: 20 robots)")
    p.add_argument("--kill-every", type=float, default=60.0, help="seconds between actor kills")
    p.add_argument("--warmup", type=float, default=10.0, help="seconds of training before t0")
    p.add_argument("--run-dir", type=Path, default=None, help="default runs/soak-<time>")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step-deadline", type=float, default=1.0)
    p.add_argument("--rollout-steps", type=int, default=128)
    return p.parse_args()


def drops_from_logs(run: Path) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for log in sorted((run / "logs").glob("*.log")):
        text = log.read_text(errors="replace")
        found: dict[str, int] = {}
        for marker in ("drops: {", "drops {", "dropped={"):
            for block in re.findall(re.escape(marker) + r"([^}]*)\}", text):
                for k, v in re.findall(r"'([^']+)': (\d+)", block):
                    found[k] = max(found.get(k, 0), int(v))  # cumulative lines: keep the max
        if found:
            out[log.stem] = found
    return out


def stamp(msg: Any) -> float:
    h = msg.header.stamp
    return float(h.sec + h.nanosec * 1e-9)


def recovery(states: list[Any], t_kill: float) -> tuple[float | None, int]:
    """(sim time of the first step with every action again after the outage, steps in the
    outage), from the simulator's recorded TeamState stamps and missed_actions counts."""
    after = [s for s in states if stamp(s) > t_kill and s.step > 0]
    k = next((i for i, s in enumerate(after) if s.missed_actions), None)
    if k is None:
        return None, 0
    back = next((s for s in after[k:] if s.missed_actions == 0), None)
    missing = sum(1 for s in after[k:] if back is None or stamp(s) < stamp(back))
    return (None if back is None else stamp(back)), missing


def recorded(run: Path) -> tuple[list[Any], list[int], int]:
    """(TeamState messages, weights versions, episodes) from the run's recording."""
    from sdhn_sim.recording.reader import read_recording

    rec = read_recording(run / "recording.mcap")
    states = [m for _, m in rec.decoded("/state")]
    versions = [int(m.version) for _, m in rec.decoded("policy/weights")]
    episodes = sum(1 for _ in rec.decoded("/episode"))
    return states, versions, episodes


def main() -> int:
    args = parse()
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random().randint(1, 101)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["PYTHONUNBUFFERED"] = "1"
    from sdhn_sim.envs import make_env

    run = (args.run_dir or REPO / f"runs/soak-{time.strftime('%Y%m%d-%H%M%S')}").resolve()
    n = make_env(args.env).num_robots
    rng = random.Random(args.seed)
    sets = [f"run_dir={run}", f"env={args.env}", "mode=train", "episodes=0", "recorder=true",
            "restart.policy=on-failure", "restart.max_restarts=1000",
            f"step_deadline={args.step_deadline}", f"seed={args.seed}",
            f"trainer.rollout_steps={args.rollout_steps}", "status_interval=10"]
    cmd = [*LAUNCH, *(x for item in sets for x in ("--set", item))]
    print(f"[soak] {n} robots on {args.env}, {args.minutes} min, a kill every "
          f"{args.kill_every}s; run dir {run}; ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}")
    load_start = os.getloadavg()
    load_end = load_start
    run.mkdir(parents=True, exist_ok=True)
    out = open(run / "soak-launcher.log", "w")  # noqa: SIM115
    launcher = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, cwd=REPO)
    expected = {"sim", "trainer", "recorder", *(f"actor_{i}" for i in range(n))}
    kills: list[tuple[str, float]] = []
    try:
        t_boot = time.monotonic()
        if not wait_until(lambda: expected <= set(children(launcher.pid)), 180, poll=0.5):
            print(f"[soak] the graph never came up; see {run / 'soak-launcher.log'}")
            return 1
        print(f"[soak] all {len(expected)} processes up after {time.monotonic() - t_boot:.1f}s;"
              f" {args.warmup}s of warm-up")
        time.sleep(args.warmup)
        pid0 = children(launcher.pid)
        rss0 = {k: tree_rss_kb(p) for k, p in pid0.items()}
        t0, t0_wall = time.monotonic(), time.time()
        next_kill = t0 + args.kill_every
        trace: dict[str, list[int]] = {k: [v or 0] for k, v in rss0.items()}
        next_sample = t0 + 30.0
        end = t0 + args.minutes * 60
        while time.monotonic() < end:
            if launcher.poll() is not None:
                print("[soak] launcher exited early")
                break
            if time.monotonic() >= next_kill:
                name = f"actor_{rng.randrange(n)}"
                pid = children(launcher.pid).get(name)
                if pid is not None:
                    kills.append((name, time.time()))
                    os.kill(pid, signal.SIGKILL)
                    print(f"[soak] t={time.monotonic() - t0:.0f}s killed {name} (pid {pid})")
                next_kill += args.kill_every
            if time.monotonic() >= next_sample:
                next_sample += 30.0
                for k, p in children(launcher.pid).items():
                    trace.setdefault(k, []).append(tree_rss_kb(p) or 0)
            time.sleep(0.2)
        time.sleep(min(30.0, args.kill_every))  # let the last kill recover before stopping
        now_pids = children(launcher.pid)
        rss1 = {k: tree_rss_kb(p) for k, p in now_pids.items()}
        load_end = os.getloadavg()
        elapsed = time.monotonic() - t0
    finally:
        if launcher.poll() is None:
            launcher.send_signal(signal.SIGTERM)
            try:
                launcher.wait(timeout=60)
            except subprocess.TimeoutExpired:
                launcher.kill()
                launcher.wait()
        out.close()

    states_all, versions, episodes = recorded(run)
    states = [s for s in states_all if stamp(s) >= t0_wall]
    steps = len(states)
    missed = sum(int(s.missed_actions) for s in states)
    print("\n[soak] results")
    print(f"  load average (1 min) at start {load_start[0]:.1f}, at end {load_end[0]:.1f} "
          f"({os.cpu_count()} CPUs)")
    print(f"  duration {elapsed:.0f}s: {steps} team steps ({steps / elapsed:.1f}/s), "
          f"{missed} missed actions, {episodes} episodes, "
          f"weights v{max(versions, default=0)}")
    print(f"  {'kill':<10} {'recovery_s':>10} {'steps_missing':>13}")
    rec = []
    for name, t in kills:
        back, missing = recovery(states, t)
        rec.append(None if back is None else back - t)
        print(f"  {name:<10} {('never' if back is None else f'{back - t:.2f}'):>10} "
              f"{missing:>13}")
    good = [r for r in rec if r is not None]
    if good:
        print(f"  recovery: mean {sum(good) / len(good):.2f}s, max {max(good):.2f}s, "
              f"{len(rec) - len(good)} never")
    print(f"\n  {'process':<10} {'pid':>8} {'rss_start_MB':>12} {'rss_end_MB':>10} "
          f"{'change':>8}  note")
    flat = True
    for name in sorted(rss0, key=lambda k: (k.startswith("actor"), len(k), k)):
        a, b = rss0[name], rss1.get(name)
        same = now_pids.get(name) == pid0.get(name)
        note = "" if same else "restarted (new process)"
        change = "" if (a is None or b is None) else f"{(b - a) / a * 100:+.1f}%"
        if same and a and b and abs(b - a) / a > 0.10:
            flat, note = False, "GREW >10%"
        print(f"  {name:<10} {now_pids.get(name, 0):>8} "
              f"{(a or 0) / 1024:>12.1f} {(b or 0) / 1024:>10.1f} {change:>8}  {note}")
    print(f"  RSS flat within 10% for every process that was not restarted: {flat}")
    for name in ("sim", "trainer", "recorder", "actor_0"):
        if name in trace:
            mb = " ".join(f"{v / 1024:.0f}" for v in trace[name])
            print(f"  RSS every 30 s, {name}: {mb} MB")
    # -- issue 15: transitions, deadline misses, weights latency ------------------------------
    status_file = run / "status" / "trainer.status.json"
    st = json.loads(status_file.read_text()) if status_file.exists() else {}
    made = [s for s in states_all if not (s.terminated or s.truncated)]  # steps made
    excepted = sum(1 for s in states_all if s.missed_actions)  # a robot 'stay'ed: not learnable
    transitions = int(st.get("transitions", 0))
    if made:
        print(f"\n  sim steps (whole run, terminal frames excluded): {len(made)}; with a missed "
              f"action (killed actor): {excepted}; trainer transitions: {transitions} = "
              f"{transitions / len(made):.1%} of all, "
              f"{transitions / max(len(made) - excepted, 1):.2%} of the answered ones "
              f"(goal >= 99 %)")
        print(f"  trainer: learned {st.get('transitions_learned')} transitions, dropped "
              f"{st.get('dropped')}, executor lag max {st.get('executor_lag_max_ms')} ms")
    outage = 0
    for _name, t in kills:
        outage += recovery(states, t)[1]
    misses = sum(1 for s in states if s.missed_actions)
    print(f"  sim steps with a deadline miss after warm-up: {misses}; in the kills' outages: "
          f"{outage}; elsewhere: {misses - outage} (goal 0)")
    print(f"\n  dropped messages per process: {drops_from_logs(run) or 'none'}")
    from sdhn_sim.recording.reader import read_recording

    mcap = run / "recording.mcap"
    if mcap.exists():
        r = read_recording(mcap)
        print(f"  weights in use by every live actor after an update's end: "
              f"{percentiles(weights_latency(r, kills))} (goal: all within 1 s)")
        from mcap.reader import make_reader

        with mcap.open("rb") as f:
            summary = make_reader(f).get_summary()
        complete = r.truncated is None and summary is not None
        print(f"  MCAP {mcap}: {len(r.messages)} messages, {mcap.stat().st_size / 1e6:.1f} MB, "
              f"complete (summary + index, no truncation): {complete}"
              + (f" ({r.truncated.line()})" if r.truncated else ""))
    else:
        print("  MCAP: none written")
    print(f"  launcher exit code: {launcher.returncode}")
    if not steps:
        print("  no simulator step was recorded after the warm-up: the graph never acted")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
