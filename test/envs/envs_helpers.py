"""Shared helpers of the env tests: hand-built MAIF scenarios, greedy play through the
simulator's lock-step core."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_instances import MaifConfig, MaifInstances
from sdhn_sim.episode import EpisodeResult
from sdhn_sim.lockstep import LockstepSim

TINY_ACTOR = Path(__file__).resolve().parents[2] / "models/maif-tiny-sdhn/actor.safetensors"
# an episode's outcome: completed, makespan, the survivors' completed and makespan, failed robots
Row = tuple[bool, int | None, bool, int | None, int]


def scenario(
    starts: list[tuple[int, int]],
    goals: list[tuple[int, int]],
    obstacles: list[tuple[int, int]] = (),  # type: ignore[assignment]
    size: int = 8,
    **kw: object,
) -> MaifEnv:
    """A one-instance MAIF env on a ``size`` grid; cells are (x, y). Reset already done."""
    n = len(starts)
    grid = np.zeros((1, size, size), dtype=bool)
    for x, y in obstacles:
        grid[0, y, x] = True
    fs = max(2, int(np.ceil(np.sqrt(n))))
    cfg = MaifConfig(name="test", num_robots=n, size=size, fs=fs, num_maps=1, num_formations=1)
    inst = MaifInstances(
        cfg,
        grid,
        np.array(starts, dtype=np.int64).reshape(1, 1, n, 2),
        np.array(goals, dtype=np.int64).reshape(1, 1, n, 2),
    )
    env = MaifEnv(inst, num_envs=1, seed=0, **kw)  # type: ignore[arg-type]
    env.reset()
    return env


def greedy_lockstep(sim: LockstepSim, episodes: int
                    ) -> tuple[list[Row], list[dict], list[EpisodeResult]]:
    """``episodes`` episodes of the tiny MAIF actor answering greedily for each of the 4 robots
    the simulator still sends observations to (a cut robot says nothing): each episode's outcome
    row and result, and the simulator's events (faults cut, robots declared failed)."""
    rt = ActorRuntime.from_file(TINY_ACTOR)
    rng = np.random.default_rng(0)
    rows: list[Row] = []
    events: list[dict] = []
    results: list[EpisodeResult] = []
    for _ in range(episodes):
        frame = sim.reset()
        h = rt.initial_state(4)
        result = None
        while result is None:
            a, _, h = rt.act(frame.obs, h, greedy=True, rng=rng)
            for i in range(4):
                if not sim.cut[i]:
                    assert sim.submit(i, frame.episode, frame.step, int(a[i]), 1) is None
            frame, result = sim.advance()
            events += sim.take_events()
        o = sim.last_outcome
        assert o is not None
        rows.append((o.completed, o.makespan, o.survivors_completed, o.survivors_makespan,
                     o.failed))
        results.append(result)
    return rows, events, results
