"""Soak: a train-mode graph (20 actor processes by default) for a while, killing a random actor
every minute; prints steps, recovery times, dropped messages, every process's RSS at start and
end, and whether the MCAP recording is complete. Not a CI test.

    .venv/bin/python scripts/soak.py --minutes 10          # nice it on a shared machine

Recovery time of a kill = from SIGKILL to the first simulator step that has every action again
(TeamState stamps and missed_actions, so the watcher's own discovery delay does not count).
RSS "start" is taken once the graph is training (after
``--warmup`` seconds), "end" just before the stop; processes restarted in between are compared
with their own first sample.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "test"))

from faults.graph import (  # noqa: E402
    Watcher,
    launch_cmd,
    pids,
    rss_kb,
    wait_until,
)
from ros.processes import NodeProcess  # noqa: E402


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


def stamp(msg: object) -> float:
    h = msg.header.stamp  # type: ignore[attr-defined]
    return float(h.sec + h.nanosec * 1e-9)


def recovery(states: list, t_kill: float) -> tuple[float | None, int]:
    """(sim time of the first step with every action again after the outage, steps in the
    outage), from the simulator's TeamState stamps and missed_actions counts."""
    after = [s for s in states if stamp(s.msg) > t_kill and s.msg.step > 0]
    k = next((i for i, s in enumerate(after) if s.msg.missed_actions), None)
    if k is None:
        return None, 0
    back = next((s for s in after[k:] if s.msg.missed_actions == 0), None)
    missing = sum(1 for s in after[k:] if back is None or stamp(s.msg) < stamp(back.msg))
    return (None if back is None else stamp(back.msg)), missing


def main() -> int:
    args = parse()
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.Random().randint(1, 101)))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ["PYTHONUNBUFFERED"] = "1"
    from sdhn_sim.launch.supervisor import (
        FASTDDS_PROFILE,  # the watcher discovers as fast as the children
    )

    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))
    run = (args.run_dir or REPO / f"runs/soak-{time.strftime('%Y%m%d-%H%M%S')}").resolve()
    from sdhn_sim.launch.supervisor import team_size

    n = team_size(args.env)
    rng = random.Random(args.seed)
    cmd = launch_cmd(run, f"env={args.env}", "mode=train", "episodes=0", "recorder=true",
                     "restart.policy=on-failure", "restart.max_restarts=1000",
                     f"step_deadline={args.step_deadline}", f"seed={args.seed}",
                     f"trainer.rollout_steps={args.rollout_steps}", "status_interval=10")
    print(f"[soak] {n} robots on {args.env}, {args.minutes} min, a kill every "
          f"{args.kill_every}s; run dir {run}; ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}")
    watcher = Watcher("/sdhn", n, name="soak_watcher")
    launcher = NodeProcess(cmd)
    seen = watcher.seen
    kills: list[tuple[str, float]] = []
    try:
        t_boot = time.monotonic()
        ok = wait_until(lambda: seen.latest_version() >= 1
                        and all(seen.actions[i] for i in range(n)), 180, poll=0.5)
        if not ok:
            print(launcher.output[-3000:])
            print("[soak] graph never started acting")
            return 1
        print(f"[soak] all {n} actors acting after {time.monotonic() - t_boot:.1f}s")
        time.sleep(args.warmup)
        rss0 = {k: rss_kb(p) for k, p in pids(launcher).items()}
        pid0 = dict(pids(launcher))
        states0 = len(seen.states)
        t0 = time.monotonic()
        next_kill = t0 + args.kill_every
        trace: dict[str, list[int]] = {k: [v or 0] for k, v in rss0.items()}
        next_sample = t0 + 30.0
        end = t0 + args.minutes * 60
        while time.monotonic() < end:
            if launcher.proc.poll() is not None:
                print("[soak] launcher exited early")
                break
            if time.monotonic() >= next_kill:
                name = f"actor_{rng.randrange(n)}"
                pid = pids(launcher)[name]
                kills.append((name, time.time()))
                os.kill(pid, signal.SIGKILL)
                print(f"[soak] t={time.monotonic() - t0:.0f}s killed {name} (pid {pid})")
                next_kill += args.kill_every
            if time.monotonic() >= next_sample:
                next_sample += 30.0
                for k, p in pids(launcher).items():
                    trace.setdefault(k, []).append(rss_kb(p) or 0)
            time.sleep(0.2)
        wait_until(lambda: all(recovery(seen.states, t)[0] for _, t in kills), 30)
        now_pids = pids(launcher)
        rss1 = {k: rss_kb(p) for k, p in now_pids.items()}
        steps = len(seen.states) - states0
        missed = sum(int(s.msg.missed_actions) for s in seen.states[states0:])
        elapsed = time.monotonic() - t0
        launcher.stop(signal.SIGTERM, timeout=60)
    finally:
        watcher.close()
        if launcher.proc.poll() is None:
            launcher.stop(signal.SIGTERM, timeout=60)

    print("\n[soak] results")
    print(f"  duration {elapsed:.0f}s: {steps} team steps ({steps / elapsed:.1f}/s), "
          f"{missed} missed actions, {len(seen.episodes)} episodes, "
          f"weights v{seen.latest_version()}")
    print(f"  {'kill':<10} {'recovery_s':>10} {'steps_missing':>13}")
    rec = []
    for name, t in kills:
        back, missing = recovery(seen.states, t)
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
    status = [ln for ln in (run / "logs" / "trainer.log").read_text(errors="replace").splitlines()
              if "status:" in ln]
    if status:
        print(f"  trainer's last status: {status[-1].split('status: ', 1)[1]}")
    print(f"\n  dropped messages per process: {drops_from_logs(run) or 'none'}")
    from sdhn_sim.recording.reader import read_recording

    mcap = run / "recording.mcap"
    if mcap.exists():
        r = read_recording(mcap)
        from mcap.reader import make_reader

        with mcap.open("rb") as f:
            summary = make_reader(f).get_summary()
        complete = r.truncated is None and summary is not None
        print(f"  MCAP {mcap}: {len(r.messages)} messages, {mcap.stat().st_size / 1e6:.1f} MB, "
              f"complete (summary + index, no truncation): {complete}"
              + (f" ({r.truncated.line()})" if r.truncated else ""))
    else:
        print("  MCAP: none written")
    codes = next((ln for ln in launcher.lines if "exit codes:" in ln), "(no exit line)")
    print(f"  launcher: {codes.strip()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
