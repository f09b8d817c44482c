"""The trainer node's learner in its own process (ROS-free): PPO updates can never starve the
node's executor, whatever they cost.

Why a process: a 7.5 s update on a worker thread of the node held the GIL for long stretches, the
executor could not run the subscription callbacks, and the STEP queues overflowed (the node kept
about 20 % of the steps at 20 robots, issue 15). A separate process has its own interpreter; it
also runs ``nice``-d (``LEARNER_NICE``), so on a busy machine the lock-step loop (simulator,
actors) gets the CPU first and the learner takes what is left.

Hand-over, both directions over two one-way pipes (``multiprocessing`` with the ``spawn``
context: a fresh interpreter, no forked copy of the node's DDS state). A message is one JSON
header frame naming its kind, its scalar fields and its arrays (name, dtype, shape), followed by
one raw frame per array, received straight into a preallocated NumPy array
(``recv_bytes_into``). Nothing is pickled: not the rollouts, not the weights.

    node -> learner   "rollout"  the assembled rollout's arrays + the episode summaries since the
                                 last one;  "stop"
    learner -> node   "ready"    version, weights (format, sha256, payload) of the start version
                      "update"   version, metrics, timings, the update's end time, weights,
                                 hypergraph samples, rollouts the learner dropped so far
                      "error"    a message; ``config`` = true when the run_dir/resume or
                                 actor.init_from is unusable

In the learner offload process a receiver thread drains the pipe at once (so the node's sender never
waits on an update in progress) into a queue of at most ``LEARNER_QUEUE`` rollouts; when the
learner falls that far behind, the oldest waiting rollout is dropped and counted (freshest data
first), and the count travels back with the next update.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import json
import multiprocessing as mp
import os
import queue
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from sdhn_base.drops import DropKind
from sdhn_train.rollout import Rollout
from sdhn_train.transitions import AssembledRollout

LEARNER_QUEUE = 4  # rollouts waiting in the learner offload process; beyond that the oldest is
# dropped
LEARNER_NICE = 10  # the loop's processes come first on a busy machine

Arrays = dict[str, npt.NDArray[Any]]
ROLLOUT_FIELDS = ("obs", "state", "actions", "log_probs", "rewards", "terminated", "truncated",
                  "final_obs", "final_state")


# -- framing ---------------------------------------------------------------------------------


def send_message(conn: Connection, kind: str, fields: dict[str, Any] | None = None,
                 arrays: Arrays | None = None) -> None:
    """One JSON header frame, then one raw frame per array (no pickle)."""
    arrays = {k: np.ascontiguousarray(v) for k, v in (arrays or {}).items()}
    header = {"kind": kind, **(fields or {}),
              "arrays": [[k, v.dtype.str, list(v.shape)] for k, v in arrays.items()]}
    conn.send_bytes(json.dumps(header).encode())
    for v in arrays.values():
        conn.send_bytes(v.reshape(-1).view(np.uint8).data)


def recv_message(conn: Connection) -> tuple[dict[str, Any], Arrays]:
    """The next message: (header, arrays); raises EOFError when the other end is gone."""
    header = json.loads(conn.recv_bytes())
    arrays: Arrays = {}
    for name, dtype, shape in header.pop("arrays"):
        a = np.empty(shape, np.dtype(dtype))
        if a.nbytes:
            conn.recv_bytes_into(a.reshape(-1).view(np.uint8).data)
        else:
            conn.recv_bytes()
        arrays[name] = a
    return header, arrays


def rollout_arrays(a: AssembledRollout) -> Arrays:
    r = a.rollout
    out: Arrays = {k: getattr(r, k) for k in ROLLOUT_FIELDS}
    out.update(versions=a.versions, keys=np.asarray(a.keys, np.int64).reshape(-1, 2),
               prefix_obs=a.prefix_obs, prefix_state=a.prefix_state)
    return out


def assembled_from(arrays: Arrays) -> AssembledRollout:
    n = arrays["actions"].shape[2]
    rollout = Rollout(**{k: arrays[k] for k in ROLLOUT_FIELDS},
                      actor_h0=np.zeros((1, n, 0), np.float32), critic_h0=None)
    keys = [(int(e), int(s)) for e, s in arrays["keys"]]
    return AssembledRollout(rollout, arrays["versions"], keys, arrays["prefix_obs"],
                            arrays["prefix_state"])


# -- the node's side -------------------------------------------------------------------------


@dataclass
class WeightsBlob:
    version: int
    format: str
    sha256: str
    payload: bytes


# (episode, step, skewness, P_H [N, M], sampled incidence H [N, M])
HypergraphSample = tuple[int, int, float, npt.NDArray[np.float32], npt.NDArray[np.uint8]]


@dataclass
class LearnerUpdate:
    """What the node publishes and logs after one update."""

    version: int
    transitions: int
    weights: WeightsBlob
    update_s: float
    checkpoint_s: float
    end_time: float  # time.time() when the update (and its checkpoint) ended
    metrics: dict[str, float]
    hypergraphs: list[HypergraphSample]
    dropped: dict[str, int] = field(default_factory=dict)


class LearnerStartError(RuntimeError):
    def __init__(self, message: str, config: bool) -> None:
        super().__init__(message)
        self.config = config


def _weights(header: dict[str, Any], arrays: Arrays) -> WeightsBlob:
    return WeightsBlob(int(header["version"]), str(header["format"]), str(header["sha256"]),
                       arrays["payload"].tobytes())


class LearnerClient:
    """Starts the learner offload process and talks to it from the node, without blocking the
    caller:
    ``submit`` only queues (a sender thread writes the pipe); results arrive on a receiver thread
    that calls ``on_update`` / ``on_error`` (those must only publish and log)."""

    def __init__(self, config: dict[str, Any], run_dir: Path, resume: bool,
                 start_timeout: float = 180.0, total_steps: int = 0) -> None:
        ctx = mp.get_context("spawn")
        self._to_child_r, self._to_child_w = ctx.Pipe(duplex=False)
        self._from_child_r, self._from_child_w = ctx.Pipe(duplex=False)
        self.process = ctx.Process(
            target=learner_main, name="sdhn-learner", daemon=True,
            args=(self._to_child_r, self._from_child_w, config, str(run_dir)),
            kwargs={"resume": resume, "parent_pid": os.getpid(), "total_steps": total_steps})
        self.process.start()
        self._to_child_r.close()
        self._from_child_w.close()
        if not self._from_child_r.poll(start_timeout):
            self.process.terminate()
            raise LearnerStartError(f"the learner offload process did not start within "
                                    f"{start_timeout:.0f} s", config=False)
        try:
            header, arrays = recv_message(self._from_child_r)
        except EOFError:
            raise LearnerStartError(f"the learner offload process died at start (exit code "
                                    f"{self.process.exitcode})", config=False) from None
        if header["kind"] == "error":
            self.process.join(timeout=5.0)
            raise LearnerStartError(str(header["message"]), config=bool(header.get("config")))
        self.start_weights = _weights(header, arrays)
        self.resumed: str | None = header.get("resumed")
        self.start_transitions = int(header.get("transitions", 0))
        self.on_update: Callable[[LearnerUpdate], None] = lambda _u: None
        self.on_error: Callable[[str], None] = lambda _m: None
        self._outbox: queue.Queue[tuple[str, dict[str, Any], Arrays] | None] = queue.Queue()
        self._sender = threading.Thread(target=self._send_loop, name="learner-send", daemon=True)
        self._receiver = threading.Thread(target=self._recv_loop, name="learner-recv",
                                          daemon=True)

    def start(self, on_update: Callable[[LearnerUpdate], None],
              on_error: Callable[[str], None]) -> None:
        self.on_update, self.on_error = on_update, on_error
        self._sender.start()
        self._receiver.start()

    def submit(self, assembled: AssembledRollout, episodes: list[dict[str, Any]]) -> None:
        """Queue a rollout for the learner (returns at once)."""
        self._outbox.put(("rollout", {"episodes": episodes}, rollout_arrays(assembled)))

    @property
    def waiting(self) -> int:
        return self._outbox.qsize()

    def _send_loop(self) -> None:
        while (item := self._outbox.get()) is not None:
            try:
                send_message(self._to_child_w, *item)
            except (OSError, ValueError):
                return  # the learner is gone; the receiver reports it

    def _recv_loop(self) -> None:
        while True:
            try:
                header, arrays = recv_message(self._from_child_r)
            except (EOFError, OSError):
                if self.process.exitcode not in (None, 0):
                    self.on_error(f"the learner offload process exited with code "
                                  f"{self.process.exitcode}")
                return
            if header["kind"] == "error":
                self.on_error(str(header["message"]))
            elif header["kind"] == "update":
                graphs = [(int(g["episode"]), int(g["step"]), float(g["skewness"]),
                           arrays[f"p_h_{k}"], arrays[f"incidence_{k}"])
                          for k, g in enumerate(header["hypergraphs"])]
                self.on_update(LearnerUpdate(
                    int(header["version"]), int(header["transitions"]),
                    _weights(header, arrays), float(header["update_s"]),
                    float(header["checkpoint_s"]), float(header["end_time"]),
                    {k: float(v) for k, v in header["metrics"].items()}, graphs,
                    {k: int(v) for k, v in header["dropped"].items()}))

    def stop(self, timeout: float = 2.0) -> int | None:
        """Ask the learner to stop after the update in progress; kill it after ``timeout`` (it
        ignores SIGTERM; checkpoints are written atomically, so a cut never leaves a broken one,
        and the update it loses was never published). Bounded, so the node stops within the
        few seconds a supervisor allows, also when a loaded machine starves the niced learner."""
        self._outbox.put(("stop", {}, {}))
        self._outbox.put(None)
        self.process.join(timeout)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(1.0)
        self._receiver.join(timeout=1.0)
        return self.process.exitcode


# -- the learner offload process ---------------------------------------------------------------


def learner_main(inbox: Connection, outbox: Connection, params: dict[str, Any], run_dir: str,
                 *, resume: bool, parent_pid: int, total_steps: int = 0) -> None:
    """Entry point of the learner offload process (spawned): build the learner, then train on every
    rollout that arrives until "stop" or the node's end of the pipe closes; with ``total_steps``
    > 0, only until it has learned from that many transitions (later rollouts are counted)."""
    # Ctrl-C in a terminal reaches the whole process group: the node stops the learner itself
    # (a "stop" message, or the pipe closing when the node is gone).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # A node killed outright takes its learner along at once, so a restarted trainer's new
    # learner never races an orphan finishing an update (checkpoints are atomic either way).
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:
        return  # the node died before the line above took effect
    with contextlib.suppress(OSError):
        os.nice(LEARNER_NICE)
    from sdhn_sim.envs.registry import make_env  # heavy imports only in the child
    from sdhn_sim.episode import EpisodeResult
    from sdhn_train import checkpoint as ckpt
    from sdhn_train.config import Config, ConfigError, apply_dict
    from sdhn_train.env_features import resolve_features, wrap_features
    from sdhn_train.envinfo import EnvInfo
    from sdhn_train.learners.base import NonFiniteLossError
    from sdhn_train.metrics_file import MetricsLog
    from sdhn_train.runs import episode_metrics
    from sdhn_train.stream_learner import StreamLearner

    cfg = Config()
    apply_dict(cfg, params)  # the node's checked config (Config.to_dict), field by field
    env = make_env(cfg.env.name, num_envs=1, seed=cfg.train.seed)
    learner_env = wrap_features(env, resolve_features(cfg))  # the learner sees features
    try:
        learner = StreamLearner(cfg, EnvInfo.of(learner_env), Path(run_dir))
    except ConfigError as e:  # actor.init_from that cannot be read or does not fit
        send_message(outbox, "error", {
            "config": True, "message": f"init_from: {e}; allowed: an exported actor of this "
                                       "run's network and features, or ''"})
        return
    try:
        resumed = learner.resume_latest() if resume else None
    except (ckpt.CheckpointError, KeyError, ValueError, RuntimeError) as e:
        send_message(outbox, "error", {
            "config": True,
            "message": f"resume: the newest checkpoint in {run_dir} cannot be loaded "
                       f"({str(e)[:200]}); allowed: a run_dir with a valid checkpoint, "
                       "or resume:=false with a new run_dir"})
        return
    if resumed is None:
        learner.save_checkpoint()
    blob = learner.weights()
    send_message(outbox, "ready", {"version": blob.version, "format": blob.format,
                                   "sha256": blob.sha256, "transitions": learner.transitions,
                                   "resumed": resumed.name if resumed else None},
                 {"payload": np.frombuffer(blob.payload, np.uint8)})

    pending: collections.deque[tuple[dict[str, Any], Arrays]] = collections.deque()
    cond = threading.Condition()
    dropped: dict[str, int] = {}
    stop = [False]

    def receive() -> None:
        while True:
            try:
                header, arrays = recv_message(inbox)
            except (EOFError, OSError):
                header, arrays = {"kind": "stop"}, {}
            with cond:
                if header["kind"] == "stop":
                    stop[0] = True
                else:
                    if len(pending) >= LEARNER_QUEUE:
                        pending.popleft()
                        dropped[DropKind.LEARNER_BUSY] = dropped.get(DropKind.LEARNER_BUSY, 0) + 1
                    pending.append((header, arrays))
                cond.notify()
            if stop[0]:
                return

    threading.Thread(target=receive, name="learner-inbox", daemon=True).start()
    log = MetricsLog(learner.run_dir, cfg.log.tensorboard)
    try:
        while True:
            with cond:
                while not pending and not stop[0]:
                    cond.wait(timeout=1.0)
                if stop[0]:
                    return
                header, arrays = pending.popleft()
                if total_steps and learner.transitions >= total_steps:
                    past = DropKind.PAST_TOTAL_STEPS
                    dropped[past] = dropped.get(past, 0) + 1
                    continue
            assembled = assembled_from(arrays)
            try:
                result = learner.train(assembled, HYPERGRAPHS_PER_UPDATE)
            except NonFiniteLossError as e:
                send_message(outbox, "error", {"message": f"{e}; training stopped at version "
                                                          f"{learner.version}, last checkpoint "
                                                          "kept"})
                return
            end_time = time.time()
            episodes = [EpisodeResult.from_event(e).to_stats()
                        for e in header.get("episodes", [])]
            metrics = dict(result.metrics)
            metrics.update(episode_metrics("charts", episodes))
            metrics["perf/update_s"] = result.update_s
            metrics["perf/checkpoint_s"] = result.checkpoint_s
            log.write(learner.transitions, metrics)
            w = result.weights
            out: Arrays = {"payload": np.frombuffer(w.payload, np.uint8)}
            graphs = []
            for k, g in enumerate(result.hypergraphs):
                out[f"p_h_{k}"] = np.asarray(g.p_h, np.float32)
                out[f"incidence_{k}"] = np.asarray(g.incidence, np.uint8)
                graphs.append({"episode": g.episode, "step": g.step, "skewness": g.skewness})
            with cond:
                drops = dict(dropped)
            send_message(outbox, "update", {
                "version": result.version, "transitions": learner.transitions,
                "format": w.format, "sha256": w.sha256, "update_s": result.update_s,
                "checkpoint_s": result.checkpoint_s, "end_time": end_time,
                "metrics": {k: float(v) for k, v in metrics.items()}, "hypergraphs": graphs,
                "dropped": drops}, out)
    except (BrokenPipeError, EOFError):
        return  # the node is gone
    finally:
        log.close()


HYPERGRAPHS_PER_UPDATE = 8
