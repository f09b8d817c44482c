"""Throughput of the environments (prints figures; not a test).

MAIF: agent-steps/s of the batched core at (B=1, N=10), (B=64, N=10), (B=64, N=20), next to
``LoopMaif`` below, a straightforward per-robot Python-loop implementation of the same rules
(``test/envs`` checks that it agrees with the batched core step for step).
RWARE: adapter vs raw ``gym.make("rware-...")`` stepping, same actions; overhead in %.

    .venv/bin/python scripts/bench_envs.py [--quick]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import numpy as np

from sdhn_sim.envs import make_env
from sdhn_sim.envs.maif import MaifEnv, MaifRewards, MaifWorld

DELTAS = [(0, 0), (0, -1), (0, 1), (-1, 0), (1, 0)]  # stay, up, down, left, right as (dx, dy)


class LoopMaif:
    """One MAIF environment with plain lists and per-robot loops (reference and baseline)."""

    def __init__(self, world: MaifWorld, max_steps: int = 500, rewards: MaifRewards | None = None):
        self.obstacles = world.obstacles.tolist()
        self.size = len(self.obstacles)
        self.pos = [tuple(p) for p in world.positions.tolist()]
        self.goals = [tuple(g) for g in world.goals.tolist()]
        self.n = len(self.pos)
        self.rw = rewards or MaifRewards()
        self.max_steps = max_steps
        self.t = 0
        self.dist = [
            abs(p[0] - g[0]) + abs(p[1] - g[1]) for p, g in zip(self.pos, self.goals, strict=True)
        ]
        gmx = sum(g[0] for g in self.goals) / self.n
        gmy = sum(g[1] for g in self.goals) / self.n
        self.goal_off = [(g[0] - gmx, g[1] - gmy) for g in self.goals]

    def free(self, x: int, y: int) -> bool:
        return 0 <= x < self.size and 0 <= y < self.size and not self.obstacles[y][x]

    def resolve(self, actions: list[int]) -> tuple[list[tuple[int, int]], list[bool]]:
        cur, tgt, coll = list(self.pos), [], [False] * self.n
        for i in range(self.n):
            dx, dy = DELTAS[actions[i]]
            x, y = cur[i][0] + dx, cur[i][1] + dy
            if actions[i] != 0 and not self.free(x, y):
                tgt.append(cur[i])
                coll[i] = True
            else:
                tgt.append((x, y))
        while True:
            losers: set[int] = set()
            claims: dict[tuple[int, int], list[int]] = {}
            for i in range(self.n):
                claims.setdefault(tgt[i], []).append(i)
            for robots in claims.values():
                if len(robots) > 1:
                    stayers = [i for i in robots if tgt[i] == cur[i]]
                    winner = stayers[0] if stayers else min(robots)
                    losers.update(i for i in robots if i != winner)
            occupant = {cur[i]: i for i in range(self.n)}
            for i in range(self.n):
                j = occupant.get(tgt[i])
                if tgt[i] != cur[i] and j is not None and j != i and tgt[j] == cur[i]:
                    losers.add(i)
            if not losers:
                return tgt, coll
            for i in losers:
                tgt[i] = cur[i]
                coll[i] = True

    def step(self, actions: list[int]) -> tuple[list[list[float]], float, list[float], list[bool]]:
        """Returns (obs [N][57], team reward, robot rewards, collided) of this step."""
        self.pos, coll = self.resolve(actions)
        n, rw = self.n, self.rw
        mx = sum(p[0] for p in self.pos) / n
        my = sum(p[1] for p in self.pos) / n
        dist = [
            abs(p[0] - g[0]) + abs(p[1] - g[1]) for p, g in zip(self.pos, self.goals, strict=True)
        ]
        all_on = all(d == 0 for d in dist)
        rewards = []
        for i in range(n):
            if actions[i] != 0:
                r = rw.move
            else:
                r = rw.stay_on_goal if dist[i] == 0 else rw.stay_off_goal
            if coll[i]:
                r += rw.collision
            if dist[i] < self.dist[i]:
                r += rw.progress
            elif dist[i] > self.dist[i]:
                r += rw.progress_away
            ox, oy = self.pos[i][0] - mx, self.pos[i][1] - my
            d = abs(ox - self.goal_off[i][0]) + abs(oy - self.goal_off[i][1])
            r += (math.exp(-d) - 0.5) * rw.formation_scale
            if all_on:
                r += rw.completion
            rewards.append(r)
        self.dist = dist
        self.t += 1
        return self.observe(), sum(rewards), rewards, coll

    def observe(self) -> list[list[float]]:
        n, k = self.n, 1.0 / (self.size - 1)
        mx = sum(p[0] for p in self.pos) / n
        my = sum(p[1] for p in self.pos) / n
        gmx = sum(g[0] for g in self.goals) / n
        gmy = sum(g[1] for g in self.goals) / n
        robots = set(self.pos)
        out = []
        for i in range(n):
            x, y = self.pos[i]
            gx, gy = self.goals[i]
            o = [x * k, y * k, mx * k, my * k, gx * k, gy * k, gmx * k, gmy * k]
            for wy in range(y - 3, y + 4):
                for wx in range(x - 3, x + 4):
                    if not self.free(wx, wy):
                        o.append(1.0)
                    elif (wx, wy) in robots and (wx, wy) != (x, y):
                        o.append(2.0)
                    else:
                        o.append(0.0)
            out.append(o)
        return out


def best_rate(fn: Callable[[], int], repeats: int) -> float:
    """Best items/s over ``repeats`` runs of ``fn`` (which returns the number of items done)."""
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        items = fn()
        best = max(best, items / (time.perf_counter() - t0))
    return best


def bench_maif(name: str, b: int, steps: int, repeats: int) -> tuple[float, float]:
    env = make_env(name, num_envs=b, seed=0)
    assert isinstance(env, MaifEnv)
    env.reset()
    n = env.num_robots
    acts = np.random.default_rng(0).integers(0, 5, size=(steps, b, n))

    def fast() -> int:
        for k in range(steps):
            env.step(acts[k])
        return steps * b * n

    loops = [LoopMaif(env.world(e)) for e in range(b)]
    loop_acts: list[list[list[int]]] = acts.tolist()
    loop_steps = max(1, steps // 4)

    def slow() -> int:
        for k in range(loop_steps):
            for e in range(b):
                loops[e].step(loop_acts[k][e])
        return loop_steps * b * n

    fast()  # warm-up
    return best_rate(fast, repeats), best_rate(slow, max(1, repeats - 1))


def bench_rware(name: str, b: int, steps: int, repeats: int) -> tuple[float, float]:
    from sdhn_sim.envs.rware_env import RwareEnv, make_rware_gym

    env = make_env(name, num_envs=b, seed=0, backend="rware")
    assert isinstance(env, RwareEnv)
    env.reset()
    raws = [make_rware_gym(env.env_id, env.max_steps) for _ in range(b)]
    for e, gym_env in enumerate(raws):
        gym_env.reset(seed=e)
    acts = np.random.default_rng(0).integers(0, 5, size=(steps, b, env.num_robots))
    acts_list: list[list[list[int]]] = acts.tolist()

    def adapter() -> int:
        for k in range(steps):
            env.step(acts[k])
        return steps * b

    def raw() -> int:
        for k in range(steps):
            for e, r in enumerate(raws):
                _, _, te, tr, _ = r.step(tuple(acts_list[k][e]))
                if te or tr:
                    r.reset()
        return steps * b

    adapter()
    raw()
    rates_a, rates_r = [], []
    for _ in range(repeats):  # interleave so both see the same machine load
        rates_a.append(best_rate(adapter, 1))
        rates_r.append(best_rate(raw, 1))
    return max(rates_a), max(rates_r)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps (a smoke run)")
    args = ap.parse_args(argv)
    steps, repeats = (50, 2) if args.quick else (400, 5)
    print("MAIF agent-steps/s (batched NumPy core vs per-robot Python loops)")
    print(f"{'config':<10}{'B':>4}{'N':>4}{'batched':>14}{'loop':>12}{'ratio':>8}")
    for name, b in (("maif-10", 1), ("maif-10", 64), ("maif-20", 64)):
        s = steps * 4 if b == 1 else steps
        fast, slow = bench_maif(name, b, s, repeats)
        n = 10 if name == "maif-10" else 20
        print(f"{name:<10}{b:>4}{n:>4}{fast:>14,.0f}{slow:>12,.0f}{fast / slow:>7.1f}x")
    print("\nRWARE env-steps/s (adapter vs raw gym.make, same actions)")
    print(f"{'task':<9}{'B':>4}{'adapter':>10}{'raw':>10}{'overhead':>10}")
    for name, b in (("rware-3", 1), ("rware-9", 1), ("rware-9", 8)):
        a, r = bench_rware(name, b, max(20, (steps * 3 // 2) // b), repeats + 2)
        print(f"{name:<9}{b:>4}{a:>10,.0f}{r:>10,.0f}{(r / a - 1) * 100:>9.1f}%")


if __name__ == "__main__":
    main()
