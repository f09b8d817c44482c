"""Starting, serving and stopping the data-parallel ranks (``train.learner_processes``).

    with learner_ranks(cfg, run_dir, resume, warm_start) as group:   # None when K = 1
        code = Trainer(cfg, run_dir=run_dir, warm_start=warm_start, group=group).run(resume)

This process is rank 0; ranks 1..K-1 are spawned here and run ``serve``: the same
``Trainer.train_iteration`` as rank 0 whenever it says so, and their checkpoint shard or CPU usage
on request. They ignore SIGINT / SIGTERM: a Ctrl-C reaches the whole process group, and rank 0
alone decides to stop (after a checkpoint that holds every rank's shard). A rank that fails puts
its error on a queue and exits; its peers' next collective then fails at once (its sockets
closed), and rank 0 raises one ``RankFailedError`` naming it.
"""

from __future__ import annotations

import contextlib
import resource
import shutil
import signal
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch.multiprocessing as mp

from sdhn_train.config import Config, apply_dict
from sdhn_train.data_parallel import Command, Group, RankFailedError, end_rank
from sdhn_train.learners.base import NonFiniteLossError
from sdhn_train.trainer import EnvFactory, Trainer, default_env_factory


@dataclass
class Usage:
    cpu_s: float  # process CPU seconds so far
    peak_rss_mib: float


def usage() -> Usage:
    return Usage(time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def gather_usage(group: Group | None) -> list[Usage]:
    """Rank 0's usage, then every other rank's (one entry when there are no others)."""
    if group is None:
        return [usage()]
    group.command(Command.USAGE)
    return list(group.gather(usage()) or [])


def serve(trainer: Trainer) -> None:
    """Ranks > 0: do what rank 0 commands until it says stop."""
    group = trainer.group
    assert group is not None
    while True:
        cmd = group.command()
        if cmd is Command.ITERATE:
            # raised in every rank at once (Group.all_true); rank 0 reports it and stops us
            with contextlib.suppress(NonFiniteLossError):
                trainer.train_iteration()
        elif cmd is Command.SHARD:
            group.gather(trainer.shard_state())
        elif cmd is Command.USAGE:
            group.gather(usage())
        else:
            return


@dataclass
class _Job:
    """What a spawned rank needs (pickled to it by multiprocessing)."""

    world: int
    store: str  # the rendezvous file
    config: dict[str, Any]
    run_dir: Path | None
    resume: Path | None
    warm_start: bool
    env_factory: EnvFactory


def _worker(rank: int, job: _Job, errors: Any) -> None:
    for sig in (signal.SIGINT, signal.SIGTERM):  # rank 0 stops us (see the module doc)
        signal.signal(sig, signal.SIG_IGN)
    group: Group | None = None
    code = 0
    try:
        group = Group.join(rank, job.world, job.store)
        cfg = Config()
        apply_dict(cfg, job.config)
        trainer = Trainer(cfg, job.env_factory, job.run_dir, job.warm_start, group)
        if job.resume is not None:
            trainer.load_checkpoint(job.resume)
        serve(trainer)
    except BaseException as e:  # any failure is reported to rank 0, then this process ends
        text = " ".join(str(e).split()) or type(e).__name__
        errors.put(f"data-parallel rank {rank} failed: {type(e).__name__}: {text}")
        code = 1
    finally:
        if group is not None:
            group.close()
    end_rank(code)


@contextmanager
def learner_ranks(cfg: Config, run_dir: Path | None, resume: Path | None = None,
                  warm_start: bool = True, env_factory: EnvFactory = default_env_factory
                  ) -> Iterator[Group | None]:
    """Rank 0's group with ranks 1..K-1 running beside it (None and no process when K = 1).
    On leaving: the others are told to stop and joined; if one failed, RankFailedError."""
    world = cfg.train.learner_processes
    if world == 1:
        yield None
        return
    tmp = tempfile.mkdtemp(prefix="sdhn-ranks-")
    ctx = mp.get_context("spawn")  # no forked copy of this process's threads or torch state
    errors = ctx.SimpleQueue()
    job = _Job(world, f"{tmp}/store", cfg.to_dict(), run_dir, resume, warm_start, env_factory)
    procs = [ctx.Process(target=_worker, args=(r, job, errors), name=f"sdhn-learner-{r}",
                         daemon=True) for r in range(1, world)]
    for p in procs:
        p.start()
    group: Group | None = None
    stopped = False
    try:
        group = Group.join(0, world, f"{tmp}/store")
        yield group
        group.command(Command.STOP)
        stopped = True
    except RuntimeError as e:  # a collective failed: name the rank that broke it
        failure = _failure(procs, errors)
        if failure is None:
            raise
        raise RankFailedError(failure) from e
    finally:
        for p in procs:
            p.join(timeout=30.0 if stopped else 0.0)
            if p.is_alive():  # rank 0 failed: the others wait on a collective that never ends
                p.terminate()
                p.join()
        if group is not None:
            group.close()
        shutil.rmtree(tmp, ignore_errors=True)


def _failure(procs: list[Any], errors: Any, wait_s: float = 10.0) -> str | None:
    """The first failed rank's error line, or its exit code (killed, say); None if none did."""
    deadline = time.monotonic() + wait_s
    for rank, p in enumerate(procs, start=1):
        p.join(timeout=max(0.0, deadline - time.monotonic()))
        if p.exitcode not in (None, 0):
            return (errors.get() if not errors.empty()
                    else f"data-parallel rank {rank} ended with exit code {p.exitcode}")
    return None
