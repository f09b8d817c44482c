"""The shipped policies deployed over ROS with the simulator's realtime clock (prints figures and
writes JSON; not a test). Run with the venv's python, on a machine as idle as it gets:

    .venv/bin/python scripts/realtime_deploy.py --rates 5 10 20 --episodes 20 \
        --out runs/realtime --json docs/results/realtime-deploy.json

For each launch config (default: configs/launch/deploy-maif10.yaml and deploy-maif20.yaml, the
cards' deployment modes) and each rate, one launcher run: simulator with ``clock: realtime`` at
that rate, one actor process per robot, no recorder, ``--episodes`` episodes from ``--seed``
(the same seed at every rate: the same instances in the same order). From the simulator's events
(``status/sim-events.jsonl``) it reports per run: success rate (95 % Wilson interval), makespan
over completed episodes (mean, 95 % t interval), the staleness of the applied actions (fraction
at 0, 1, 2+ steps; mean), robot-steps without a new action (missed) and superseded actions, the
ticks the timer ran late, the achieved step rate, and the load average over the run. Each run's
episodes (instance, outcome, staleness) go into the JSON.

``--inprocess`` then plays the same policy in the same deployment mode in process
(``sdhn_sim.envs.conditions.ConditionedEnv``) on every instance of the set the simulator draws
from (MAIF "train", 100 instances, one episode each, the same step limit) under the condition that
matches each run's measurement: observation latency = its mean staleness rounded (the staleness
the policy saw), lost actions = its missed fraction (a robot-step without a new action stays, as
a lost action does); and under the ideal world for reference. It prints whether the ROS figures
lie in the in-process intervals.

    .venv/bin/python scripts/realtime_deploy.py --inprocess docs/results/realtime-deploy.json

``--dead-reckoning on|off|both`` runs each config and rate with the actors' dead reckoning on,
off, or once each (default: as the card says); conditions ride on ``--set 'conditions={latency:
1}'``. Each run records both from its parameters file, and the in-process comparison plays the
run's conditions (plus the matched staleness and misses) with dead reckoning where the run had
it. ``--clock lockstep`` runs each config once in lock-step (no rate):

    .venv/bin/python scripts/realtime_deploy.py --clock lockstep --episodes 20 \
        --set 'conditions={latency: 1}' --dead-reckoning both --json /tmp/dr.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from sdhn_experiments.bench import CHECKOUT

ROOT = CHECKOUT
CONFIGS = ["configs/launch/deploy-maif10.yaml", "configs/launch/deploy-maif20.yaml"]


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (max(0.0, c - h), min(1.0, c + h))


def mean_interval(xs: list[float]) -> tuple[float, float, float]:
    if not xs:
        return (math.nan, math.nan, math.nan)
    m = float(np.mean(xs))
    if len(xs) < 2:
        return (m, math.nan, math.nan)
    h = float(stats.t.ppf(0.975, len(xs) - 1) * np.std(xs, ddof=1) / math.sqrt(len(xs)))
    return (m, m - h, m + h)


def read_events(run_dir: Path) -> list[dict[str, Any]]:
    path = run_dir / "status" / "sim-events.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def summarise(events: list[dict[str, Any]]) -> dict[str, Any]:
    eps = [e for e in events if e["event"] == "episode"]
    stopped = next((e for e in events if e["event"] == "stopped"), {})
    started = next((e for e in events if e["event"] == "started"), None)
    done = [e for e in eps if e["completed"]]
    stale: dict[int, int] = {}
    for e in eps:
        for k, c in e.get("staleness", {}).items():
            stale[int(k)] = stale.get(int(k), 0) + int(c)
    applied = sum(stale.values())
    robot_steps = sum(e["length"] for e in eps) * (started or {}).get("robots", 0)
    missed = sum(e["missed_actions"] for e in eps)
    steps = sum(e["length"] for e in eps)
    t0 = started["time"] if started else math.nan
    t1 = eps[-1]["time"] if eps else math.nan
    k = len(done)
    ms = mean_interval([float(e["makespan"]) for e in done])
    return {
        "episodes": len(eps), "success": k / len(eps) if eps else math.nan,
        "success_ci": wilson(k, len(eps)),
        "makespan": ms[0], "makespan_ci": (ms[1], ms[2]),
        "staleness": {str(s): c for s, c in sorted(stale.items())},
        "staleness_fraction": {"0": stale.get(0, 0) / applied if applied else math.nan,
                               "1": stale.get(1, 0) / applied if applied else math.nan,
                               "2+": sum(c for s, c in stale.items() if s >= 2) / applied
                               if applied else math.nan},
        "mean_staleness": sum(s * c for s, c in stale.items()) / applied if applied else math.nan,
        "missed_fraction": missed / robot_steps if robot_steps else math.nan,
        "superseded": sum(e.get("superseded_actions", 0) for e in eps),
        "late_ticks": stopped.get("late_ticks"),
        "achieved_hz": steps / (t1 - t0) if eps and t1 > t0 else math.nan,
        "per_episode": [{k2: e.get(k2) for k2 in (
            "episode", "instance_id", "completed", "makespan", "length", "missed_actions",
            "staleness", "superseded_actions")} for e in eps],
    }


def run_one(config: str, rate: float | None, args: argparse.Namespace, reckon: bool | None
            ) -> tuple[Path, float, tuple[float, float], int]:
    """One launcher run; ``rate`` None = lock-step; ``reckon`` None = as the card says."""
    episodes, seed, out = args.episodes, args.seed, args.out
    extra = [*args.set, *([f"dead_reckoning={str(reckon).lower()}"] if reckon is not None
                          else [])]
    name = (f"{Path(config).stem}-{rate:g}hz" if rate is not None else
            f"{Path(config).stem}-lockstep") + {None: "", True: "-dr", False: "-plain"}[reckon]
    run_dir = out / name
    clock = ["clock=realtime", f"rate_hz={float(rate)}"] if rate is not None else \
        ["clock=lockstep"]
    sets = [*clock, f"episodes={episodes}", f"seed={seed}",
            "recorder=false", f"run_dir={run_dir}", f"team_ns=/rt_{name.replace('-', '_')}",
            "status_interval=30", *extra]
    cmd = [sys.executable, "-m", "sdhn_bringup", config, *(a for s in sets for a in ("--set", s))]
    load0 = os.getloadavg()[0]
    t0 = time.monotonic()
    out.mkdir(parents=True, exist_ok=True)
    # the launcher's own lines (status, exit codes) beside the run: why a run exited non-zero
    with (out / f"{name}.launcher.log").open("w") as log:
        code = subprocess.run(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                              check=False).returncode
    return run_dir, time.monotonic() - t0, (load0, os.getloadavg()[0]), code


def run_settings(run_dir: Path) -> tuple[bool, dict[str, Any]]:
    """(dead reckoning, conditions block) a run's nodes were started with (its params.yaml)."""
    from sdhn_base.yaml_io import load_yaml

    path = run_dir / "params.yaml"
    if not path.exists():
        return False, {}
    nodes = load_yaml(path, what="params file") or {}
    actors = [v["ros__parameters"] for k, v in nodes.items() if k.endswith("/actor")]
    sim: dict[str, Any] = next((v["ros__parameters"] for k, v in nodes.items()
                                if k.endswith("/sim")), {})
    text = sim.get("conditions") or ""
    return (any(bool(a.get("dead_reckoning")) for a in actors),
            dict(load_yaml(text, what="conditions") or {}) if text else {})


def play_in_process(config: str, cond_block: dict[str, Any], max_steps: int,
                    seed: int = 0, instances: list[int] | None = None, *,
                    dead_reckoning: bool = False) -> dict[str, Any]:
    """One episode per instance of the "train" set (or of ``instances``, in that order) under
    ``cond_block``, in the config's deployment mode (with dead reckoning if asked); success and
    makespan, 95 % intervals."""
    from sdhn_base.yaml_io import load_yaml
    from sdhn_policy.actor_runtime import ActorRuntime
    from sdhn_policy.dead_reckoning import DeadReckoner
    from sdhn_policy.stall_breaker import StallBreaker, StallRule
    from sdhn_sim.envs import make_env
    from sdhn_sim.envs.conditions import ConditionedEnv, conditions_from_dict

    cfg = load_yaml(ROOT / config, what="launch config")
    weights = ROOT / cfg["weights"]  # the shipped configs name a model folder (its actor file)
    rt = ActorRuntime.from_file(weights / "actor.safetensors" if weights.is_dir() else weights)
    greedy, temperature = bool(cfg.get("greedy", True)), float(cfg.get("temperature", 1.0))
    rule = StallRule.of_mode(cfg)
    played = list(range(100)) if instances is None else instances
    b = len(played)
    env = ConditionedEnv(make_env(cfg["env"], num_envs=b, seed=seed, max_steps=max_steps,
                                  instance_order="round_robin", instance_ids=played),
                         conditions_from_dict(cond_block))
    n = env.num_robots
    obs, _ = env.reset()
    h = rt.initial_state(b * n)
    ids = np.tile(np.arange(n), b) if rt.spec.use_robot_id else None
    rng = np.random.default_rng(seed)
    breaker = StallBreaker(rule, b * n) if rule is not None else None
    dr = DeadReckoner(b * n, int(getattr(env.inner_env, "size", 0))) if dead_reckoning else None
    out: dict[int, Any] = {}
    while len(out) < b:
        flat = obs.reshape(b * n, -1)
        if dr is not None:
            flat = dr.correct(flat, env.obs_age.reshape(-1))
        act, _, h_next = rt.act(flat, h, greedy=greedy, rng=rng, robot_id=ids,
                                temperature=temperature)
        if breaker is not None:
            act = breaker.resample(rt, flat, h, act, rng=rng, robot_id=ids)
        h = h_next
        if dr is not None:
            dr.record(act)
        res = env.step(act.reshape(b, n))
        for o in env.outcomes:
            out.setdefault(o.env_index, o)
        for ep in res.episodes:
            h[ep.env_index * n:(ep.env_index + 1) * n] = 0.0
            if breaker is not None:
                breaker.reset(slice(ep.env_index * n, (ep.env_index + 1) * n))
            if dr is not None:
                dr.reset(slice(ep.env_index * n, (ep.env_index + 1) * n))
        obs = res.obs
    oks = [out[e].survivors_completed for e in range(b)]
    ms = mean_interval([float(out[e].survivors_makespan) for e in range(b) if oks[e]])
    k = int(sum(oks))
    return {"conditions": cond_block, "dead_reckoning": dead_reckoning, "instances": b,
            "success": k / b,
            "success_ci": wilson(k, b), "makespan": ms[0], "makespan_ci": (ms[1], ms[2]),
            "per_instance": [[played[e], bool(oks[e]),
                              out[e].survivors_makespan if oks[e] else None] for e in range(b)]}


def inside(x: float | None, ci: Any) -> bool:
    return (x is not None and ci[0] is not None
            and ci[0] - 1e-9 <= x <= ci[1] + 1e-9)


def compare(path: Path) -> None:
    """The in-process figures under each run's matching condition, beside the ROS ones."""
    data = json.loads(path.read_text())
    limit = int(next((s.split("=")[1] for s in data["meta"].get("sets", [])
                      if s.startswith("max_steps=")), 500))
    ideal: dict[str, Any] = {}
    for run in data["runs"]:
        if run["config"] not in ideal:
            ideal[run["config"]] = play_in_process(run["config"], {}, limit)
        reckon = bool(run.get("dead_reckoning", False))
        # the run's own conditions, with the staleness and misses the clock added on top
        block: dict[str, Any] = dict(run.get("conditions") or {})
        lat = round(run["mean_staleness"] or 0) + int(block.get("latency", 0))
        block["lost_actions"] = round(min(float(block.get("lost_actions", 0.0))
                                          + (run["missed_fraction"] or 0), 0.99), 3)
        if lat:
            block["latency"] = lat
        run["inprocess_ideal"] = ideal[run["config"]]
        run["inprocess_matched"] = m = play_in_process(run["config"], block, limit,
                                                       dead_reckoning=reckon)
        played = [int(e["instance_id"]) for e in run["per_episode"]]
        run["inprocess_matched_same_instances"] = same = play_in_process(
            run["config"], block, limit, instances=played, dead_reckoning=reckon)
        inside_s = inside(run["success"], m["success_ci"])
        inside_m = inside(run["makespan"], m["makespan_ci"])
        run["within_interval"] = {"success": inside_s, "makespan": inside_m,
                                  "inprocess_in_ros_success": inside(m["success"],
                                                                     run["success_ci"]),
                                  "inprocess_in_ros_makespan": inside(m["makespan"],
                                                                      run["makespan_ci"])}
        i = ideal[run["config"]]
        print(f"{label(run)}: ROS success {run['success']:.2f}"
              f", makespan {run['makespan'] or math.nan:.1f} | in process {block}"
              f"{' with dead reckoning' if reckon else ''}: success "
              f"{fmt_ci(m['success'], m['success_ci'])}, makespan "
              f"{fmt_ci(m['makespan'], m['makespan_ci'], 1)} (inside: success {inside_s}, "
              f"makespan {inside_m}) | same {len(played)} instances in process: success "
              f"{same['success']:.2f}, makespan {same['makespan']:.1f} | ideal: "
              f"{fmt_ci(i['success'], i['success_ci'])}, "
              f"{fmt_ci(i['makespan'], i['makespan_ci'], 1)}", flush=True)
    path.write_text(json.dumps(no_nan(data), indent=1))


def no_nan(x: Any) -> Any:
    """JSON has no NaN: None instead."""
    if isinstance(x, float) and math.isnan(x):
        return None
    if isinstance(x, dict):
        return {k: no_nan(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [no_nan(v) for v in x]
    return x


def fmt_ci(v: float, ci: tuple[float, float], digits: int = 2) -> str:
    if math.isnan(v):
        return "—"
    return f"{v:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def label(run: dict[str, Any]) -> str:
    """'deploy-maif10 10 Hz', 'deploy-maif20 lock-step', with the run's conditions and dead
    reckoning where it had them."""
    clock = f"{run['rate_hz']:g} Hz" if run.get("rate_hz") else "lock-step"
    extra = "".join([f" {run['conditions']}" if run.get("conditions") else "",
                     " + dead reckoning" if run.get("dead_reckoning") else ""])
    return f"{Path(run['config']).stem} {clock}{extra}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--configs", nargs="+", default=CONFIGS)
    p.add_argument("--rates", nargs="+", type=float, default=[5.0, 10.0, 20.0])
    p.add_argument("--dead-reckoning", choices=("card", "on", "off", "both"), default="card",
                   help="the actors' dead reckoning: as the card says, on, off, or a run of each")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime",
                   help="lockstep: one run per config, no rate (e.g. with --set conditions=...)")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--out", type=Path, default=Path(f"runs/realtime-{time.strftime('%H%M%S')}"))
    p.add_argument("--json", type=Path, help="write every run's figures and episodes here")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="extra launcher overrides for every run (e.g. max_steps=300)")
    p.add_argument("--inprocess", type=Path, metavar="JSON",
                   help="instead: add the in-process comparison to a JSON this script wrote")
    args = p.parse_args(argv)
    if args.inprocess:
        compare(args.inprocess)
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    rates: list[float | None] = list(args.rates) if args.clock == "realtime" else [None]
    choices: dict[str, list[bool | None]] = {"card": [None], "on": [True], "off": [False],
                                             "both": [False, True]}
    reckons = choices[args.dead_reckoning]
    for config, rate, reckon in itertools.product(args.configs, rates, reckons):
        run_dir, wall, load, code = run_one(config, rate, args, reckon)
        s = summarise(read_events(run_dir))
        reckoned, conditions = run_settings(run_dir)
        s |= {"config": config, "clock": args.clock, "rate_hz": rate,
              "dead_reckoning": reckoned, "conditions": conditions, "wall_s": round(wall, 1),
              "load_avg_1min": load, "exit_code": code, "run_dir": str(run_dir)}
        results.append(s)
        f = s["staleness_fraction"]
        print(f"{label(s)}: {s['episodes']} episodes, success "
              f"{fmt_ci(s['success'], s['success_ci'])}, makespan "
              f"{fmt_ci(s['makespan'], s['makespan_ci'], 1)}; staleness 0/1/2+ "
              f"{f['0']:.3f}/{f['1']:.3f}/{f['2+']:.3f} (mean {s['mean_staleness']:.3f}), "
              f"missed {s['missed_fraction']:.3f}, superseded {s['superseded']}, late ticks "
              f"{s['late_ticks']}, achieved {s['achieved_hz']:.2f} Hz; {wall:.0f} s, load "
              f"{load[0]:.1f}->{load[1]:.1f}, exit {code}", flush=True)
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            meta = {"machine": f"{os.cpu_count()} cores", "seed": args.seed,
                    "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                    "sets": args.set}
            args.json.write_text(json.dumps(no_nan({"meta": meta, "runs": results}), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
