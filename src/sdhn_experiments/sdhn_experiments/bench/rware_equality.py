"""Long step-for-step comparison of the batched RWARE with the real ``rware`` package.

    nice -n 10 .venv/bin/python scripts/check_rware_equality.py [--steps 1100] [--envs 3]

The CI tests (``test/envs/test_rware_batched.py``) compare short rollouts with ``rollout`` below;
``main`` runs the same comparison (observations, rewards, dones, episodes, robot cells and
directions, carried shelves, shelf cells, request queue after every step) over several episodes
on every task layout, with random (FORWARD 40 %) and centralised scripted actions. Prints one
line per case with the deliveries seen and the ties handed to networkx; exits 1 at the first
difference.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from typing import Any

import numpy as np

from sdhn_sim.envs.rware_batched import RwareBatchedEnv
from sdhn_sim.envs.rware_env import RwareEnv
from sdhn_sim.envs.rware_scripted import ScriptedPolicy


def real_state(wh: Any) -> dict[str, list[Any]]:
    """What a warehouse holds, read from rware's objects (0-based shelf indices)."""
    return {
        "positions": [(a.x, a.y) for a in wh.agents],
        "directions": [a.dir.value for a in wh.agents],
        "carried": [-1 if a.carrying_shelf is None else a.carrying_shelf.id - 1
                    for a in wh.agents],
        "queue": [s.id - 1 for s in wh.request_queue],
        "shelves": [(s.x, s.y) for s in wh.shelfs],
    }


def batched_state(env: RwareBatchedEnv, b: int) -> dict[str, list[Any]]:
    return {
        "positions": [tuple(p) for p in env.positions[b].tolist()],
        "directions": env.dir[b].tolist(),
        "carried": env.carry[b].tolist(),
        "queue": env.request_queue[b].tolist(),
        "shelves": [tuple(p) for p in env.shelf_positions[b].tolist()],
    }


def assert_same_state(real: RwareEnv, bat: RwareBatchedEnv, ctx: str) -> None:
    for b, wh in enumerate(real.warehouses):
        want, got = real_state(wh), batched_state(bat, b)
        for key in want:
            assert got[key] == want[key], f"{ctx} env {b} {key}: rware {want[key]}, got {got[key]}"


def rollout(n: int, size: str, steps: int, *, seed: int, num_envs: int = 2,
            difficulty: str = "normal", max_steps: int = 500, forward: float = 0.2,
            scripted: bool = False) -> RwareBatchedEnv:
    """Step both envs with the same actions and compare everything after each step. Random
    actions draw FORWARD with probability ``forward`` (crowds make conflicts), scripted ones
    come from the centralised policy reading the real warehouses."""
    kw: dict[str, Any] = {"size": size, "difficulty": difficulty, "max_steps": max_steps}
    real = RwareEnv(n, num_envs=num_envs, seed=seed, **kw)
    bat = RwareBatchedEnv(n, num_envs=num_envs, seed=seed, **kw)
    assert bat.obs_size == real.obs_size and bat.state_size == real.state_size
    o_r, s_r = real.reset()
    o_b, s_b = bat.reset()
    np.testing.assert_array_equal(o_b, o_r, err_msg="reset obs")
    np.testing.assert_array_equal(s_b, s_r, err_msg="reset state")
    assert_same_state(real, bat, "reset")
    rng = np.random.default_rng(seed)
    policy = ScriptedPolicy(seed=seed)
    p = np.array([(1 - forward) / 4, forward, (1 - forward) / 4, (1 - forward) / 4,
                  (1 - forward) / 4])
    for t in range(steps):
        if scripted:
            acts = policy.act(real)
        else:
            acts = rng.choice(5, size=(num_envs, n), p=p).astype(np.int64)
        rr = real.step(acts)
        rb = bat.step(acts)
        ctx = f"step {t}"
        np.testing.assert_array_equal(rb.final_obs, rr.final_obs, err_msg=f"{ctx} final obs")
        np.testing.assert_array_equal(rb.obs, rr.obs, err_msg=f"{ctx} obs")
        np.testing.assert_array_equal(rb.state, rr.state, err_msg=f"{ctx} state")
        np.testing.assert_array_equal(bat.robot_rewards, real.robot_rewards, err_msg=ctx)
        np.testing.assert_array_equal(rb.reward, rr.reward, err_msg=f"{ctx} reward")
        np.testing.assert_array_equal(rb.terminated, rr.terminated, err_msg=ctx)
        np.testing.assert_array_equal(rb.truncated, rr.truncated, err_msg=ctx)
        assert rb.episodes == rr.episodes, ctx
        assert_same_state(real, bat, ctx)
    return bat


CASES = [(2, "tiny"), (4, "tiny"), (3, "small"), (6, "small"), (9, "small")]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=1100, help="steps per case (500 per episode)")
    p.add_argument("--envs", type=int, default=3, help="warehouses per case")
    p.add_argument("--seed", type=int, default=100)
    args = p.parse_args(argv)
    if args.steps < 1 or args.envs < 1:
        print("--steps and --envs must be >= 1", file=sys.stderr)
        return 2
    warnings.filterwarnings("ignore", message=".*reward returned by")
    t0 = time.perf_counter()
    for n, size in CASES:
        for scripted in (True, False):
            kind = "scripted" if scripted else "random"
            try:
                bat = rollout(n, size, args.steps, seed=args.seed + n, num_envs=args.envs,
                                  scripted=scripted, forward=0.4)
            except AssertionError as e:
                print(f"rware-{size}-{n}ag {kind}: DIFFERENT: {str(e).splitlines()[0]}")
                return 1
            print(f"rware-{size}-{n}ag {kind:8s} equal: {args.steps} steps x {args.envs} envs, "
                  f"{bat.ties_resolved_by_networkx} networkx ties "
                  f"[{time.perf_counter() - t0:.0f} s]", flush=True)
    print("all equal")
    return 0


if __name__ == "__main__":
    sys.exit(main())
