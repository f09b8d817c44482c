"""RWARE baselines: deliveries and return per episode of random and scripted policies.

    .venv/bin/python scripts/eval_rware_baselines.py [rware-3 rware-6 rware-9] [--episodes 10]
        [--policies random,scripted,decentralised]

One episode (500 steps, rware's limit) from each of the seeds ``--seed .. --seed+episodes-1``;
prints mean ± std (population std over those episodes) of the requested shelves delivered and of
the return under rware's own reward (individual: +1 to the robot on the goal per delivery, so the
two agree). ``scripted`` is the centralised fetch-deliver-return heuristic of
``sdhn_sim.envs.rware_scripted`` (it reads rware's warehouses, so it runs on the real rware
backend); ``decentralised`` is ``sdhn_sim.envs.rware_decentralised``, each robot acting on its own
observation (batched backend); ``random`` draws the 5 actions uniformly (batched backend; the two
backends are equal step for step).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

from sdhn_sim.envs.rware_baselines import POLICIES, evaluate_baseline


def evaluate(name: str, policy: str, *, episodes: int, seed: int) -> dict[str, object]:
    """``evaluate_baseline`` with its wall time."""
    t0 = time.perf_counter()
    r = evaluate_baseline(name, policy, episodes=episodes, seed=seed)
    r.pop("deliveries")
    return {**r, "wall_s": round(time.perf_counter() - t0, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("envs", nargs="*", default=["rware-3"], help="RWARE tasks (default rware-3)")
    p.add_argument("--episodes", type=int, default=10, help="one episode per seed")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--policies", default="random,scripted,decentralised",
                   help=f"comma-separated, of {', '.join(POLICIES)}")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    # rware 2.0.0 returns its rewards as a list, which gymnasium's checker warns about
    warnings.filterwarnings("ignore", message=".*reward returned by")
    policies = args.policies.split(",")
    bad = [x for x in policies if x not in POLICIES]
    if bad:
        print(f"--policies: {bad[0]!r} is not a policy; allowed: {', '.join(POLICIES)}",
              file=sys.stderr)
        return 2
    for name in args.envs:
        for policy in policies:
            r = evaluate(name, policy, episodes=args.episodes, seed=args.seed)
            if args.json:
                print(json.dumps(r), flush=True)
                continue
            print(f"{name:8s} {policy:8s} deliveries {r['deliveries_mean']:5.1f} ± "
                  f"{r['deliveries_std']:4.1f}  return {r['return_mean']:5.1f} ± "
                  f"{r['return_std']:4.1f} ({r['reward']})  seeds {r['seeds']}  "
                  f"[{r['wall_s']} s]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
