"""Judge the training-under-conditions pilot (configs/suites/maif-20-conditions-pilot.yaml):
the fine-tuned actors of each arm and the policy they started from, in that policy's card mode,
under the goals' conditions of issue 53 (logic in sdhn_experiments.conditions_pilot).

    nice -n 10 .venv/bin/python scripts/conditions_pilot_eval.py runs/dr-pilot \\
        --mark 81920 --instances 50 --out docs/results/conditions/training-pilot-step81920.json

Policies: ``--baseline`` (a model directory: its actor and card mode) and, for every run
directory ``<task>__<arm>__s<seed>`` of the log directory, its actor at ``--mark``
(``actors/step_<mark>.safetensors``; without --mark the final ``actor.safetensors``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
from pathlib import Path
from typing import Any

from sdhn_experiments.condition_eval import (
    DEFAULT_SET,
    ConditionResult,
    card_mode,
    records_json,
)
from sdhn_experiments.conditions_pilot import PLAN, compare_arms, evaluate_policies, markdown
from sdhn_experiments.heldout_eval import (
    Policy,
    print_table,
    set_checksum,
    set_instances,
    write_json,
)
from sdhn_policy.actor_runtime import ActorRuntime

RECORD_COLUMNS = ("instance", "map", "success", "makespan", "team_success", "failed", "length")
RUN = re.compile(r"^(?P<task>[a-z0-9-]+)__(?P<arm>[a-z0-9_]+)__s(?P<seed>\d+)$")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("logdir", type=Path, help="the suite's log directory")
    p.add_argument("--baseline", type=Path, default=Path("models/maif-20-sdhn"))
    p.add_argument("--mark", type=int, help="judge every run's actor at this many team steps")
    p.add_argument("--instances", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--markdown", type=Path)
    p.add_argument("--cache", type=Path, help="directory of per-policy results: a policy whose "
                   "actor, instances and seed match its file there is not played again")
    p.add_argument("--only", help="evaluate (and cache) only this policy, e.g. baseline")
    args = p.parse_args(argv)
    card = json.loads((args.baseline / "card.json").read_text())
    task, mode = card["env"], card_mode(args.baseline)
    files = {"baseline": args.baseline / "actor.safetensors"}
    arms: dict[str, list[str]] = {}
    for d in sorted(args.logdir.iterdir()):
        m = RUN.match(d.name)
        if m is None or m["task"] != task:
            continue
        actor = (d / "actors" / f"step_{args.mark}.safetensors" if args.mark
                 else d / "actor.safetensors")
        if not actor.is_file() and args.only in (None, d.name):
            print(f"conditions_pilot_eval: {actor} missing; every run must have it",
                  file=sys.stderr)
            return 2
        files[d.name] = actor
        arms.setdefault(m["arm"], []).append(d.name)
    if not arms:
        print(f"conditions_pilot_eval: no {task} runs in {args.logdir}", file=sys.stderr)
        return 2
    arms = {k: arms[k] for k in sorted(arms, key=lambda a: (a != "control", a))}
    if args.only:
        files = {args.only: files[args.only]}
    rows: dict[str, dict[str, list[ConditionResult]]] = {}
    for name, path in files.items():
        key = {"actor_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
               "instances": args.instances, "seed": args.seed, "mode": mode.label(),
               "plan": [lab for lab, _, _ in PLAN]}
        cached = args.cache / f"{name}.json" if args.cache else None
        if cached is not None and cached.is_file():
            data = json.loads(cached.read_text())
            if data["key"] == key:
                rows[name] = {lab: [ConditionResult(**r) for r in recs]
                              for lab, recs in data["records"].items()}
                continue
        policies: dict[str, Policy] = {name: ActorRuntime.from_file(path)}
        rows.update(evaluate_policies(policies, task, PLAN, mode, instances=args.instances,
                                      seed=args.seed, log=lambda s: print(s, flush=True)))
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            write_json(cached, {"key": key, "records": {
                lab: records_json(r) for lab, r in rows[name].items()}})
    if args.only:
        return 0
    table = compare_arms(rows, arms, "baseline")
    inst = set_instances(task, DEFAULT_SET)
    out: dict[str, Any] = {
        "task": task, "baseline": str(args.baseline), "mode": mode.label(),
        "set": DEFAULT_SET, "set_checksum": set_checksum(inst), "instances": args.instances,
        "condition_seed": args.seed, "mark": args.mark, "arms": arms,
        "plan": [{"label": lab, "conditions": c.to_dict(), "dead_reckoning": dr}
                 for lab, c, dr in PLAN],
        "table": table,
        "records_columns": list(RECORD_COLUMNS),  # one row per instance, these columns
        "records": {name: {lab: [[rec[c] for c in RECORD_COLUMNS] for rec in records_json(r)]
                           for lab, r in per.items()} for name, per in rows.items()},
    }
    write_json(args.out, out)
    print_table(markdown(table, list(arms), "baseline"), args.markdown)
    return 0

