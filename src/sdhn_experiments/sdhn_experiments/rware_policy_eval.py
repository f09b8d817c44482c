"""An exported RWARE actor, greedy, on any RWARE task: deliveries per episode (zero-shot on a
team size it was not trained on, its one-hot robot ids moved to the new team as warm start moves
them: ``sdhn_policy.team_size.for_team``).

    .venv/bin/python scripts/eval_rware_policy.py models/rware-3-mappo rware-3 rware-6 rware-9

One 500-step episode from each seed ``--seed .. --seed+episodes-1`` (default: the model cards'
100 episodes from 1,000,000, the episodes the scripted baselines of
``scripts/eval_rware_baselines.py --seed 1000000 --episodes 100`` play); the NumPy runtime the
actor processes run. Prints mean ± population std; ``--json`` one object per line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_eval import RWARE_EVAL_SEED, rware_deliveries
from sdhn_policy.team_size import for_team
from sdhn_policy.weights import WeightsError, decode_weights, load_actor_file
from sdhn_sim.envs import make_env
from sdhn_sim.envs.registry import RWARE_TASKS


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("actor", type=Path, help="a model directory (its actor.safetensors) or an "
                                            "actor file")
    p.add_argument("tasks", nargs="+", help=f"of {sorted(RWARE_TASKS)}")
    p.add_argument("--episodes", type=int, default=100, help="one episode per seed")
    p.add_argument("--seed", type=int, default=RWARE_EVAL_SEED, help="first seed")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    unknown = [t for t in args.tasks if t not in RWARE_TASKS]
    if unknown or args.episodes < 1:
        p.error(f"tasks {unknown} not RWARE tasks; allowed: {sorted(RWARE_TASKS)}" if unknown
                else f"--episodes {args.episodes}: allowed: an integer >= 1")
    path = args.actor / "actor.safetensors" if args.actor.is_dir() else args.actor
    if not path.is_file():
        print(f"eval_rware_policy: {path}: no such actor file", file=sys.stderr)
        return 2
    try:
        spec, tensors = decode_weights(load_actor_file(path))
    except (OSError, WeightsError) as e:
        print(f"eval_rware_policy: {path}: {e}", file=sys.stderr)
        return 2
    for task in args.tasks:
        n = RWARE_TASKS[task]
        obs_size = make_env(task, num_envs=1, seed=args.seed).obs_size
        if spec.obs_size != obs_size:
            print(f"eval_rware_policy: {path}: an actor for {spec.obs_size}-float observations; "
                  f"{task}'s are {obs_size} (a MAIF actor?)", file=sys.stderr)
            return 2
        rt = ActorRuntime(*for_team(spec, tensors, n))
        res = rware_deliveries(rt, task, args.episodes, args.seed)
        trained = "its own team" if n == spec.num_robots else f"zero-shot, trained with " \
                                                              f"{spec.num_robots} robots"
        if args.json:
            print(json.dumps({"actor": str(path), "task": task, "robots": n,
                              "trained_robots": spec.num_robots, **res}), flush=True)
        else:
            print(f"{task:15s} deliveries {res['deliveries_mean']:6.2f} ± "
                  f"{res['deliveries_std']:5.2f}  ({trained}; seeds {res['seeds']})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
