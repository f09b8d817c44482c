"""Evaluate MAIF actors on whole instance sets: success with a 95 % interval, makespan against
the planner's, success per map, deadlocks. JSON + a markdown table.

    .venv/bin/python scripts/evaluate_policy.py models/maif-10-sdhn models/maif-16-sdhn \\
        --sets heldout_large train --out /tmp/eval.json --markdown /tmp/eval.md
    .venv/bin/python scripts/evaluate_policy.py RUN/actor.safetensors --task maif-10 --sample

An actor is a model directory (its card.json names the task) or an actor.safetensors file
(then --task is needed). Greedy by default (--sample: actions sampled from the policy);
--runtime torch runs the training-side torch actor instead of the deployed NumPy runtime.
The planner's makespans are cached per set under --planner-cache (computing them is the slow
part on large teams; an interrupted computation resumes).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from sdhn_base import bounded_json
from sdhn_experiments.heldout_eval import (
    WEDGE_STEPS,
    Policy,
    TorchPolicy,
    default_planner_cache,
    evaluate_set,
    planner_makespans,
    print_table,
    records_json,
    set_checksum,
    set_instances,
    stall_options,
    summarise,
    write_json,
)
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_contract import stall_mode_name
from sdhn_policy.stall_breaker import StallRule
from sdhn_policy.weights import WeightsError
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS
from sdhn_sim.envs.registry import INSTANCE_SETS

EVAL_SETS = [s for s in INSTANCE_SETS if s != "procedural"]


def resolve(actor: Path, task: str | None) -> tuple[str, Path, str]:
    """(label, actor file, task) of a model directory or an actor file."""
    if actor.is_dir():
        card = actor / "card.json"
        f = actor / "actor.safetensors"
        if task is None and card.is_file():
            try:
                named = bounded_json.loads(card.read_bytes())["env"]
                if not isinstance(named, str):
                    raise TypeError(f"env is {type(named).__name__}, not a string")
            except (OSError, ValueError, KeyError, TypeError, RecursionError) as e:
                raise ValueError(f"actor: {card} does not name a task (its 'env'): "
                                 f"{str(e)[:200]}; or give --task") from None
            task = named
        label = actor.name
    else:
        f = actor
        label = actor.parent.name or actor.stem
    if not f.is_file():
        raise ValueError(f"actor: {f} does not exist (a model directory or an actor file)")
    if task is None:
        raise ValueError(f"--task: {actor} has no card.json naming its task; allowed: "
                         f"{', '.join(k for k in MAIF_CONFIGS)}")
    if task not in MAIF_CONFIGS:
        raise ValueError(f"--task: {task!r} is not a MAIF task; allowed: {', '.join(MAIF_CONFIGS)}")
    return label, f, task


def output_problem(path: Path) -> str | None:
    """Why ``path`` cannot take an output file (None: it can)."""
    if path.is_dir():
        return "is a directory; allowed: a file path"
    if not path.parent.is_dir():
        return "is not in an existing directory"
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        return "is not writable"
    return None


def fmt(x: float | None, digits: int = 2) -> str:
    return "—" if x is None else f"{x:.{digits}f}"


def markdown(results: list[dict[str, Any]]) -> str:
    head = ("| policy | task | set (instances / maps) | mode | success [95 % CI, maps] | "
            "Wilson 95 % | makespan / planner (mean, p90) | maps at 0 | failures: deadlock / "
            "wander | success per map |\n|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for r in results:
        s = r["summary"]
        lo, hi = s["success_ci95_maps"]
        wl, wh = s["success_ci95_wilson"]
        hist = " ".join(f"{k}:{v}" for k, v in s["per_map_success_histogram"].items() if v)
        f = s["failures"]
        rows.append(
            f"| {r['policy']} | {r['task']} | {r['set']} ({s['instances']} / {s['maps']}) | "
            f"{r['mode']} | **{s['success_rate']:.3f}** [{lo:.3f}, {hi:.3f}] | "
            f"[{wl:.3f}, {wh:.3f}] | {fmt(s.get('makespan_ratio_mean'), 3)}, "
            f"{fmt(s.get('makespan_ratio_p90'), 3)} | {s['maps_with_zero_success']} | "
            f"{f['deadlock']} / {f['wander']} | {hist} |")
    return head + "\n" + "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=' '.join(__doc__.split('\n\n')[0].split()))
    p.add_argument("actors", nargs="+", type=Path, help="model directories or actor files")
    p.add_argument("--task", help="MAIF task of actor files (model directories name theirs)")
    p.add_argument("--sets", nargs="+", default=["heldout_large", "train"],
                   help=f"instance sets to play, of {EVAL_SETS}")
    p.add_argument("--sample", action="store_true", help="sample actions instead of argmax")
    p.add_argument("--temperature", type=float, default=1.0, metavar="T",
                   help="sampled play (--sample, --unstick) draws from softmax(logits / T); "
                        "T < 1 leans towards the argmax (default 1: the policy itself)")
    p.add_argument("--unstick", type=int, default=0, metavar="K",
                   help="greedy, but a robot off its goal that has not moved for K steps "
                        "samples its action until it moves (0 = off)")
    p.add_argument("--break-stalls", nargs="?", const="", default=None,
                   metavar="CALM,PROGRESS,SAMPLE[,T]",
                   help="greedy with stall breaking, as the actor nodes' break_stalls runs it "
                        "(sdhn_policy.stall_breaker); optional: the rule's steps and "
                        f"temperature (default {StallRule().text()},1)")
    p.add_argument("--final-approach", action="store_true",
                   help="with --break-stalls: a robot whose free goal is in its window steps along "
                        "a shortest free path to it (one cell off: onto it), one on its goal "
                        "stays unless stall breaking samples "
                        "(sdhn_policy.final_approach; the actor nodes' final_approach)")
    p.add_argument("--max-steps", type=int, default=None, metavar="T",
                   help="episode step limit (default: the environment's, 500 for MAIF)")
    p.add_argument("--runtime", choices=("numpy", "torch"), default="numpy")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--wedge-steps", type=int, default=WEDGE_STEPS,
                   help="K: a robot off its goal not moving for K steps at the end is wedged")
    p.add_argument("--no-planner", action="store_true", help="skip the planner's makespans")
    p.add_argument("--planner-cache", type=Path, default=default_planner_cache())
    p.add_argument("--out", type=Path, help="JSON with the summaries and per-instance records")
    p.add_argument("--markdown", type=Path, help="the markdown table")
    args = p.parse_args(argv)
    bad = [s for s in args.sets if s not in EVAL_SETS]
    if bad:
        print(f"evaluate_policy: --sets: {bad} not allowed; allowed: {EVAL_SETS}", file=sys.stderr)
        return 2
    if args.unstick < 0 or (args.unstick and args.sample):
        print("evaluate_policy: --unstick must be an integer >= 0, and only with greedy play",
              file=sys.stderr)
        return 2
    if not math.isfinite(args.temperature) or args.temperature <= 0:
        print("evaluate_policy: --temperature must be a finite number > 0", file=sys.stderr)
        return 2
    if args.temperature != 1.0 and not (args.sample or args.unstick):
        print("evaluate_policy: --temperature applies to sampled play: add --sample or --unstick",
              file=sys.stderr)
        return 2
    try:
        stall = stall_options(args.break_stalls, args.final_approach)
    except ValueError as e:
        print(f"evaluate_policy: {e}", file=sys.stderr)
        return 2
    if stall is not None and (args.sample or args.unstick or args.temperature != 1.0):
        print("evaluate_policy: --break-stalls is a greedy mode: not with --sample, "
              "--unstick or --temperature (its temperature is its fourth value)",
              file=sys.stderr)
        return 2
    if args.max_steps is not None and args.max_steps < 1:
        print("evaluate_policy: --max-steps must be an integer >= 1", file=sys.stderr)
        return 2
    if args.wedge_steps < 1:
        print("evaluate_policy: --wedge-steps must be an integer >= 1", file=sys.stderr)
        return 2
    # Everything that can be wrong is checked before the evaluation (which takes minutes to
    # hours): the outputs are written after it, and their errors lost the results.
    for flag, path in (("--out", args.out), ("--markdown", args.markdown)):
        problem = None if path is None else output_problem(path)
        if problem:
            print(f"evaluate_policy: {flag}: {path} {problem}", file=sys.stderr)
            return 2
    if not args.no_planner:
        cache = args.planner_cache
        existing = next(p for p in (cache, *cache.parents) if p.exists())  # it creates the rest
        problem = (f"cannot be a directory ({existing} is a file)" if not existing.is_dir() else
                   f"is not writable ({existing})" if not os.access(existing, os.W_OK) else None)
        if problem:
            print(f"evaluate_policy: --planner-cache: {cache} {problem}", file=sys.stderr)
            return 2
    try:
        actors = [resolve(a, args.task) for a in args.actors]
        policies: list[Policy] = [ActorRuntime.from_file(path) if args.runtime == "numpy"
                                  else TorchPolicy(path) for _, path, _ in actors]
    except WeightsError as e:
        print(f"evaluate_policy: actor: {e.reason}", file=sys.stderr)
        return 2
    except ValueError as e:
        print(f"evaluate_policy: {e}", file=sys.stderr)
        return 2
    results = []
    for (label, path, task), policy in zip(actors, policies, strict=True):
        for which in args.sets:
            inst = set_instances(task, which)
            t0 = time.monotonic()
            recs = evaluate_set(policy, task, which, sample=args.sample, seed=args.seed,
                                wedge_steps=args.wedge_steps, unstick=args.unstick,
                                temperature=args.temperature, stall=stall,
                                approach=args.final_approach, max_steps=args.max_steps)
            took = time.monotonic() - t0
            plan = None if args.no_planner else planner_makespans(
                task, which, args.planner_cache, progress=True)
            summary = summarise(recs, plan, inst.num_formations)
            at_t = f" at T={args.temperature:g}" if args.temperature != 1.0 else ""
            mode = (f"sampled{at_t}" if args.sample else
                    f"greedy, sampled{at_t} when stuck {args.unstick}" if args.unstick
                    else stall_mode_name(stall, args.final_approach) if stall else "greedy")
            print(f"[eval] {label} {task}/{which} ({mode}, {args.runtime}): success "
                  f"{summary['success_rate']:.3f} {summary['success_ci95_maps']}, makespan ratio "
                  f"{summary.get('makespan_ratio_mean')}, deadlocks "
                  f"{summary['failures']['deadlock']}, {took:.0f} s", flush=True)
            results.append({"policy": label, "actor": path.name, "task": task, "set": which,
                            "set_checksum": set_checksum(inst), "mode": mode,
                            "max_steps": args.max_steps,
                            "runtime": args.runtime, "seed": args.seed, "unstick": args.unstick,
                            "temperature": args.temperature,
                            "stall_rule": None if stall is None else asdict(stall),
                            "final_approach": args.final_approach,
                            "wedge_steps": args.wedge_steps, "summary": summary,
                            "records": records_json(recs), "planner_makespan": plan})
    if args.out:
        write_json(args.out, results)
    print_table(markdown(results), args.markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
