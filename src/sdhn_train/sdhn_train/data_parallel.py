"""The collectives of data-parallel ranks (``train.learner_processes`` = K > 1).

K processes each collect rollouts on their B/K environments and run the same PPO update on
their share of every minibatch. Before each optimiser step the gradients are averaged over the K
processes (gloo all-reduce on localhost), so every replica clips and steps the same gradient and
the networks stay identical. With equal shares the mean of the per-process mean losses is the
whole minibatch's mean loss, so the update is the K = 1 update up to float summation order; the
one statistic that is not a mean of per-row terms, the advantage normalisation's mean and std,
is computed over the whole minibatch (``mean_std``).

Rank 0 drives the others with commands (``command``): iterate, send your checkpoint shard, send
your CPU time, stop. Processes are started and stopped by ``sdhn_train.ranks``.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from datetime import timedelta
from enum import IntEnum
from typing import Any, NoReturn

import torch
import torch.distributed as dist
from torch import Tensor, nn

# A peer that dies closes its sockets and the others' collectives fail at once; this timeout is
# only for a peer that hangs alive. Rank 0's evaluation (minutes on maif-20) must fit in it.
TIMEOUT = timedelta(minutes=30)


class RankFailedError(RuntimeError):
    """A data-parallel rank other than this one failed (its error line, or its exit code)."""


class Command(IntEnum):
    STOP = 0
    ITERATE = 1  # one rollout + update (Trainer.train_iteration)
    SHARD = 2  # gather each rank's environment / collector state into rank 0's checkpoint
    USAGE = 3  # gather each rank's CPU seconds and peak RSS (bench_train)


def end_rank(code: int) -> NoReturn:
    """End a spawned data-parallel rank (>= 1) once its group is closed, without the
    interpreter's teardown: there gloo's C++ threads are destroyed with the static objects and,
    now and then, abort the process ('terminate called without an active exception', exit -6;
    seen once in CI in the K = 2 exactness test) after its work had finished."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


class Group:
    """This process's place among the K data-parallel ranks (rank 0 evaluates, logs, writes)."""

    def __init__(self, rank: int, world: int) -> None:
        self.rank, self.world = rank, world

    @classmethod
    def join(cls, rank: int, world: int, store_file: str) -> Group:
        """Join the gloo group that rendezvouses through ``store_file`` (blocks until all K
        processes have joined)."""
        os.environ.setdefault("GLOO_SOCKET_IFNAME", "lo")  # localhost only
        dist.init_process_group("gloo", init_method=f"file://{store_file}", rank=rank,
                                world_size=world, timeout=TIMEOUT)
        return cls(rank, world)

    def close(self) -> None:
        if dist.is_initialized():
            dist.destroy_process_group()

    # -- the update ------------------------------------------------------------------------

    def average_grads(self, params: Iterable[nn.Parameter]) -> None:
        """Replace every gradient by its mean over the K processes (one all-reduce of one flat
        buffer; a parameter without a gradient counts as zero)."""
        ps = list(params)
        flat = torch.cat([p.grad.reshape(-1) if p.grad is not None
                          else torch.zeros(p.numel(), dtype=p.dtype) for p in ps])
        dist.all_reduce(flat)
        flat /= self.world
        offset = 0
        for p in ps:
            n = p.numel()
            p.grad = flat[offset:offset + n].view_as(p).clone()
            offset += n

    def mean_std(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and (unbiased) std of the union of every process's ``x``: what ``x.mean()``
        and ``x.std()`` give on the whole minibatch (two passes, as torch does)."""
        s = torch.stack([x.sum(), torch.tensor(float(x.numel()), dtype=x.dtype)])
        dist.all_reduce(s)
        mean = s[0] / s[1]
        sq = ((x - mean) ** 2).sum().reshape(1)
        dist.all_reduce(sq)
        return mean, (sq[0] / (s[1] - 1)).sqrt()

    def all_true(self, flag: bool) -> bool:
        """True when ``flag`` is true in every process (so all raise together, none hangs)."""
        t = torch.tensor([0.0 if flag else 1.0])
        dist.all_reduce(t)
        return bool(t.item() == 0.0)

    def average_metrics(self, metrics: dict[str, float]) -> dict[str, float]:
        """Each logged scalar averaged over the processes (exact for means over equal shares)."""
        keys = sorted(metrics)
        t = torch.tensor([metrics[k] for k in keys], dtype=torch.float64)
        dist.all_reduce(t)
        return {k: float(v) / self.world for k, v in zip(keys, t.tolist(), strict=True)}

    def broadcast_modules(self, modules: Iterable[nn.Module]) -> None:
        """Every process takes rank 0's parameters and buffers (identical replicas at start)."""
        with torch.no_grad():
            for m in modules:
                for t in [*m.parameters(), *m.buffers()]:
                    dist.broadcast(t.data, src=0)

    # -- rank 0 drives the others ----------------------------------------------------------

    def command(self, cmd: Command | None = None) -> Command:
        """Rank 0 sends ``cmd``; the others receive and return it."""
        t = torch.tensor([int(cmd) if cmd is not None else -1], dtype=torch.int64)
        dist.broadcast(t, src=0)
        return Command(int(t.item()))

    def gather(self, obj: Any) -> list[Any] | None:
        """Rank 0 receives every rank's ``obj`` (in rank order, its own first); others None."""
        out: list[Any] | None = [None] * self.world if self.rank == 0 else None
        dist.gather_object(obj, out, dst=0)
        return out
