#!/usr/bin/env python3
"""Long step-for-step comparison of the batched RWARE with the real ``rware`` package.

    nice -n 10 .venv/bin/python scripts/check_rware_equality.py [--steps 1100] [--envs 3]

The CI tests (``test/envs/test_rware_batched.py``) compare short rollouts; this runs the same
comparison (its ``rollout``: observations, rewards, dones, episodes, robot cells and directions,
carried shelves, shelf cells, request queue after every step) over several episodes on every
task layout, with random (FORWARD 40 %) and centralised scripted actions. Prints one line per
case with the deliveries seen and the ties handed to networkx; exits 1 at the first difference.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
import warnings
from pathlib import Path

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
    path = Path(__file__).resolve().parents[1] / "test" / "envs" / "test_rware_batched.py"
    spec = importlib.util.spec_from_file_location("rware_equality", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    t0 = time.perf_counter()
    for n, size in CASES:
        for scripted in (True, False):
            kind = "scripted" if scripted else "random"
            try:
                bat = mod.rollout(n, size, args.steps, seed=args.seed + n, num_envs=args.envs,
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
