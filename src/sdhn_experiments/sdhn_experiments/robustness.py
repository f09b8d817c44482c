"""The robustness suite: every actor under every deployment condition at several severities.

    robustness_suite run --tasks maif-10 --instances 100 --out docs/results/robustness/raw
    robustness_suite run --models models/maif-10-sdhn --modes card greedy --out ...
    robustness_suite report docs/results/robustness/raw docs/results/robustness
    robustness_suite manifest COMMIT carry/maif-10-protocol-protocol ... --out actors.json

For each actor (the protocol suites' final per-seed actors, restored from git history through
the manifest ``docs/results/robustness/actors.json`` by ``actor_history``; or a shipped model
directory) x condition x severity (``SWEEPS``; the ideal world is severity 0, shared by every
condition): MAIF: success (under robot failure, the survivors' success) and makespan over the
centralised planner's on instances 0..K-1 of the large held-out set; RWARE: deliveries per
500-step episode on the protocol's absolute-metric episodes (seeds from ``RWARE_EVAL_SEED``).
The condition model is seeded ``--seed``; env ``b`` plays instance ``b``.

Modes: the protocol's actors play greedy, as the protocol's absolute metric does
(``heldout_eval.evaluate_set``), without dead reckoning (the raw policies are what the paper's
claim is about); a shipped model plays in its card's deployment mode (``card``) or greedy.

Resumable: one JSON result file per actor and mode, written atomically after the actor's last
setting; an actor whose file is present with the same plan is skipped. Progress is printed per
actor with its CPU time. Statistics, figures and the claims verdict: ``robustness_report``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sdhn_experiments.actor_history import (
    ActorEntry,
    ActorHistoryError,
    default_cache,
    load_manifest,
    manifest_from_tree,
    restore,
    write_manifest,
)
from sdhn_experiments.condition_eval import Mode, card_mode, evaluate_under
from sdhn_experiments.heldout_eval import (
    Policy,
    default_planner_cache,
    planner_makespans,
    set_checksum,
    set_instances,
    write_json,
)
from sdhn_sim.envs.conditions import ConditionedEnv, Conditions

FORMAT = "sdhn-robustness/1"
MANIFEST = Path("docs/results/robustness/actors.json")
SET = "heldout_large"

# condition -> (severities, what one severity means, the Conditions of one severity, MAIF only)
Make = Callable[[float], Conditions]
SWEEPS: dict[str, tuple[tuple[float, ...], str, Make, bool]] = {
    "latency": ((1, 2, 3, 4), "steps old", lambda k: Conditions(latency=int(k)), False),
    "lost_actions": ((0.05, 0.1, 0.2, 0.4), "p lost", lambda p: Conditions(lost_actions=p),
                     False),
    "slow_half": ((0.75, 0.5, 0.25, 0.1), "rate of the slow half",
                  lambda r: Conditions(slow_fraction=0.5, slow_rate=r), False),
    "position_noise": ((0.05, 0.1, 0.2, 0.4), "p one cell off",
                       lambda p: Conditions(position_noise=p), True),
    "cell_misread": ((0.02, 0.05, 0.1, 0.2), "p per cell",
                     lambda p: Conditions(cell_misread=p), True),
    "failures": ((1, 2, 3, 4), "robots failed", lambda k: Conditions(failures=int(k)), False),
}
DEFAULT_CONDITIONS = ("latency", "lost_actions", "slow_half", "position_noise", "failures")
RWARE_CONDITIONS = ("latency", "lost_actions", "slow_half", "failures")


@dataclass(frozen=True)
class Setting:
    condition: str  # "ideal" or a SWEEPS key
    level: int  # 0 = ideal, 1.. = the severities in order
    severity: float
    cond: Conditions


def plan_settings(conditions: list[str], maif: bool, severities: int | None = None,
                  num_robots: int | None = None) -> list[Setting]:
    """The ideal world (level 0) and each condition at its severities (the first
    ``severities`` of them when given). MAIF-only conditions are dropped for RWARE, and
    failures of ``num_robots`` or more (one robot must survive: rware-3 has 1 and 2)."""
    out = [Setting("ideal", 0, 0.0, Conditions())]
    for c in conditions:
        if c not in SWEEPS:
            raise ValueError(f"condition {c!r}: unknown; allowed: {', '.join(SWEEPS)}")
        sev, _, make, maif_only = SWEEPS[c]
        if maif_only and not maif:
            continue
        for i, v in enumerate(sev[:severities]):
            if c == "failures" and num_robots is not None and v >= num_robots:
                continue
            out.append(Setting(c, i + 1, float(v), make(v)))
    return out


@dataclass(frozen=True)
class Actor:
    """What the suite evaluates: a weights file, who it is, and how it plays."""

    key: str  # result file stem
    policy: str  # the method (protocol actors) or the model's name (shipped)
    seed: int | None
    task: str
    path: Path  # actor.safetensors
    mode: Mode
    mode_name: str  # "greedy" or "card"
    source: dict[str, Any]  # where the weights came from (manifest entry or model dir)


def protocol_actor(e: ActorEntry, path: Path) -> Actor:
    return Actor(key=f"{e.key()}__greedy", policy=e.method, seed=e.seed, task=e.task, path=path,
                 mode=Mode(), mode_name="greedy",
                 source={"suite": e.suite, "run": e.run, "commit": e.commit, "path": e.path,
                         "sha256": e.sha256["actor.safetensors"]})


def model_actors(model: Path, modes: list[str]) -> list[Actor]:
    card = json.loads((model / "card.json").read_text())
    out = []
    for m in modes:
        mode = card_mode(model) if m == "card" else Mode()
        out.append(Actor(key=f"shipped__{model.name}__{m}", policy=model.name, seed=None,
                         task=str(card["env"]), path=model / "actor.safetensors", mode=mode,
                         mode_name=m, source={"model": model.name}))
    return out


def _records_maif(policy: Policy, task: str, s: Setting, mode: Mode, *, instances: int,
                  seed: int) -> list[list[Any]]:
    recs = evaluate_under(policy, task, s.cond, mode, instances=instances, which=SET, seed=seed)
    return [[int(r.success), r.makespan] for r in recs]


def _records_rware(policy: Policy, task: str, s: Setting, mode: Mode, *, episodes: int,
                   seed: int) -> list[int]:
    """Deliveries of one episode per env under the condition (env b from seed ``seed + b``)."""
    from sdhn_sim.envs.registry import make_env

    env = ConditionedEnv(make_env(task, num_envs=episodes, seed=seed), s.cond)
    b, n = env.num_envs, env.num_robots
    obs, _ = env.reset(seed=seed)
    h = policy.initial_state(b * n)
    ids = np.tile(np.arange(n), b) if policy.spec.use_robot_id else None
    rng = np.random.default_rng(seed)
    out: dict[int, int] = {}
    while len(out) < b:
        act, _, h = policy.act(obs.reshape(b * n, -1), h, greedy=mode.greedy, rng=rng,
                               robot_id=ids, temperature=mode.temperature)
        res = env.step(act.reshape(b, n))
        for o in env.outcomes:
            out.setdefault(o.env_index, int(o.deliveries or 0))
        for ep in res.episodes:
            h[ep.env_index * n:(ep.env_index + 1) * n] = 0.0
        obs = res.obs
    return [out[e] for e in range(b)]


def summarise_setting(records: list[Any], ideal: list[Any] | None,
                      planner: list[int | None] | None) -> dict[str, Any]:
    """MAIF records ``[success, makespan]``: success rate, makespan mean over completions,
    makespan over the planner's (mean ratio over completed instances the planner completes) and
    over the actor's own ideal makespan (paired). RWARE records (deliveries): their mean and
    the mean over the ideal's."""
    if records and isinstance(records[0], list):
        succ = [r[0] for r in records]
        mk = [r[1] for r in records if r[1] is not None]
        out: dict[str, Any] = {"success_rate": float(np.mean(succ)),
                               "makespan_mean": float(np.mean(mk)) if mk else None}
        if planner is not None:
            rp = [r[1] / p for r, p in zip(records, planner, strict=True) if r[1] and p]
            out["makespan_over_planner"] = float(np.mean(rp)) if rp else None
        if ideal is not None:
            ri = [r[1] / i[1] for r, i in zip(records, ideal, strict=True) if r[1] and i[1]]
            out["makespan_over_ideal"] = float(np.mean(ri)) if ri else None
        return out
    d = np.asarray(records, dtype=np.float64)
    res: dict[str, Any] = {"deliveries_mean": float(d.mean())}
    if ideal is not None:
        base = float(np.mean(ideal))
        res["deliveries_over_ideal"] = float(d.mean() / base) if base > 0 else None
    return res


def plan_json(settings: list[Setting], instances: int, seed: int) -> dict[str, Any]:
    return {"instances": instances, "seed": seed,
            "settings": [[s.condition, s.level, s.severity] for s in settings]}


def evaluate_actor(actor: Actor, settings: list[Setting], *, instances: int, seed: int,
                   planner_cache: Path | None = None,
                   progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The actor's result: one entry per setting with its summary and per-instance records."""
    from sdhn_policy.actor_runtime import ActorRuntime

    maif = actor.task.startswith("maif")
    rt = ActorRuntime.from_file(actor.path)
    t_cpu, t_wall = time.process_time(), time.monotonic()
    planner: list[int | None] | None = None
    head: dict[str, Any] = {}
    if maif:
        inst = set_instances(actor.task, SET)
        k = min(instances, inst.num_instances)
        planner = planner_makespans(actor.task, SET, planner_cache, instances=k)[:k]
        head = {"set": SET, "set_checksum": set_checksum(inst), "instances": k,
                "formations_per_map": inst.num_formations, "planner_makespan": planner}
    else:
        from sdhn_policy.deploy_eval import RWARE_EVAL_SEED

        k = instances
        head = {"episodes": k, "episode_seeds": f"{RWARE_EVAL_SEED}..{RWARE_EVAL_SEED + k - 1}"}
    rows: list[dict[str, Any]] = []
    ideal: list[Any] | None = None
    for s in settings:
        if maif:
            recs: list[Any] = _records_maif(rt, actor.task, s, actor.mode, instances=k,
                                            seed=seed)
        else:
            from sdhn_policy.deploy_eval import RWARE_EVAL_SEED

            recs = _records_rware(rt, actor.task, s, actor.mode, episodes=k,
                                  seed=RWARE_EVAL_SEED)
        if s.level == 0:
            ideal = recs
        summary = summarise_setting(recs, ideal if s.level else None, planner)
        rows.append({"condition": s.condition, "level": s.level, "severity": s.severity,
                     "conditions": s.cond.active(), "summary": summary, "records": recs})
        if progress is not None:
            first = next(iter(summary.items()))
            progress(f"  {s.condition} {s.severity:g}: {first[0]} {first[1]:.3f}")
    return {"format": FORMAT, "key": actor.key, "policy": actor.policy, "seed": actor.seed,
            "task": actor.task, "mode": actor.mode.label(), "mode_name": actor.mode_name,
            "source": actor.source, "plan": plan_json(settings, instances, seed),
            "condition_seed": seed, **head, "settings": rows,
            "cpu_s": round(time.process_time() - t_cpu, 2),
            "wall_s": round(time.monotonic() - t_wall, 2),
            "load_1min": round(os.getloadavg()[0], 2)}


def result_path(out: Path, actor: Actor) -> Path:
    return out / f"{actor.key}.json"


def is_done(path: Path, plan: dict[str, Any]) -> bool:
    """A result file for this plan is present (another plan's file is redone)."""
    if not path.is_file():
        return False
    try:
        return bool(json.loads(path.read_text()).get("plan") == plan)
    except (OSError, ValueError):
        return False


def run_suite(actors: list[Actor], settings_of: Callable[[Actor], list[Setting]],
              instances_of: Callable[[Actor], int], out: Path, *, seed: int,
              planner_cache: Path | None = None, log: Callable[[str], None] = print) -> int:
    """Evaluate every actor whose result is not there yet; returns how many were evaluated."""
    out.mkdir(parents=True, exist_ok=True)
    done = 0
    for i, a in enumerate(actors):
        settings, k = settings_of(a), instances_of(a)
        path = result_path(out, a)
        if is_done(path, plan_json(settings, k, seed)):
            log(f"[robustness] {i + 1}/{len(actors)} {a.key}: present, skipped")
            continue
        log(f"[robustness] {i + 1}/{len(actors)} {a.key} on {a.task} ({a.mode.label()}), "
            f"{len(settings)} settings x {k}")
        res = evaluate_actor(a, settings, instances=k, seed=seed, planner_cache=planner_cache,
                             progress=log)
        write_json(path, res)
        done += 1
        log(f"[robustness] {a.key}: {res['cpu_s']:.0f} CPU-s, {res['wall_s']:.0f} s wall, "
            f"load {res['load_1min']}")
    return done


def _cmd_run(args: argparse.Namespace) -> int:
    actors: list[Actor] = []
    if args.tasks:
        try:
            entries = load_manifest(args.manifest)
        except ActorHistoryError as err:
            print(f"robustness_suite: {err}", file=sys.stderr)
            return 2
        chosen = [e for e in entries if e.task in args.tasks
                  and (not args.methods or e.method in args.methods)
                  and (not args.suites or e.suite in args.suites)
                  and (args.max_seed is None or e.seed <= args.max_seed)]
        # seed-major: an interrupted suite has every method at its first seeds
        for e in sorted(chosen, key=lambda e: (e.task, e.seed, e.method)):
            try:
                path = restore(e, args.repo, args.cache)
            except ActorHistoryError as ex:
                print(f"robustness_suite: {ex}", file=sys.stderr)
                return 2
            actors.append(protocol_actor(e, path))
    for m in args.models:
        actors += model_actors(m, args.modes)
    if not actors:
        print("robustness_suite: no actor chosen (--tasks with the manifest, or --models)",
              file=sys.stderr)
        return 2
    inst = dict(kv.split("=", 1) for kv in args.instances_for)

    def instances_of(a: Actor) -> int:
        return int(inst.get(a.task, args.instances))

    def settings_of(a: Actor) -> list[Setting]:
        from sdhn_sim.envs.registry import make_env

        maif = a.task.startswith("maif")
        conds = args.conditions or list(DEFAULT_CONDITIONS if maif else RWARE_CONDITIONS)
        return plan_settings(conds, maif, args.severities,
                             make_env(a.task, num_envs=1).num_robots)

    run_suite(actors, settings_of, instances_of, args.out, seed=args.seed,
              planner_cache=None if args.no_planner_cache else default_planner_cache(),
              log=lambda s: print(s, flush=True))
    return 0


def _cmd_manifest(args: argparse.Namespace) -> int:
    try:
        entries = manifest_from_tree(args.repo, args.commit, args.dirs)
    except ActorHistoryError as e:
        print(f"robustness_suite: {e}", file=sys.stderr)
        return 2
    write_manifest(args.out, entries,
                   "Final per-seed actors of the protocol suites in git history (restored by "
                   "sdhn_experiments.actor_history; sha256 of the bytes in git).")
    print(f"[robustness] {len(entries)} actors -> {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="robustness_suite",
                                description="Every actor under every deployment condition.")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="evaluate actors (resumable: one result file per actor)")
    r.add_argument("--tasks", nargs="+", default=[],
                   help="protocol actors of these tasks from the manifest (maif-10 ...)")
    r.add_argument("--methods", nargs="+", help="only these methods")
    r.add_argument("--suites", nargs="+", help="only these suites of the manifest")
    r.add_argument("--max-seed", type=int, help="only seeds <= this")
    r.add_argument("--models", nargs="+", type=Path, default=[],
                   help="shipped model directories (card.json, actor.safetensors)")
    r.add_argument("--modes", nargs="+", default=["card", "greedy"], choices=("card", "greedy"),
                   help="modes of the shipped models")
    r.add_argument("--conditions", nargs="+", choices=list(SWEEPS),
                   help=f"default: MAIF {list(DEFAULT_CONDITIONS)}, RWARE "
                        f"{list(RWARE_CONDITIONS)}")
    r.add_argument("--severities", type=int, help="only the first N severities of each")
    r.add_argument("--instances", type=int, default=100,
                   help="MAIF instances / RWARE episodes per setting")
    r.add_argument("--instances-for", nargs="+", default=[], metavar="TASK=K",
                   help="per-task override, e.g. maif-20=50 rware-3=20")
    r.add_argument("--seed", type=int, default=0, help="the condition model's seed")
    r.add_argument("--manifest", type=Path, default=MANIFEST)
    r.add_argument("--repo", type=Path, default=Path("."), help="the git clone holding history")
    r.add_argument("--cache", type=Path, default=default_cache(),
                   help="where restored actors go (outside the repository)")
    r.add_argument("--no-planner-cache", action="store_true")
    r.add_argument("--out", type=Path, required=True, help="result directory")
    m = sub.add_parser("manifest", help="write the manifest from a commit's run directories")
    m.add_argument("commit")
    m.add_argument("dirs", nargs="+", help="suite directories in that commit's tree")
    m.add_argument("--repo", type=Path, default=Path("."))
    m.add_argument("--out", type=Path, default=MANIFEST)
    rep = sub.add_parser("report", help="statistics, figures, marl-eval JSON, claim verdict")
    rep.add_argument("results", type=Path)
    rep.add_argument("outdir", type=Path)
    args = p.parse_args(argv)
    if args.cmd == "run":
        if args.instances < 1:
            print("robustness_suite: --instances must be >= 1", file=sys.stderr)
            return 2
        return _cmd_run(args)
    if args.cmd == "manifest":
        return _cmd_manifest(args)
    from sdhn_experiments.robustness_report import write_report

    write_report(args.results, args.outdir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
