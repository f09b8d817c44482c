"""SIGKILL one process of a running train-mode graph (launcher: sim + 4 actor processes +
trainer on maif-tiny, restart on failure) and watch the rest from the test process: what keeps
running, how long recovery takes, which weights versions flow. The recorder is killed on its
own, in front of a stream published from the test process."""

from __future__ import annotations

import copy
import itertools
import json
import os
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import rclpy
from rclpy.serialization import serialize_message
from ros.processes import ROS2, NodeProcess, node_processes
from ros.team_stream import team_stream

from sdhn_base.polling import wait_until
from sdhn_base.ros import topics
from sdhn_base.ros.qos import STEP
from sdhn_sim.recording.reader import decode, read_recording
from sdhn_sim.recording.writer import CHUNK_BYTES
from sdhn_train.checkpoint import latest_checkpoint

from .graph import (
    TRAIN_TINY,
    Peer,
    Received,
    Seen,
    Watcher,
    alive,
    launch_cmd,
    log_lines,
    pids,
)

pytestmark = pytest.mark.ros
N = 4
DEADLINE = 0.5


def unique_ns(request: pytest.FixtureRequest) -> str:
    """A team namespace of this test alone: a process killed by an earlier test stays in the DDS
    graph until its lease expires and must not count as a peer here."""
    return "/f_" + re.sub(r"\W", "_", request.node.name)[:40]


@pytest.fixture()
def graph(tmp_path: Path, request: pytest.FixtureRequest
          ) -> Iterator[tuple[NodeProcess, Watcher, Path]]:
    """The running train graph, the watcher, and the run dir; stopped cleanly afterwards."""
    ns = unique_ns(request)
    watcher = Watcher(ns, N)
    try:
        with node_processes(launch_cmd(tmp_path, *TRAIN_TINY, f"team_ns={ns}")) as (launcher,):
            yield launcher, watcher, tmp_path
            launcher.stop(signal.SIGTERM, timeout=25)
    finally:
        watcher.close()


def started(launcher: NodeProcess, watcher: Watcher, version: int = 2,
            timeout: float = 50) -> None:
    ok = wait_until(lambda: watcher.seen.latest_version() >= version
                    and all(watcher.seen.actions[i] for i in range(N)), timeout)
    assert ok, (f"graph not training within {timeout}s: versions {watcher.seen.versions()}, "
                f"actions {[len(v) for v in watcher.seen.actions.values()]}\n{launcher.output}")


def kill(launcher: NodeProcess, name: str) -> tuple[int, float]:
    """SIGKILL ``name`` and return once it is dead. ``os.kill`` returns as soon as the signal is
    queued: a process inside a system call (an fsync of a checkpoint, under load tens of ms)
    finishes that call first, so what it leaves on disk is only final once it is gone."""
    pid = pids(launcher)[name]
    t = time.time()
    os.kill(pid, signal.SIGKILL)
    assert wait_until(lambda: not alive(pid), 10, poll=0.01), f"{name} (pid {pid}) survived"
    return pid, t


def answers_without_a_sim(seen: Seen, t_kill: float, t_new: float) -> list[Received]:
    """Actions stamped between the simulator's kill and its successor's first step that answer
    no observation the killed simulator sent. An answer in flight at the kill is fine however
    late a starved actor publishes it, so no time window decides: the killed simulator sent the
    steps of its states (stamped before the kill) and at most one step past the last (its
    observations go out before its state); each robot answers each of those at most once."""
    sent = {(int(s.msg.episode), int(s.msg.step)) for s in seen.states
            if stamp(s.msg) <= t_kill}
    if sent:
        e, st = max(sent)
        sent |= {(e, st + 1), (e + 1, 0)}
    bad = []
    for robot in seen.actions:
        answered: set[tuple[int, int]] = set()
        for r in seen.actions[robot]:
            if not t_kill < stamp(r.msg) < t_new:
                continue
            k = (int(r.msg.episode), int(r.msg.step))
            if k not in sent or k in answered:
                bad.append(r)
            answered.add(k)
    return bad


def stamp(msg: object) -> float:
    h = msg.header.stamp  # type: ignore[attr-defined]
    return h.sec + h.nanosec * 1e-9


def test_actor_killed_midepisode_is_respawned_and_acts_with_latest_weights(graph) -> None:
    """Timing comes from the nodes' own clocks (same host): the actor's log stamps and the
    simulator's TeamState stamps; the watcher (default discovery timing) may match a respawned
    actor seconds later than the simulator does, so it only reports versions."""
    launcher, watcher, run = graph
    seen = watcher.seen
    started(launcher, watcher)
    _, t_kill = kill(launcher, "actor_2")
    v_at_kill = seen.latest_version()
    assert launcher.wait_for_line("restarted actor_2", timeout=10), launcher.output

    def back() -> object | None:
        """The first state after the outage that has every action again (robot 2 is back)."""
        after = [s for s in seen.states if stamp(s.msg) > t_kill and s.msg.step > 0]
        k = next((i for i, s in enumerate(after) if s.msg.missed_actions), None)
        if k is None:
            return None
        return next((s for s in after[k:] if s.msg.missed_actions == 0), None)
    assert wait_until(back, 30), f"robot 2 never answered again:\n{launcher.output}"
    t_back = stamp(back().msg)  # type: ignore[union-attr]
    outage = [s for s in seen.states if t_kill < stamp(s.msg) < t_back]
    missed = sum(int(s.msg.missed_actions) for s in outage)
    stepped = sum(1 for s in outage if s.msg.step > 0)
    worst = max((stamp(b.msg) - stamp(a.msg) for a, b in itertools.pairwise(outage)),
                default=0.0)
    # The new process: its 'ready' line and the weights it took from the latched topic.
    lines = log_lines(run / "logs" / "actor_2.log")
    ready = [ln for ln in lines if ln.text.startswith("ready") and ln.t > t_kill]
    took = [ln for ln in lines if "accepted" in ln.text and ln.t > t_kill]
    assert ready and took, f"restarted actor_2 log:\n{[ln.text for ln in lines]}"
    v_took = int(took[0].text.split()[2])
    assert wait_until(lambda: any(stamp(r.msg) > t_kill for r in seen.actions[2]), 20)
    first = next(r for r in seen.actions[2] if stamp(r.msg) > t_kill)
    report = (f"kill->answering again {t_back - t_kill:.2f}s (kill->ready "
              f"{ready[0].t - t_kill:.2f}s, ready->weights {took[0].t - ready[0].t:.2f}s, "
              f"weights->answer counted by sim {t_back - took[0].t:.2f}s), ready->answer "
              f"{t_back - ready[0].t:.2f}s; outage: {stepped} sim steps, {missed} missed "
              f"actions, longest step {worst:.2f}s (deadline {DEADLINE}s); latest version at "
              f"kill v{v_at_kill}, restarted actor took v{v_took} (latched), its first action "
              f"seen v{first.msg.policy_version}")
    print(report)
    # Stepping went on, robot 2 missing (the first step may have been answered before the kill).
    assert stepped >= 1 and missed >= stepped - 1, report
    # The simulator never waits for the dead robot past its deadline. The bound leaves room for
    # a CPU-starved host (a 1.5 s step was seen at load 40); the real figure is printed above.
    assert worst <= DEADLINE + 3.0, report
    assert v_took >= v_at_kill and first.msg.policy_version >= v_took, report
    # Acting soon after holding the weights. Matching the trainer for the latched weights took
    # 0.0-0.7 s in most runs (0.5 s announcements, data/fastdds.xml), up to 2.7 s on this shared
    # 2-core host under load. These are bounds on a stuck actor, not speed goals (the report
    # prints the figures; docs/reliability.md quotes them).
    assert t_back - took[0].t <= 10.0, report
    assert t_back - ready[0].t <= 15.0, report


def test_trainer_killed_actors_keep_acting_and_restart_resumes(graph) -> None:
    launcher, watcher, run = graph
    seen = watcher.seen
    started(launcher, watcher, version=3)
    _, t_kill = kill(launcher, "trainer")
    v_pub = seen.latest_version()
    # A checkpoint of every published version exists (written before publishing).
    newest = latest_checkpoint(run / "trainer")
    assert newest is not None, "no checkpoint on disk"
    v_ckpt = int(json.loads(newest.with_suffix(".json").read_text())["version"])
    # Actors keep acting with their last weights while no trainer runs.
    assert launcher.wait_for_line("restarted trainer", timeout=10), launcher.output
    acting = [r for i in range(N) for r in seen.actions[i] if r.t > t_kill]
    lines = []

    def resumed() -> bool:
        lines[:] = [ln for ln in log_lines(run / "logs" / "trainer.log")
                    if ln.t > t_kill and ln.text.startswith("ready")]
        return bool(lines)
    assert wait_until(resumed, 90), f"trainer never ready again:\n{launcher.output}"
    t_ready = lines[0].t
    during = [r for i in range(N) for r in seen.actions[i] if t_kill < r.t < t_ready]
    versions_during = sorted({int(r.msg.policy_version) for r in during})
    # A bound on a stuck trainer: after its restart it must spawn its learner offload process
    # (torch import, 25-33 s at load 20+ on 2 cores) and finish a rollout and an update.
    assert wait_until(lambda: seen.latest_version() > v_ckpt, 120), (
        f"no new version after restart: {seen.versions()}; "
        f"{restarted_trainer(run, seen, t_kill, t_ready)}\n{launcher.output}")
    versions = seen.versions()
    t_new = next(r.t for r in seen.weights if int(r.msg.version) > v_ckpt)
    report = (f"published v{v_pub} at kill, newest checkpoint v{v_ckpt}; trainer back after "
              f"{t_ready - t_kill:.1f}s: '{lines[0].text[:120]}'; {len(during)} actions while "
              f"it was down (versions {versions_during}); its first new version "
              f"{first_update(run, t_kill)}, seen {t_new - t_ready:.2f}s after its ready; "
              f"published versions {versions}")
    print(report)
    assert len(acting) > 0 and len(during) >= N, report
    # Every actor goes on with the weights it had (or ones still in flight at the kill), never
    # older ones. Not "at least v_pub - 1" for all: under load an actor can be two versions
    # behind when the trainer dies, its reliable writer going with it (versions [1, 3] at v3,
    # load ~10, 7 Dec 2026).
    for i in range(N):
        had = max((int(r.msg.policy_version) for r in seen.actions[i] if r.t <= t_kill),
                  default=0)
        used = sorted({int(r.msg.policy_version) for r in seen.actions[i]
                       if t_kill < r.t < t_ready})
        assert used and used[0] >= had, f"{report}; robot {i}: v{had} before the kill, {used} after"
    assert f"version={v_ckpt} (resumed from step_" in lines[0].text, report
    assert v_ckpt >= v_pub, report
    assert all(b >= a for a, b in itertools.pairwise(versions)), report


def first_update(run: Path, t_kill: float) -> str:
    """The restarted trainer's first update, timed from its ready line (both its own log)."""
    lines = [ln for ln in log_lines(run / "logs" / "trainer.log") if ln.t > t_kill]
    ready = next((ln for ln in lines if ln.text.startswith("ready")), None)
    update = next((ln for ln in lines if ln.text.startswith("update:")), None)
    if ready is None or update is None:
        return "none logged"
    return f"{update.text.split()[1]} {update.t - ready.t:.2f}s after its ready"


def restarted_trainer(run: Path, seen: Seen, t_kill: float, t_ready: float) -> str:
    """Why a restarted trainer published nothing new, in the words of each suspect: the loop
    (did the simulator and every robot go on after the restart?), the trainer (its status file:
    steps assembled, drops by cause, what incomplete steps lacked, resubscriptions; its log's
    last lines, tracebacks of its learner offload process included) and the watcher (when it
    last heard anything)."""
    now = time.time()
    after = {i: [r for r in seen.actions[i] if r.t > t_ready] for i in range(N)}
    loop = ", ".join(f"robot {i}: {len(v)} (v{max(int(r.msg.policy_version) for r in v)})"
                     if v else f"robot {i}: 0" for i, v in after.items())
    states = [s for s in seen.states if s.t > t_ready]
    last = max((r.t for v in [seen.states, *seen.actions.values()] for r in v[-1:]),
               default=t_kill)
    try:
        status = (run / "status" / "trainer.status.json").read_text()
    except OSError as e:
        status = f"({e})"
    log = (run / "logs" / "trainer.log").read_text(errors="replace").splitlines()
    return (f"since the restarted trainer's ready ({now - t_ready:.0f}s ago): {len(states)} "
            f"states, actions {loop}; watcher's last message {now - last:.1f}s ago; first new "
            f"version {first_update(run, t_kill)}; trainer status: {status.strip()}; "
            f"trainer log, last lines (kill at {t_kill:.3f}):\n" + "\n".join(log[-60:]))


def test_sim_killed_actors_and_trainer_idle_then_continue(graph) -> None:
    launcher, watcher, run = graph
    seen = watcher.seen
    started(launcher, watcher)
    assert wait_until(lambda: len(seen.episodes) >= 2, 40), f"episodes {len(seen.episodes)}"
    survivors = {k: v for k, v in pids(launcher).items() if k != "sim"}
    episode_at_kill = max(int(s.msg.episode) for s in seen.states)
    _, t_kill = kill(launcher, "sim")
    assert launcher.wait_for_line("restarted sim", timeout=10), launcher.output
    # The new simulator's own log says when it had matched everyone and began episode 0.
    began: list = []

    def restarted() -> bool:
        began[:] = [ln for ln in log_lines(run / "logs" / "sim.log")
                    if ln.t > t_kill and "starting episode 0" in ln.text]
        return bool(began)
    assert wait_until(restarted, 40), f"restarted sim never started:\n{launcher.output}"
    t_new = began[0].t
    # Nobody acts while no simulator runs (answers to observations in flight at the kill
    # excepted, whenever they come).
    idle = answers_without_a_sim(seen, t_kill, t_new)
    v_before = seen.latest_version()
    assert wait_until(lambda: any(stamp(r.msg) > t_new for r in seen.episodes), 40), (
        "no episode finished after the restart")
    assert wait_until(lambda: seen.latest_version() > v_before, 40), (
        f"trainer did not learn from the new sim: versions {seen.versions()}")
    after = [s for s in seen.states if stamp(s.msg) > t_new]
    # The new sim's own events (not the watcher, whose discovery of the new sim may lag several
    # short episodes behind): its first finished episode after its 'started' event.
    def new_sim_episodes() -> list[int]:
        events = [json.loads(line) for line in
                  (run / "status" / "sim-events.jsonl").read_text().splitlines() if line.strip()]
        last_start = max(i for i, e in enumerate(events) if e.get("event") == "started")
        return [int(e["episode"]) for e in events[last_start + 1:] if e.get("event") == "episode"]
    assert wait_until(lambda: bool(new_sim_episodes()), 20), "the new sim finished no episode"
    restarted_counter = new_sim_episodes()[0]
    report = (f"killed in episode {episode_at_kill}; new sim began episode 0 {t_new - t_kill:.1f}s "
              f"after the kill ('{began[0].text}'); {len(idle)} actions while it was gone; "
              f"first episode the new sim finished: {restarted_counter}; versions "
              f"{seen.versions()}")
    print(report)
    assert all(alive(p) for p in survivors.values()), (
        f"{[k for k, p in survivors.items() if not alive(p)]} died\n{launcher.output}")
    assert not any(f"{k} (pid" in launcher.output for k in survivors), launcher.output
    assert not idle, report
    assert restarted_counter == 0, report  # a new run of episodes, not a resume
    # Step 0 of the new run may miss actors: the sim checks matching from its own side only, and
    # an actor whose reader has not matched the new sim's writer yet drops that observation.
    first_missed = next((int(s.msg.missed_actions) for s in after if s.msg.step == 1), None)
    later = [int(s.msg.missed_actions) for s in after if s.msg.step > 1 or s.msg.episode > 0]
    print(f"missed at the new run's step 0: {first_missed}; later steps missing: {sum(later)}")
    assert not any(later), f"missed actions after the new run's step 0: {later}"


WARMUP = 9999


def key(m: object) -> tuple[int, ...]:
    return tuple(int(getattr(m, f)) for f in ("episode", "step", "robot_id") if hasattr(m, f))


def test_recorder_killed_leaves_readable_mcap_and_replay_says_truncated(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    ns = "/f_recfault"
    msgs = list(team_stream(episodes=24, max_steps=12))  # > 1 chunk of 256 KiB
    peer = Peer("rec_fault_pub")
    pubs = {o.topic: peer.node.create_publisher(type(o.message), topics.absolute(ns, o.topic), STEP)
            for o in msgs}
    peer.start()
    rec_cmd = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={out}",
               "-p", f"team_ns:={ns}"]
    try:
        with node_processes(rec_cmd) as (recorder,):
            assert recorder.wait_for_line("ready", timeout=20), recorder.output
            assert wait_until(lambda: all(p.get_subscription_count() for p in pubs.values()),
                              20), f"recorder never subscribed:\n{recorder.output}"
            # One warm-up message per topic (episode WARMUP, not compared), acked: a reader
            # acks only once it has matched the writer too, and volatile messages sent before
            # that would be lost to it.
            for o in msgs[:len(pubs) * 3]:
                warm = copy.copy(o.message)
                warm.episode = WARMUP  # type: ignore[attr-defined]
                pubs[o.topic].publish(warm)
            for p in pubs.values():
                assert p.wait_for_all_acked(rclpy.duration.Duration(seconds=15))
            sent: dict[str, list[object]] = {}
            t0 = time.monotonic()
            for o in msgs:
                pubs[o.topic].publish(o.message)
                sent.setdefault(topics.absolute(ns, o.topic), []).append(o.message)
                if o.topic == "episode":  # ~13 messages per topic per episode: paced so
                    time.sleep(0.1)  # neither queue (depth 64) overflows on a loaded host
            for p in pubs.values():
                p.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
            # Let the recorder write everything it took in: the file stops growing once only
            # the open chunk (< CHUNK_BYTES, in memory) is left. Then kill it.
            sizes = [-1]

            def settled() -> bool:
                sizes.append(out.stat().st_size)
                return len(sizes) > 15 and sizes[-1] == sizes[-15] and sizes[-1] > 0
            t1 = time.monotonic()
            assert wait_until(settled, 60, poll=0.1), f"file sizes {sizes[-5:]}"
            print(f"published+acked in {t1 - t0:.1f}s, recorder settled "
                  f"{time.monotonic() - t1:.1f}s later")
            recorder.proc.send_signal(signal.SIGKILL)
            recorder.proc.wait()
    finally:
        peer.close()
    rec = read_recording(out)
    total_sent = sum(len(v) for v in sent.values())
    got: dict[str, list[tuple[int, ...]]] = {}
    for m in rec.messages:
        k = key(decode(m))
        if k[0] != WARMUP:
            got.setdefault(m.topic, []).append(k)
    lost_bytes = sum(len(serialize_message(x)) for t, v in sent.items()
                     for x in v[len(got.get(t, [])):])
    report = (f"{len(rec.messages)}/{total_sent} messages readable "
              f"({out.stat().st_size} B file), lost {lost_bytes} B of CDR "
              f"(chunk size {CHUNK_BYTES}); truncation: "
              f"{rec.truncated.line() if rec.truncated else None}")
    print(report)
    assert rec.truncated is not None, report
    assert rec.messages, report
    for topic, data in got.items():  # a prefix of what was sent, per topic, nothing skipped
        want = [key(x) for x in sent[topic][:len(data)]]
        assert data == want, f"{topic}: recorded (episode, step, robot) differ ({report})"
    assert lost_bytes <= CHUNK_BYTES, f"more than the last open chunk was lost: {report}"
    done = subprocess.run([*ROS2, "run", "sdhn_sim", "replay", str(out), "--summary"],
                          capture_output=True, text=True, timeout=60, check=False)
    err = [ln for ln in done.stderr.splitlines() if ln.strip()]
    print(f"replay --summary: exit {done.returncode}; stderr {err}; "
          f"{len(done.stdout.splitlines())} table lines")
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    assert len(err) == 1 and "truncated" in err[0], f"stderr: {done.stderr}"
    assert done.stdout.splitlines()[0].split()[0] == "episode", done.stdout


def test_recorder_killed_before_first_chunk_leaves_an_mcap_replay_reads(tmp_path: Path) -> None:
    """Killed right after start (nothing but the open chunk): the file still starts like an
    MCAP file, so replay reports 0 messages, truncated, instead of 'not an MCAP file'."""
    out = tmp_path / "early.mcap"
    rec_cmd = [*ROS2, "run", "sdhn_sim", "recorder", "--ros-args", "-p", f"output:={out}",
               "-p", "team_ns:=/recearly"]
    with node_processes(rec_cmd) as (recorder,):
        assert recorder.wait_for_line("ready", timeout=20), recorder.output
        recorder.proc.send_signal(signal.SIGKILL)
        recorder.proc.wait()
    done = subprocess.run([*ROS2, "run", "sdhn_sim", "replay", str(out), "--summary"],
                          capture_output=True, text=True, timeout=60, check=False)
    err = [ln for ln in done.stderr.splitlines() if ln.strip()]
    print(f"early kill: {out.stat().st_size} B file; replay exit {done.returncode}: {err}")
    assert done.returncode == 0 and len(err) == 1 and "truncated after 0 messages" in err[0], (
        f"exit {done.returncode}, stderr {done.stderr}")


def test_trainer_that_hears_nothing_is_replaced_by_the_launcher(tmp_path: Path,
                                                                 request: pytest.FixtureRequest
                                                                 ) -> None:
    """restart.deaf_trainer_s: a trainer alive but hearing nothing (a restarted trainer's DDS
    participant that never gets a message, docs/reliability.md) looks to the launcher like a
    SIGSTOPped one: its status file stands still while the simulator plays on. The launcher
    SIGKILLs it, the restart resumes from the checkpoint, and learning goes on."""
    ns = unique_ns(request)
    watcher = Watcher(ns, N)
    stopped: list[int] = []
    try:
        cmd = launch_cmd(tmp_path, *TRAIN_TINY, f"team_ns={ns}", "restart.deaf_trainer_s=5")
        with node_processes(cmd) as (launcher,):
            started(launcher, watcher, version=2)
            # the watch reads the trainer's status file (every 2 s): stopped before its first
            # one, the trainer would be a process that never said anything, not a deaf one
            status = tmp_path / "status" / "trainer.status.json"
            assert wait_until(status.is_file, 20), launcher.output
            pid = pids(launcher)["trainer"]
            os.kill(pid, signal.SIGSTOP)
            # a stopped process keeps its parent-death SIGTERM pending: should the test fail
            # before the launcher kills it, the finally below does, or it would outlive the run
            stopped.append(pid)
            t_stop = time.time()
            assert launcher.wait_for_line("hears nothing", timeout=60), launcher.output
            assert launcher.wait_for_line("restarted trainer", timeout=20), launcher.output
            assert wait_until(lambda: not alive(pid), 10), f"stopped trainer {pid} not killed"
            said = next(ln for ln in launcher.lines if "hears nothing" in ln)
            assert f"pid {pid}" in said and "killing it for a fresh process" in said, said
            ready: list = []

            def resumed() -> bool:
                ready[:] = [ln for ln in log_lines(tmp_path / "logs" / "trainer.log")
                            if ln.t > t_stop and ln.text.startswith("ready")]
                return bool(ready)
            assert wait_until(resumed, 90), f"no new trainer ready:\n{launcher.output}"
            m = re.search(r"version=(\d+) \(resumed from step_", ready[0].text)
            assert m, ready[0].text
            v_resumed = int(m.group(1))
            # the new process learns: a version past the one it resumed at
            assert wait_until(lambda: watcher.seen.latest_version() > v_resumed, 120), (
                f"no version after v{v_resumed}: {watcher.seen.versions()}\n{launcher.output}")
            # once: the new process is not judged by the killed one's status file while it starts
            assert sum("hears nothing" in ln for ln in launcher.lines) == 1, launcher.output
            print(f"{said.strip()}; versions {watcher.seen.versions()}")
            launcher.stop(signal.SIGTERM, timeout=25)
    finally:
        for pid in stopped:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        watcher.close()
