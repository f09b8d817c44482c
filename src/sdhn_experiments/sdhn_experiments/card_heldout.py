"""Add the large held-out set to a shipped MAIF model's card: greedy play and, with
``--temperature T``, sampled play at T, with ``--break-stalls [RULE]`` greedy play with stall
breaking (``sdhn_policy.stall_breaker``), and with ``--final-approach`` also that with the
final-approach rule after it (``sdhn_policy.final_approach``), on the 1,000 instances on 200
maps no training run sees; the card recommends the mode its launch config deploys
(``--deploy``; default: the last one evaluated of greedy, sampled, break-stalls,
final-approach).

    .venv/bin/python scripts/card_heldout_large.py models/maif-10-sdhn --break-stalls
    .venv/bin/python scripts/card_heldout_large.py models/maif-20-sdhn --temperature 0.25 \
        --break-stalls --deploy sampled
    .venv/bin/python scripts/card_heldout_large.py models/maif-20-sdhn --break-stalls 2,10,2 \
        --final-approach

Writes ``card.json["heldout_large"]`` and a section of ``card.md`` (replacing an earlier one of
the same title; the rest of the card, written by ``ship_model.py``, is kept), each file written
atomically. The actor is checked against the card's weights checksum first, so a card never
describes other weights. Success with its map-bootstrap interval, maps at 0, failures and the
makespan over the centralised planner's (cached per set, as ``evaluate_policy.py`` does).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

from sdhn_experiments.heldout_eval import (
    default_planner_cache,
    evaluate_set,
    planner_makespans,
    set_checksum,
    set_instances,
    stall_options,
    summarise,
)
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_contract import stall_mode_name, write_deploy_json
from sdhn_policy.stall_breaker import StallRule
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS

SET = "heldout_large"
TITLE = "## Large held-out set"


DEPLOY_MODES = ("greedy", "sampled", "break-stalls", "final-approach")


def evaluate(model: Path, temperature: float | None, planner_cache: Path | None,
             seed: int = 0, *, stall_rule: StallRule | None = None, deploy: str | None = None,
             final_approach: bool = False, dead_reckoning: bool = False,
             only_deploy: bool = False) -> dict[str, Any]:
    """card.json's ``heldout_large`` entry for the model directory ``model``. ``final_approach``
    (with ``stall_rule``): greedy play with stall breaking is evaluated both without and with
    the final-approach rule, so the card shows what the rule adds. ``dead_reckoning``:
    the recommended mode includes it (the launcher then deploys it); it changes nothing on the
    current observations of this set, so the figures hold for the mode with it. ``only_deploy``:
    evaluate the recommended mode alone (a fleet's mode costs half an hour of a core per 1,000
    instances at 100 robots; the others are then left off the card, not measured)."""
    card = json.loads((model / "card.json").read_text())
    task = str(card["env"])
    if task not in MAIF_CONFIGS:
        raise ValueError(f"{model}: the card's env {task!r} is not a MAIF task")
    actor = model / "actor.safetensors"
    sha = str(json.loads(actor.with_suffix(".json").read_text()).get("sha256", ""))
    if sha != card.get("weights_sha256"):
        raise ValueError(f"{model}: actor.safetensors (sha256 {sha[:12]}) is not the card's "
                         f"weights ({str(card.get('weights_sha256'))[:12]}); ship it again")
    rt = ActorRuntime.from_file(actor)
    inst = set_instances(task, SET)
    plan = None if planner_cache is None else planner_makespans(task, SET, planner_cache,
                                                                progress=True)
    # (the --deploy kind it is, its name on the card, evaluate_set's arguments)
    runs: list[tuple[str, str, dict[str, Any]]] = [("greedy", "greedy", {})]
    if temperature is not None:
        runs.append(("sampled", f"sampled at T={temperature:g}",
                     {"sample": True, "temperature": temperature}))
    break_stalls = stall_rule is not None
    if final_approach and stall_rule is None:
        raise ValueError("--final-approach requires --break-stalls (its hold would deadlock "
                         "corridors without stall breaking)")
    if stall_rule is not None:
        runs.append(("break-stalls", stall_mode_name(stall_rule), {"stall": stall_rule}))
        if final_approach:
            runs.append(("final-approach", stall_mode_name(stall_rule, True),
                         {"stall": stall_rule, "approach": True}))
    deploy = deploy or ("final-approach" if final_approach else "break-stalls" if break_stalls
                        else "sampled" if temperature is not None else "greedy")
    if ((deploy == "sampled" and temperature is None)
            or (deploy == "break-stalls" and not break_stalls)
            or (deploy == "final-approach" and not final_approach)):
        raise ValueError(f"--deploy {deploy}: that mode is not evaluated (add --temperature, "
                         "--break-stalls or --final-approach)")
    stalls_deployed = deploy in ("break-stalls", "final-approach")
    if only_deploy:
        runs = [r for r in runs if r[0] == deploy]
    modes: dict[str, Any] = {}
    for _, name, how in runs:
        recs = evaluate_set(rt, task, SET, seed=seed, **how)
        s = summarise(recs, plan, inst.num_formations)
        modes[name] = {k: s.get(k) for k in (
            "success_rate", "success_ci95_maps", "maps_with_zero_success", "failures",
            "makespan_ratio_mean", "makespan_ratio_p90")}
        print(f"[card] {model.name} {name}: success {s['success_rate']:.3f}", flush=True)
    return {"set": SET, "set_checksum": set_checksum(inst), "instances": inst.num_instances,
            "maps": inst.num_instances // inst.num_formations, "seed": seed, "modes": modes,
            "deploy": {"greedy": deploy != "sampled",
                       "temperature": temperature if deploy == "sampled" else 1.0,
                       "break_stalls": stalls_deployed,
                       **({"stall_rule": stall_rule.text()}
                          if stalls_deployed and stall_rule is not None
                          and stall_rule != StallRule() else {}),
                       **({"final_approach": True} if deploy == "final-approach" else {}),
                       **({"dead_reckoning": True} if dead_reckoning else {})}}


def section(entry: dict[str, Any]) -> str:
    def ratio(x: float | None) -> str:
        return "–" if x is None else f"{x:.3f}"

    rows = []
    for name, m in entry["modes"].items():
        lo, hi = m["success_ci95_maps"]
        f = m["failures"]
        rows.append(f"| {name} | {m['success_rate']:.3f} [{lo:.3f}, {hi:.3f}] | "
                    f"{m['maps_with_zero_success']} | {f['deadlock']} / {f['wander']} | "
                    f"{ratio(m['makespan_ratio_mean'])}, {ratio(m['makespan_ratio_p90'])} |")
    d = entry["deploy"]
    rule = f", `stall_rule: \"{d['stall_rule']}\"`" if d.get("stall_rule") else ""
    if d.get("final_approach"):
        rule += ", `final_approach: true`"
    how = (f"`greedy: true`, `break_stalls: true`{rule}" if d.get("break_stalls") else "greedy"
           if d["greedy"] else f"`greedy: false`, `temperature: {d['temperature']:g}`")
    if d.get("dead_reckoning"):
        how += (", with dead reckoning (`dead_reckoning: true`; it changes nothing on the current "
                "observations measured here, docs/deploying-under-conditions.md)")
    return f"""{TITLE}

{entry['instances']:,} instances on {entry['maps']} maps no training run sees (set checksum
`{entry['set_checksum'][:12]}`), one episode each, with the NumPy runtime; written by
`scripts/card_heldout_large.py`. Deploy with {how}.

| mode | success [95 % CI, maps] | maps at 0 | deadlock / wander | makespan / planner (mean, p90) |
|---|---|---|---|---|
{chr(10).join(rows)}
"""


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def update_card(model: Path, entry: dict[str, Any]) -> None:
    card = json.loads((model / "card.json").read_text())
    card["heldout_large"] = entry
    md = (model / "card.md").read_text()
    if TITLE in md:  # replace the earlier section (it runs to the end of the card)
        md = md[:md.index(TITLE)].rstrip("\n") + "\n"
    _write_atomic(model / "card.json", json.dumps(card, indent=2) + "\n")
    _write_atomic(model / "card.md", md.rstrip("\n") + "\n\n" + section(entry))
    if (model / "actor.onnx").exists():  # the deployment mode just chosen, for ONNX users
        spec = ActorRuntime.from_file(model / "actor.safetensors").spec
        write_deploy_json(model, spec, "maif")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("models", nargs="+", type=Path, help="model directories (models/<name>)")
    p.add_argument("--temperature", type=float, help="also sampled play at this temperature, "
                                                     "the mode the card recommends")
    p.add_argument("--break-stalls", nargs="?", const="", default=None,
                   metavar="CALM,PROGRESS,SAMPLE[,T]",
                   help="also greedy play with stall breaking (the actor's break_stalls); "
                        "optional: the rule (default: the actor's, "
                        f"{StallRule().text()}; scripts/tune_stall_rule.py chooses one)")
    p.add_argument("--final-approach", action="store_true",
                   help="with --break-stalls: also that mode with the final-approach rule (the "
                        "actor's final_approach; sdhn_policy.final_approach), the mode the card "
                        "recommends")
    p.add_argument("--deploy", choices=DEPLOY_MODES, default=None,
                   help="the mode the card recommends (default: the last evaluated)")
    p.add_argument("--dead-reckoning", action="store_true",
                   help="the recommended mode includes dead reckoning (deployed by the launcher; "
                        "a no-op on this set's current observations)")
    p.add_argument("--only-deploy", action="store_true",
                   help="evaluate the recommended mode alone (large fleets: each mode of 1,000 "
                        "instances of 100 robots costs about half an hour)")
    p.add_argument("--no-planner", action="store_true", help="skip the planner's makespans")
    p.add_argument("--planner-cache", type=Path, default=default_planner_cache())
    args = p.parse_args(argv)
    if args.temperature is not None and not (math.isfinite(args.temperature)
                                             and args.temperature > 0):
        print("card_heldout_large: --temperature must be a finite number > 0", file=sys.stderr)
        return 2
    try:
        rule = stall_options(args.break_stalls, args.final_approach)
    except ValueError as e:
        print(f"card_heldout_large: {e}", file=sys.stderr)
        return 2
    for model in args.models:
        try:
            entry = evaluate(model, args.temperature,
                             None if args.no_planner else args.planner_cache,
                             stall_rule=rule, deploy=args.deploy,
                             final_approach=args.final_approach,
                             dead_reckoning=args.dead_reckoning,
                             only_deploy=args.only_deploy)
        except (OSError, ValueError, KeyError) as e:
            print(f"card_heldout_large: {e}", file=sys.stderr)
            return 2
        update_card(model, entry)
        print(f"[card] wrote {model}/card.md and card.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
