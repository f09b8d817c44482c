"""Ship a trained actor under models/: the weights pair plus a card with what it achieves.

    .venv/bin/python scripts/ship_model.py RUN_DIR models/maif-10-sdhn [--instances 100]
    .venv/bin/python scripts/ship_model.py RUN_DIR OUT --checkpoint step_000001200128
    .venv/bin/python scripts/ship_model.py RUN_DIR models/rware-tiny-2ag-mappo [--episodes 100]

Evaluates the run's exported ``actor.safetensors`` (or the actor of one of its checkpoints)
exactly as it deploys (the torch-free NumPy runtime, greedy) next to the scripted baselines, and
writes ``actor.safetensors`` + ``actor.json`` + ``actor.onnx`` + ``card.md`` + ``card.json`` into
the model directory (replacing what was there). MAIF: one episode per instance of the training
and the held-out instance sets; success rate and makespan (NC when nothing completed) first,
return second, under the reward named. RWARE: one 500-step episode from each of ``--episodes``
seeds never trained on; requested shelves delivered per episode, against random and the two
scripted policies on the same seeds.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_contract import write_deploy_json
from sdhn_policy.deploy_eval import (
    RWARE_EVAL_SEED,
    SETS,
    instance_env,
    run_actor,
    rware_deliveries,
    summarise,
)
from sdhn_policy.onnx_export import write_onnx
from sdhn_policy.weights import WeightsError, decode_weights, load_actor_file, save_actor_file
from sdhn_sim.envs import make_env
from sdhn_sim.envs.maif_scripted import evaluate_scripted
from sdhn_sim.envs.rware_baselines import LABELS, POLICIES, evaluate_baseline

CardWriter = Callable[[dict[str, object], str], str]  # (card, note) -> card.md


class ShipError(ValueError):
    """A run or an output that cannot be shipped; one line, exit 2."""


def _run_config(cfg_file: Path) -> dict[str, Any]:
    try:
        cfg = load_yaml(cfg_file, what="run config")
    except YamlError as e:
        raise ShipError(str(e)) from None
    if not isinstance(cfg, dict) or not all(isinstance(cfg.get(s), dict)
                                            for s in ("env", "algo", "train")):
        raise ShipError(f"{cfg_file}: not a trainer config (env, algo, train sections)")
    return cfg


def _check_out(out: Path, run_dir: Path) -> None:
    """Refuse, before any evaluation, an output that would overwrite the run or a file."""
    if out.exists() and not out.is_dir():
        raise ShipError(f"{out} exists and is not a directory: name a model directory")
    real = out.resolve()
    if real == run_dir.resolve() or run_dir.resolve() in real.parents:
        raise ShipError(f"{out} is the run directory (or inside it): ship into a model directory "
                        "such as models/maif-10-sdhn")


def _check_fits(rt: ActorRuntime, env_name: str, actor: Path) -> None:
    """The actor must read this env's observations (an actor of another env would fail, or
    worse run, midway through the evaluation)."""
    env = make_env(env_name, num_envs=1, seed=0)
    if rt.spec.obs_size != env.obs_size or (rt.spec.use_robot_id
                                            and rt.spec.num_robots != env.num_robots):
        raise ShipError(f"{actor}: an actor for obs size {rt.spec.obs_size}"
                        f"{f', {rt.spec.num_robots} robots' if rt.spec.use_robot_id else ''}; "
                        f"{env_name} has obs size {env.obs_size}, {env.num_robots} robots")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path, help="a training run directory holding actor.safetensors")
    p.add_argument("out", type=Path, help="model directory to write, e.g. models/maif-10-sdhn")
    p.add_argument("--instances", type=int, default=100, help="MAIF: instances 0..k-1 of each set")
    p.add_argument("--episodes", type=int, default=100,
                   help="RWARE: evaluation episodes, one per seed from 1,000,000 + --seed")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--note", default="", help="one paragraph for the card (how it was trained)")
    p.add_argument("--checkpoint", help="ship the actor of this checkpoint of the run (a name in "
                                        "RUN_DIR/checkpoints/) instead of its exported actor")
    args = p.parse_args(argv)
    try:
        with tempfile.TemporaryDirectory(prefix="ship-") as tmp:
            return ship(args, Path(tmp))
    except (ShipError, WeightsError, OSError) as e:
        print(f"ship_model: {e}", file=sys.stderr)
        return 2


def ship(args: argparse.Namespace, tmp: Path) -> int:
    if args.instances < 1 or args.episodes < 1:
        raise ShipError(f"--instances {args.instances} / --episodes {args.episodes}: allowed: "
                        "integers >= 1")
    if not args.run_dir.is_dir():
        raise ShipError(f"{args.run_dir} is not a run directory")
    _check_out(args.out, args.run_dir)
    actor = args.run_dir / "actor.safetensors"
    cfg_file = args.run_dir / "config.yaml"
    summary_file = args.run_dir / "summary.json"
    try:
        summary = json.loads(summary_file.read_bytes()) if summary_file.is_file() else {}
    except ValueError:
        summary = {}  # only its step count goes into the card
    summary = summary if isinstance(summary, dict) else {}
    if not cfg_file.is_file():
        raise ShipError(f"{args.run_dir} has no config.yaml: not a training run")
    cfg = _run_config(cfg_file)
    env_name, reward = str(cfg["env"].get("name")), str(cfg["env"].get("reward", "corrected"))
    family = env_name.split("-", maxsplit=1)[0]
    if family not in ("maif", "rware"):
        raise ShipError(f"{args.run_dir} trained {env_name}: ship_model ships MAIF and RWARE "
                        "actors")
    if args.checkpoint:
        from sdhn_train.checkpoint import CheckpointError
        from sdhn_train.export import actor_from_checkpoint  # torch only on this path

        stem = args.run_dir / "checkpoints" / args.checkpoint
        if not stem.with_suffix(".json").is_file():
            have = sorted(p.stem for p in (args.run_dir / "checkpoints").glob("*.json"))
            raise ShipError(f"--checkpoint {args.checkpoint}: not in {args.run_dir}/checkpoints "
                            f"(it has {', '.join(have[-3:]) or 'none'})")
        try:
            blob, step = actor_from_checkpoint(stem)
        except (CheckpointError, KeyError, ValueError) as e:
            raise ShipError(f"--checkpoint {args.checkpoint}: {e}") from None
        actor = tmp / "actor.safetensors"
        save_actor_file(actor, blob)
        summary = {"global_step": step}
    if not actor.is_file():
        raise ShipError(f"{args.run_dir} has no actor.safetensors (or name --checkpoint)")
    try:
        rt = ActorRuntime.from_file(actor)
    except ValueError as e:  # WeightsError and the runtime's own shape checks
        raise ShipError(f"{actor}: {e}") from None
    _check_fits(rt, env_name, actor)
    if family == "rware":
        evaluation, markdown = evaluate_rware(rt, env_name, args.episodes, args.seed)
    else:
        evaluation, markdown = evaluate_maif(rt, env_name, args.instances, args.seed, reward)
    card = {"env": env_name, "algo": cfg["algo"].get("name"), "reward": reward,
            "features": rt.spec.features, "seed": cfg["train"].get("seed"),
            "team_steps": summary.get("global_step"),
            "instance_set": cfg["env"].get("instance_set") if family == "maif" else None,
            "warm_start": warm_start_name((cfg.get("actor") or {}).get("init_from")),
            "weights_sha256": rt_sha(actor), "evaluation": evaluation}
    # Written next to the model directory, then moved in: a crash leaves the old model whole.
    staged = tmp / "model"
    staged.mkdir()
    for suffix in (".safetensors", ".json"):
        shutil.copyfile(actor.with_suffix(suffix), staged / f"actor{suffix}")
    (staged / "card.json").write_text(json.dumps(card, indent=2) + "\n")
    (staged / "card.md").write_text(markdown(card, args.note))
    blob = load_actor_file(actor)  # the ONNX form beside it, with its I/O contract
    spec, tensors = decode_weights(blob)
    write_onnx(staged / "actor.onnx", spec, tensors, env_family=family, version=blob.version)
    write_deploy_json(staged, spec, family)  # how to deploy it, from the card just written
    _check_out(args.out, args.run_dir)  # again: it may have changed during the evaluation
    args.out.mkdir(parents=True, exist_ok=True)
    files = ("actor.safetensors", "actor.json", "actor.onnx", "actor.onnx.json", "deploy.json",
             "card.md", "card.json")
    for f in files:
        shutil.copyfile(staged / f, args.out / f"{f}.tmp")
    for f in files:
        (args.out / f"{f}.tmp").replace(args.out / f)
    print(f"[ship] wrote {args.out}/ ({', '.join(files)})")
    return 0


def evaluate_rware(rt: ActorRuntime, env_name: str, episodes: int, seed: int
                   ) -> tuple[dict[str, Any], CardWriter]:
    """Greedy deliveries per episode of the policy and of the baselines, on the same seeds."""
    first = RWARE_EVAL_SEED + seed
    results: dict[str, Any] = {"episodes": episodes, "first_seed": first,
                               "policy": rware_deliveries(rt, env_name, episodes, first)}
    print(f"[ship] policy: {results['policy']['deliveries_mean']} deliveries per episode",
          flush=True)
    for name in POLICIES:
        r = evaluate_baseline(env_name, name, episodes=episodes, seed=first)
        results[name] = {"deliveries_mean": round(r["deliveries_mean"], 3),
                         "deliveries_std": round(r["deliveries_std"], 3)}
        print(f"[ship] {name}: {results[name]['deliveries_mean']}", flush=True)
    return results, rware_card_markdown


def evaluate_maif(rt: ActorRuntime, env_name: str, k: int, seed: int, reward: str
                  ) -> tuple[dict[str, Any], CardWriter]:
    """Greedy success and makespan on each instance set, with the scripted policies'."""
    results: dict[str, dict[str, object]] = {}
    for which in SETS:
        env = instance_env(env_name, which, k, seed, reward)
        results[f"policy/{which}"] = summarise(run_actor(rt, env, seed))
        for name in ("greedy", "planner"):
            r = evaluate_scripted(env_name, which, name, instances=k, seed=seed,
                                  reward=reward)
            results[f"{name}/{which}"] = {
                "success_rate": r.success_rate,
                "makespan": "NC" if r.makespan is None else round(r.makespan, 2),
                "return": round(r.episode_return, 2), "collisions": round(r.collisions, 2)}
        results[f"lower_bound/{which}"] = {"makespan": round(r.lower_bound, 2)}
        print(f"[ship] {which}: policy {results[f'policy/{which}']}", flush=True)
    return {"instances_per_set": k, "seed": seed, **results}, card_markdown


def warm_start_name(init_from: str | None) -> str | None:
    """The warm start as a card names it: repo-relative when it is in the repository (e.g. a
    shipped model), else the run directory's name and the file (never a machine's path)."""
    if not init_from:
        return None
    path = Path(init_from).resolve()
    # the repository is the checkout holding it (models/ and configs/ side by side), found from
    # the file itself: this module may be installed anywhere
    repo = next((d for d in path.parents if (d / "models").is_dir() and (d / "configs").is_dir()),
                None)
    if repo is not None:
        return str(path.relative_to(repo))
    return f"{path.parent.name}/{path.name}"


def rt_sha(actor: Path) -> str:
    return str(json.loads(actor.with_suffix(".json").read_text()).get("sha256", ""))


def card_markdown(card: dict[str, object], note: str) -> str:
    ev = card["evaluation"]
    assert isinstance(ev, dict)
    rows = []
    for who in ("policy", "greedy", "planner"):
        cells = []
        for which in SETS:
            r = ev[f"{who}/{which}"]
            cells.append(f"{r['success_rate']:.2f} | {r['makespan']}")
        label = {"policy": f"**this policy** ({card['algo']})",
                 "greedy": "scripted greedy (decentralised)",
                 "planner": "scripted planner (centralised)"}[who]
        rows.append(f"| {label} | {' | '.join(cells)} |")
    lb = " | ".join(f"— | {ev[f'lower_bound/{w}']['makespan']}" for w in SETS)
    returns = ", ".join(f"{w} {ev[f'policy/{w}']['return']}" for w in SETS)
    return f"""# {card['env']} · {card['algo']} · seed {card['seed']}

Greedy evaluation with the NumPy runtime that the actor nodes run, one episode per instance
({ev['instances_per_set']} training and {ev['instances_per_set']} held-out instances, 500-step
limit), written by `scripts/ship_model.py`.

| who | training success | training makespan | held-out success | held-out makespan |
|---|---|---|---|---|
{chr(10).join(rows)}
| lower bound (longest shortest path) | {lb} |

Makespan is the mean over completed episodes (NC: none completed). Return of this policy under
the `{card['reward']}` reward: {returns}.

- environment `{card['env']}`, reward `{card['reward']}`, input features `{card['features']}`
- trained for {card['team_steps']} team env-steps, seed {card['seed']}, training instances
  `{card['instance_set']}`, warm start: `{card['warm_start'] or 'none'}`
- weights sha256 `{card['weights_sha256']}`

{note}
"""



def rware_card_markdown(card: dict[str, object], note: str) -> str:
    ev = card["evaluation"]
    assert isinstance(ev, dict)
    pol = ev["policy"]
    rows = [f"| **this policy** ({card['algo']}) | {pol['deliveries_mean']:.2f} ± "
            f"{pol['deliveries_std']:.2f} |"]
    rows += [f"| {LABELS[n]} | {ev[n]['deliveries_mean']:.2f} ± {ev[n]['deliveries_std']:.2f} |"
             for n in POLICIES]
    last = ev["first_seed"] + ev["episodes"] - 1
    return f"""# {card['env']} · {card['algo']} · seed {card['seed']}

Greedy evaluation with the NumPy runtime that the actor nodes run: one 500-step episode from
each of the seeds {ev['first_seed']:,}..{last:,} ({ev['episodes']} episodes no training run
draws), written by `scripts/ship_model.py`. Requested shelves delivered per episode, mean ±
std over the episodes, every policy on the same seeds.

| who | deliveries per episode |
|---|---|
{chr(10).join(rows)}

- environment `{card['env']}` (rware's rules; the batched NumPy backend, equal to rware 2.0.0
  step for step), return of this policy (rware's individual reward, summed): {pol['return']}
- trained for {card['team_steps']} team env-steps, seed {card['seed']}, warm start:
  `{card['warm_start'] or 'none'}`
- weights sha256 `{card['weights_sha256']}`

{note}
"""


if __name__ == "__main__":
    sys.exit(main())
