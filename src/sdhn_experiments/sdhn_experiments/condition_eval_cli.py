"""Shipped policies under deployment conditions: MAIF success (survivors' success under robot
failure), makespan and makespan over the ideal world, with 95 % intervals; RWARE deliveries per
episode [95 % interval over episodes] and the latency mechanism's counts; at several severities
of each condition (sdhn_sim.envs.conditions; logic in sdhn_experiments.condition_eval and
sdhn_experiments.rware_conditions).

    .venv/bin/python scripts/eval_conditions.py models/maif-10-sdhn --instances 100 \\
        --conditions latency lost_actions --out /tmp/cond.json --markdown /tmp/cond.md
    .venv/bin/python scripts/eval_conditions.py models/maif-10-sdhn --task maif-20 \\
        --conditions ideal                          # team-size transfer
    .venv/bin/python scripts/eval_conditions.py models/maif-10-sdhn --modes card \\
        --dead-reckon both --conditions latency     # the deployment rule against the cliff
    .venv/bin/python scripts/eval_conditions.py models/rware-3-mappo scripted:rware-3 \\
        --instances 20 --conditions latency --severities 1 2 --dead-reckon both   # RWARE

The best-case reference for a goal (``--planner``; with no model, ``--task`` names the task)::

    .venv/bin/python scripts/eval_conditions.py --planner --task maif-10 \
        --conditions lost_actions --severities 0.05 0.1 0.2 --instances 100
    .venv/bin/python scripts/eval_conditions.py --planner --task maif-10 \
        --conditions latency --severities 1 --dead-reckon both

plays the centralised planner (replanning from the true state; under latency from the state
the robots' observations saw, with ``--dead-reckon`` moved forward by its own moves) and, for
conditions on actions, the relaxed bound (each robot alone on its shortest path under the same
draws) on the same instances, seeds and condition draws, each against its own ideal run.

Each row plays instances 0..K-1 of the large held-out set (K = --instances; maps of 5
formations), the condition model seeded --seed; an RWARE model (or ``scripted:TASK``, the
decentralised scripted policy) plays K episodes from the robustness suite's seeds (1,000,000 on),
greedy. Modes: ``card`` (the card's deployment mode),
``greedy``; ``--dead-reckon on|off|both`` adds or compares dead reckoning.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_experiments.condition_eval import (
    DEFAULT_SET,
    PLANNER,
    PLANNER_MODE,
    RELAXED,
    RELAXED_MODE,
    ConditionResult,
    Mode,
    PlannerError,
    card_mode,
    evaluate_planner_under,
    evaluate_under,
    records_json,
    relaxed_bound_under,
    set_instances,
    summarise_under,
)
from sdhn_experiments.heldout_eval import print_table, set_checksum, write_json
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_sim.envs.conditions import Conditions, ConditionsError, conditions_from_dict
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS

# condition name -> (severities, the Conditions of one severity)
SWEEPS: dict[str, tuple[list[float], Any]] = {
    "latency": ([1, 2, 3, 4], lambda k: Conditions(latency=int(k))),
    "latency_random": ([1, 2, 3, 4],
                       lambda k: Conditions(latency=int(k), latency_random=True)),
    "lost_actions": ([0.05, 0.1, 0.2, 0.4], lambda p: Conditions(lost_actions=p)),
    "slow_half": ([0.75, 0.5, 0.25, 0.1],
                  lambda r: Conditions(slow_fraction=0.5, slow_rate=r)),
    "position_noise": ([0.05, 0.1, 0.2, 0.4], lambda p: Conditions(position_noise=p)),
    "cell_misread": ([0.02, 0.05, 0.1, 0.2], lambda p: Conditions(cell_misread=p)),
    "failures": ([1, 2, 3, 4], lambda k: Conditions(failures=int(k))),
}
SEVERITY_NAMES = {"latency": "steps", "latency_random": "max steps", "lost_actions": "p",
                  "slow_half": "rate of the slow half", "position_noise": "p",
                  "cell_misread": "p", "failures": "robots"}


def fmt_ci(m: float | None, ci: Any, digits: int = 2) -> str:
    if m is None:
        return "NC"
    return f"{m:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]" if ci else f"{m:.{digits}f}"


def markdown(rows: list[dict[str, Any]]) -> str:
    out = ["| policy | task | mode | condition | severity | instances | "
           "success [95 % CI, maps] | team success | makespan [95 % CI] | "
           "makespan / ideal [95 % CI, paired] |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s = r["summary"]
        out.append(
            f"| {r['policy']} | {r['task']} | {r['mode']} | {r['condition']} | "
            f"{r['severity']} | {s['instances']} | "
            f"{fmt_ci(s['success_rate'], s['success_ci95_maps'], 3)} | "
            f"{s['team_success_rate']:.3f} | "
            f"{fmt_ci(s['makespan_mean'], s['makespan_ci95'], 1)} | "
            f"{fmt_ci(s.get('makespan_over_ideal'), s.get('makespan_over_ideal_ci95'))} |")
    return "\n".join(out) + "\n"


def _card_env(model: Path) -> str | None:
    """The task a model directory's card names (None without a card)."""
    card = model / "card.json"
    return json.loads(card.read_text())["env"] if card.is_file() else None


def _rware_task(model: Path, task: str | None) -> str | None:
    """The RWARE task a model plays (``scripted:TASK``, or its card's env), None for MAIF."""
    from sdhn_sim.envs.registry import RWARE_TASKS

    if str(model).startswith("scripted:"):
        return str(model).split(":", 1)[1]
    env = task or _card_env(model)
    return env if env in RWARE_TASKS else None


def _rware_main(args: argparse.Namespace, models: list[Path],
                plan: list[tuple[str, str, Conditions]], reckon: list[bool], alone: bool) -> int:
    """RWARE rows: deliveries per episode under each condition, with and without the rule."""
    from sdhn_experiments.rware_conditions import markdown_rows, play_rware, policy_maker
    from sdhn_policy.deploy_eval import RWARE_EVAL_SEED
    from sdhn_sim.envs.registry import RWARE_TASKS

    if not alone:
        print("eval_conditions: RWARE and MAIF models in one call; allowed: one family",
              file=sys.stderr)
        return 2
    maif_only = {"position_noise", "cell_misread"}
    plan = [p for p in plan if p[0] not in maif_only]
    rows: list[dict[str, Any]] = []
    for model in models:
        task = _rware_task(model, args.task)
        if task not in RWARE_TASKS:
            print(f"eval_conditions: {model}: task {task!r}; allowed: {', '.join(RWARE_TASKS)}",
                  file=sys.stderr)
            return 2
        name, make = policy_maker(str(model))
        for dr in reckon:
            first = [] if dr and len(reckon) > 1 else [("ideal", "-", Conditions())]
            for cname, sev, cond in [*first, *plan]:
                t0 = time.process_time()
                res = play_rware(make, task, cond, episodes=args.instances, seed=RWARE_EVAL_SEED,
                                 dead_reckon=dr)
                s = res.summary()
                mode = "greedy" + (", dead reckoning" if dr else "")
                print(f"[cond] {name} on {task} ({mode}) {cname} {sev}: deliveries "
                      f"{s['deliveries_mean']:.2f} {s['deliveries_ci95']}, {s['rates']}, "
                      f"{time.process_time() - t0:.1f} CPU-s", flush=True)
                rows.append({"policy": name, "task": task, "mode": mode, "dead_reckon": dr,
                             "condition": cname, "severity": sev, "conditions": cond.to_dict(),
                             "episode_seeds": f"{RWARE_EVAL_SEED}.."
                                              f"{RWARE_EVAL_SEED + args.instances - 1}",
                             "summary": s})
                if args.out:
                    write_json(args.out, rows)
    print_table(markdown_rows(rows), args.markdown)
    return 0


def reference_rows(tasks: list[str], plan: list[tuple[str, str, Conditions]],
                   reckon: list[bool], args: argparse.Namespace) -> list[dict[str, Any]]:
    """The planner's and the relaxed bound's rows for ``plan`` on each task, each against its
    own ideal run (PlannerError: a condition they do not model)."""
    rows: list[dict[str, Any]] = []
    kw = {"instances": args.instances, "which": args.set, "seed": args.seed}
    for task in tasks:
        if task not in MAIF_CONFIGS:
            raise PlannerError(f"{task!r} is not a MAIF task")
        inst = set_instances(task, args.set)
        ideal_p = evaluate_planner_under(task, Conditions(), **kw)
        ideal_r = relaxed_bound_under(task, Conditions(), **kw)
        runs: list[tuple[str, str, str, Conditions, bool]] = [
            (PLANNER, "ideal", "-", Conditions(), False),
            (RELAXED, "ideal", "-", Conditions(), False)]
        for cname, sev, cond in plan:
            if cond.position_noise or cond.cell_misread or cond.failures:
                raise PlannerError(f"{cname} is not modelled (allowed: latency, "
                                   "latency_random, lost_actions, slow_half)")
            if cond.latency:  # a lone robot that knows its moves loses nothing to latency
                runs += [(PLANNER, cname, sev, cond, dr) for dr in reckon]
            else:
                runs += [(PLANNER, cname, sev, cond, False), (RELAXED, cname, sev, cond, False)]
        for who, cname, sev, cond, dr in runs:
            t0 = time.process_time()
            recs: list[ConditionResult]
            if cname == "ideal":
                recs = ideal_p if who == PLANNER else ideal_r
            elif who == PLANNER:
                recs = evaluate_planner_under(task, cond, dead_reckon=dr, **kw)
            else:
                recs = relaxed_bound_under(task, cond, **kw)
            s = summarise_under(recs, ideal_p if who == PLANNER else ideal_r,
                                inst.num_formations)
            mode = (PLANNER_MODE if who == PLANNER else RELAXED_MODE) + (
                ", dead reckoning" if dr else "")
            print(f"[cond] {who} on {task} ({mode}) {cname} {sev}: success "
                  f"{s['success_rate']:.3f}, makespan {s['makespan_mean']}, / ideal "
                  f"{s.get('makespan_over_ideal')}, {time.process_time() - t0:.0f} CPU-s",
                  flush=True)
            rows.append({"policy": who, "task": task, "set": args.set,
                         "set_checksum": set_checksum(inst), "mode": mode, "dead_reckon": dr,
                         "condition": cname, "severity": sev, "conditions": cond.to_dict(),
                         "seed": args.seed, "summary": s, "records": records_json(recs)})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("models", nargs="*", type=Path,
                   help="model directories (card.json, actor); RWARE also scripted:TASK")
    p.add_argument("--task", help="task to play (default: the card's; another = transfer)")
    p.add_argument("--conditions", nargs="+", default=list(SWEEPS),
                   help=f"conditions to sweep, of {['ideal', *SWEEPS]}")
    p.add_argument("--severities", nargs="+", type=float,
                   help="override the severities of every swept condition")
    p.add_argument("--block", help="one extra condition as a YAML/JSON mapping "
                                   "(a conditions: block), e.g. '{latency: 1, failures: 1}'")
    p.add_argument("--modes", nargs="+", default=["card"], choices=("card", "greedy"))
    p.add_argument("--dead-reckon", choices=("off", "on", "both"), default="off")
    p.add_argument("--planner", action="store_true",
                   help="MAIF: also play the centralised planner and the relaxed bound under "
                        "the same conditions (on --task, else on each model's task)")
    p.add_argument("--instances", type=int, default=100,
                   help="MAIF instances / RWARE episodes per row")
    p.add_argument("--set", default=DEFAULT_SET)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="JSON: every row's summary and per-instance records")
    p.add_argument("--markdown", type=Path)
    args = p.parse_args(argv)
    bad = [c for c in args.conditions if c != "ideal" and c not in SWEEPS]
    if bad:
        print(f"eval_conditions: --conditions: {bad} unknown; allowed: ideal, "
              f"{', '.join(SWEEPS)}", file=sys.stderr)
        return 2
    if not args.models and not (args.planner and args.task):
        print("eval_conditions: give model directories, or --planner with --task",
              file=sys.stderr)
        return 2
    if args.instances < 1:
        print("eval_conditions: --instances must be >= 1", file=sys.stderr)
        return 2
    extra: list[tuple[str, str, Conditions]] = []
    if args.block:
        try:
            extra.append(("block", args.block,
                          conditions_from_dict(load_yaml(args.block, what="--block"))))
        except (ConditionsError, YamlError) as e:
            print(f"eval_conditions: --block: {e}", file=sys.stderr)
            return 2
    plan: list[tuple[str, str, Conditions]] = []
    for c in args.conditions:
        if c == "ideal":
            continue
        default_severities, make = SWEEPS[c]
        for v in args.severities or default_severities:
            try:
                plan.append((c, f"{v:g}", make(v).validate()))
            except ConditionsError as e:
                print(f"eval_conditions: --severities: {c} {v:g}: {e}", file=sys.stderr)
                return 2
    plan += extra
    reckon = {"off": [False], "on": [True], "both": [False, True]}[args.dead_reckon]
    rows: list[dict[str, Any]] = []
    rware = [m for m in args.models if _rware_task(m, args.task)]
    if rware:
        return _rware_main(args, rware, plan, reckon, len(rware) == len(args.models))
    for model in args.models:
        task = args.task or _card_env(model)
        if task not in MAIF_CONFIGS:
            print(f"eval_conditions: --task: {task!r} is not a MAIF task; allowed: "
                  f"{', '.join(MAIF_CONFIGS)}", file=sys.stderr)
            return 2
        rt = ActorRuntime.from_file(model / "actor.safetensors")
        inst = set_instances(task, args.set)
        for mode_name in args.modes:
            base = card_mode(model) if mode_name == "card" else Mode()
            t0 = time.monotonic()
            ideal = evaluate_under(rt, task, Conditions(), base, instances=args.instances,
                                   which=args.set, seed=args.seed)
            for dr in reckon:
                mode = dataclasses.replace(base, dead_reckon=dr)
                # dead reckoning changes nothing without latency: one ideal row per mode
                first = [] if dr and len(reckon) > 1 else [("ideal", "-", Conditions(), ideal)]
                runs = [*first, *[(c, v, cond, None) for c, v, cond in plan]]
                for cname, sev, cond, recs0 in runs:
                    recs = recs0
                    if recs is None:
                        t0 = time.monotonic()
                        recs = evaluate_under(rt, task, cond, mode, instances=args.instances,
                                              which=args.set, seed=args.seed)
                    s = summarise_under(recs, ideal, inst.num_formations)
                    took = time.monotonic() - t0
                    print(f"[cond] {model.name} on {task} ({mode.label()}) {cname} {sev}: "
                          f"success {s['success_rate']:.3f} {s['success_ci95_maps']}, makespan "
                          f"{s['makespan_mean']}, / ideal {s.get('makespan_over_ideal')}, "
                          f"{took:.0f} s", flush=True)
                    rows.append({"policy": model.name, "task": task, "set": args.set,
                                 "set_checksum": set_checksum(inst), "mode": mode.label(),
                                 "dead_reckon": dr, "condition": cname, "severity": sev,
                                 "conditions": cond.to_dict(), "seed": args.seed,
                                 "summary": s, "records": records_json(recs)})
                    if args.out:  # after every row: a long sweep keeps what it has
                        write_json(args.out, rows)
    if args.planner:
        tasks = [args.task] if args.task else list(dict.fromkeys(
            str(_card_env(m)) for m in args.models))
        try:
            rows += reference_rows(tasks, plan, reckon, args)
        except PlannerError as e:
            print(f"eval_conditions: --planner: {e}", file=sys.stderr)
            return 2
        if args.out:
            write_json(args.out, rows)
    print_table(markdown(rows), args.markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
