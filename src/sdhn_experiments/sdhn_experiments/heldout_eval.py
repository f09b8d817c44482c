"""A policy on a whole MAIF instance set, instance by instance: success, makespan against the
centralised planner's on the same instance, and how the failures happen.

    rt = ActorRuntime.from_file("models/maif-10-sdhn/actor.safetensors")
    recs = evaluate_set(rt, "maif-10", "heldout_large")              # one record per instance
    plan = planner_makespans("maif-10", "heldout_large", cache_dir)  # cached on disk
    report = summarise(recs, plan, num_formations=5)

One greedy (or, with ``sample=True``, sampled) episode per instance, every instance of the set
in one vectorised batch (env ``b`` plays instance ``b``), with the torch-free NumPy runtime the
actor nodes deploy or the training-side torch actor (``TorchPolicy``; the two agree).

Failure modes: a robot is **wedged** when it is off its goal and has not moved for the last
``wedge_steps`` steps of the episode; a timed-out episode with a wedged robot is a **deadlock**,
one without is a **wander** (robots still moving at the limit).

Intervals on the success rate: instances on one map are correlated (one bad map fails all its
formations), so the headline 95 % interval bootstraps over maps (``scipy.stats.bootstrap``,
percentile, on the per-map success rates; every map has the same number of formations, so their
mean is the success rate). The Wilson interval, which treats the instances as independent and
is therefore too narrow when maps matter, is reported beside it.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
from scipy import stats

from sdhn_policy.actor_runtime import ActorRuntime, check_temperature, choose_actions
from sdhn_policy.final_approach import FinalApproach
from sdhn_policy.stall_breaker import StallBreaker, StallRule
from sdhn_policy.weights import ActorSpec, atomic_write_bytes
from sdhn_sim.envs.maif import MAX_STEPS, MaifEnv
from sdhn_sim.envs.maif_instances import MaifInstances
from sdhn_sim.envs.maif_scripted import PlannerPolicy, run_episodes
from sdhn_sim.envs.registry import instance_set

WEDGE_STEPS = 50
"""A robot off its goal that has not moved for this many steps at the end is wedged (about the
makespan of a maif-10 formation: far longer than any wait a plan needs)."""


class Policy(Protocol):
    """What ``evaluate_set`` needs of an actor (``ActorRuntime`` has it)."""

    spec: ActorSpec

    def initial_state(self, n: int) -> npt.NDArray[np.float32]: ...

    def act(self, obs: npt.ArrayLike, hidden: npt.ArrayLike, greedy: bool,
            rng: np.random.Generator, robot_id: Any = None, *, temperature: float = 1.0
            ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        ...


@dataclass(frozen=True)
class InstanceResult:
    """One episode of one instance."""

    instance: int
    map: int
    success: bool
    makespan: int | None  # None: not completed within the step limit
    length: int
    wedged: int  # robots off their goal that had not moved for WEDGE_STEPS at the end
    deadlock: bool  # timed out with a wedged robot


def set_instances(task: str, which: str) -> MaifInstances:
    inst = instance_set(task, which)
    if not isinstance(inst, MaifInstances):
        raise ValueError(f"instance set {which!r} is a stream, not a fixed set to evaluate on")
    return inst


def set_checksum(inst: MaifInstances) -> str:
    """sha256 of a set's maps, starts and goals: names exactly what an evaluation ran on."""
    h = hashlib.sha256()
    for a in (inst.obstacles, inst.starts, inst.goals):
        h.update(np.ascontiguousarray(a, dtype=bool if a.dtype == bool else np.int64).tobytes())
    return h.hexdigest()


def evaluate_set(policy: Policy, task: str, which: str, *, sample: bool = False, seed: int = 0,
                 wedge_steps: int = WEDGE_STEPS, reward: str = "corrected",
                 unstick: int = 0, temperature: float = 1.0,
                 stall: StallRule | None = None, approach: bool = False,
                 max_steps: int | None = None) -> list[InstanceResult]:
    """One episode per instance of set ``which`` of ``task``, all in one batch. ``sample``:
    actions drawn from softmax(logits / ``temperature``). ``unstick`` > 0 (with greedy play): a
    robot off its goal that has not moved for ``unstick`` steps samples its action from the
    policy (at ``temperature``) instead of taking the argmax, until it moves. ``stall`` (with
    greedy play): stall breaking as the actor nodes run it (``sdhn_policy.stall_breaker``).
    ``approach`` (with ``stall``): the final-approach rule after stall breaking, as the actor
    nodes' ``final_approach`` runs it (``sdhn_policy.final_approach``). ``max_steps``: the
    episode limit (None: the environment's)."""
    check_temperature(temperature)
    if stall is not None and (sample or unstick):
        raise ValueError("stall breaking is a greedy mode: not with sample or unstick")
    if approach and stall is None:
        raise ValueError("final approach requires stall breaking (stall): its hold would "
                         "deadlock corridors without it")
    rule = FinalApproach.for_env(task) if approach else None
    inst = set_instances(task, which)
    b = inst.num_instances
    env = MaifEnv(inst, num_envs=b, seed=seed, name=task, instance_order="round_robin",
                  reward=reward, max_steps=MAX_STEPS if max_steps is None else max_steps)
    n = env.num_robots
    obs, _ = env.reset(seed=seed)
    h = policy.initial_state(b * n)
    ids = np.tile(np.arange(n), b) if policy.spec.use_robot_id else None
    rng = np.random.default_rng(seed)
    still = np.zeros((b, n), dtype=np.int64)  # steps since each robot last moved
    breaker = StallBreaker(stall, b * n) if stall is not None else None
    out: dict[int, InstanceResult] = {}
    while len(out) < b:
        before, goals = env.positions, env.goals
        flat = obs.reshape(b * n, -1)
        act, _, h_next = policy.act(flat, h, greedy=not sample, rng=rng, robot_id=ids,
                                    temperature=temperature)
        if unstick > 0 and not sample:
            stuck = (still >= unstick) & np.any(before != goals, axis=2)
            if stuck.any():  # same hidden state in, so the same next hidden state out
                drawn, _, _ = policy.act(flat, h, greedy=False, rng=rng, robot_id=ids,
                                         temperature=temperature)
                act = np.where(stuck.reshape(-1), drawn, act)
        if breaker is not None:
            act = breaker.resample(policy, flat, h, act, rng=rng, robot_id=ids)
            if rule is not None:
                act = rule.apply(flat, act, breaker.sampling)
        h = h_next
        res = env.step(act.reshape(b, n))
        after = env.positions
        for e, w in env.final_worlds.items():
            after[e] = w.positions  # where the finished episode ended, not the auto-reset start
        moved = np.any(after != before, axis=2)
        still = np.where(moved, 0, still + 1)
        for ep in res.episodes:
            e = ep.env_index
            if e not in out:
                off_goal = np.any(after[e] != goals[e], axis=1)
                wedged = int(np.sum(off_goal & (still[e] >= wedge_steps)))
                out[e] = InstanceResult(instance=e, map=e // inst.num_formations,
                                        success=bool(ep.completed), makespan=ep.makespan,
                                        length=int(ep.length), wedged=wedged,
                                        deadlock=not ep.completed and wedged > 0)
            h[e * n:(e + 1) * n] = 0.0
            still[e] = 0
            if breaker is not None:
                breaker.reset(slice(e * n, (e + 1) * n))
        obs = res.obs
    return [out[e] for e in range(b)]


def default_planner_cache() -> Path:
    """Where the planner's makespans are cached per set: $XDG_CACHE_HOME/sdhn/planner."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "sdhn" / "planner"


def planner_makespans(task: str, which: str, cache_dir: Path | None = None, *,
                      chunk: int = 50, seed: int = 0, progress: bool = False,
                      instances: int | None = None) -> list[int | None]:
    """The scripted planner's makespan on every instance of the set (None: it did not finish),
    computed in chunks and cached in ``cache_dir/planner-<task>-<which>-<checksum>.json`` (the
    planner is slow on large teams; an interrupted computation resumes from the chunks done,
    and processes computing the same set at once skip each other's chunks). ``instances``: only
    the first that many (the chunks covering them)."""
    inst = set_instances(task, which)
    path = None
    done: dict[str, int | None] = {}
    if cache_dir is not None:
        cache_dir.mkdir(parents=True, exist_ok=True)
        path = cache_dir / f"planner-{task}-{which}-{set_checksum(inst)[:16]}.json"
        if path.is_file():
            done = json.loads(path.read_text())["makespan"]
    total = inst.num_instances if instances is None else min(int(instances), inst.num_instances)
    for start in range(0, total, chunk):
        ids = list(range(start, min(start + chunk, total)))
        if path is not None and path.is_file():  # another process may have added chunks
            done = {**json.loads(path.read_text())["makespan"], **done}
        if all(str(k) in done for k in ids):
            continue
        env = MaifEnv(inst, num_envs=len(ids), seed=seed, name=task, instance_ids=ids,
                      instance_order="round_robin")
        for k, ep in zip(ids, run_episodes(env, PlannerPolicy(seed), seed=seed), strict=True):
            done[str(k)] = ep.makespan
        if path is not None:
            body = {"task": task, "set": which, "checksum": set_checksum(inst),
                    "makespan": done}
            atomic_write_bytes(path, json.dumps(body).encode())
        if progress:
            print(f"[planner] {task}/{which}: {len(done)}/{total} instances", flush=True)
    return [done[str(k)] for k in range(total)]


def wilson_interval(successes: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy's ``binomtest``)."""
    ci = stats.binomtest(successes, n).proportion_ci(confidence_level=level, method="wilson")
    return float(ci.low), float(ci.high)


def map_bootstrap_interval(per_map: npt.ArrayLike, level: float = 0.95, seed: int = 0,
                           resamples: int = 10_000) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of per-map success rates (maps resampled)."""
    x = np.asarray(per_map, dtype=np.float64)
    if np.all(x == x[0]):  # no spread: the bootstrap distribution is a point
        return float(x[0]), float(x[0])
    res = stats.bootstrap((x,), np.mean, confidence_level=level, n_resamples=resamples,
                          method="percentile", random_state=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def summarise(recs: list[InstanceResult], planner: list[int | None] | None,
              num_formations: int) -> dict[str, Any]:
    """The per-policy figures of the evaluation protocol (JSON-ready)."""
    n = len(recs)
    success = np.array([r.success for r in recs])
    maps = np.array([r.map for r in recs])
    per_map = np.array([success[maps == m].mean() for m in np.unique(maps)])
    wins = int(success.sum())
    out: dict[str, Any] = {
        "instances": n, "maps": len(per_map), "formations_per_map": num_formations,
        "success_rate": wins / n,
        "success_ci95_maps": map_bootstrap_interval(per_map),
        "success_ci95_wilson": wilson_interval(wins, n),
        "makespan_mean": _mean([r.makespan for r in recs if r.makespan is not None]),
        "maps_with_zero_success": int(np.sum(per_map == 0)),
        "per_map_success_histogram": {
            f"{k}/{num_formations}": int(np.sum(np.isclose(per_map * num_formations, k)))
            for k in range(num_formations + 1)},
    }
    failed = [r for r in recs if not r.success]
    out["failures"] = {
        "episodes": len(failed),
        "deadlock": sum(r.deadlock for r in failed),
        "wander": sum(not r.deadlock for r in failed),
        "wedged_robots_mean": _mean([r.wedged for r in failed]),
    }
    if planner is not None:
        ratios = [r.makespan / p for r, p in zip(recs, planner, strict=True)
                  if r.makespan is not None and p]
        out["planner_success_rate"] = float(np.mean([p is not None for p in planner]))
        out["makespan_ratio_mean"] = _mean(ratios)
        out["makespan_ratio_p90"] = float(np.percentile(ratios, 90)) if ratios else None
    return out


def paired_makespan_ratios(runs: list[dict[str, Any]]) -> tuple[int, list[float | None]]:
    """Makespan over the planner's, mean per run, over only the instances that *every* run
    completed (runs: ``evaluate_policy`` results of one task and set, with records and the
    planner's makespans). A mode that completes more, and so harder, instances is not charged
    for them, as the per-run mean over its own completions would. Returns (instances, means)."""
    if not runs:
        return 0, []
    keys = {(r["task"], r["set"], r.get("set_checksum")) for r in runs}
    if len(keys) != 1:
        raise ValueError(f"runs of different tasks or sets: {sorted(map(str, keys))}")
    plan = runs[0].get("planner_makespan")
    if plan is None:
        raise ValueError("no planner makespans (evaluated with --no-planner?)")
    both = [i for i, p in enumerate(plan)
            if p and all(r["records"][i]["makespan"] is not None for r in runs)]
    means: list[float | None] = [
        _mean([r["records"][i]["makespan"] / plan[i] for i in both]) for r in runs]
    return len(both), means


def modes_table(rows: list[tuple[str, dict[str, Any], float | None]]) -> list[str]:
    """Markdown lines comparing modes of one policy on one set: (mode, ``summarise`` output,
    paired makespan ratio from ``paired_makespan_ratios``) per row."""
    out = ["| mode | success [95 % CI, maps] | maps at 0 | deadlock / wander | makespan / "
           "planner, own completions | makespan / planner, paired |",
           "|---|---|---|---|---|---|"]
    for mode, s, paired in rows:
        lo, hi = s["success_ci95_maps"]
        own = s.get("makespan_ratio_mean")
        out.append(f"| {mode} | {s['success_rate']:.3f} [{lo:.3f}, {hi:.3f}] | "
                   f"{s['maps_with_zero_success']} | {s['failures']['deadlock']} / "
                   f"{s['failures']['wander']} | {'–' if own is None else f'{own:.3f}'} | "
                   f"{'–' if paired is None else f'{paired:.3f}'} |")
    return out


def _mean(xs: list[int] | list[float]) -> float | None:
    return float(np.mean(xs)) if xs else None


def records_json(recs: list[InstanceResult]) -> list[dict[str, Any]]:
    return [asdict(r) for r in recs]


class TorchPolicy:
    """The training-side torch actor behind ``ActorRuntime``'s interface (the same features and
    robot id), to check that what trains is what deploys. Imports torch."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        import torch

        from sdhn_policy.actor_torch import Actor
        from sdhn_policy.features import get_transform
        from sdhn_policy.weights import decode_weights, load_actor_file

        spec, tensors = decode_weights(load_actor_file(path))
        self._torch = torch
        self.spec = spec
        self.actor = Actor(spec)
        with torch.no_grad():
            for name, t in self.actor.tensors().items():
                t.copy_(torch.from_numpy(tensors[name]))
        self._features = get_transform(spec.features)
        self._numpy = ActorRuntime(spec, tensors)  # only for the robot-id input it builds

    def initial_state(self, n: int) -> npt.NDArray[np.float32]:
        return np.zeros((n, self.spec.gru_hidden), dtype=np.float32)

    def act(self, obs: npt.ArrayLike, hidden: npt.ArrayLike, greedy: bool,
            rng: np.random.Generator, robot_id: Any = None, *, temperature: float = 1.0
            ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        torch = self._torch
        x = self._numpy._input(obs, robot_id)
        with torch.no_grad():
            logits, h = self.actor.step(torch.from_numpy(x),
                                        torch.from_numpy(np.asarray(hidden, dtype=np.float32)))
            logp = torch.log_softmax(logits, dim=-1).numpy()
        action = choose_actions(logp, greedy, rng, temperature)
        return action, logp[np.arange(len(action)), action], h.numpy()


def write_json(path: Path, data: Any) -> None:
    atomic_write_bytes(path, (json.dumps(data, indent=1) + "\n").encode())


def stall_options(break_stalls: str | None, final_approach: bool) -> StallRule | None:
    """The stall rule of the evaluation CLIs' ``--break-stalls [CALM,PROGRESS,SAMPLE[,T]]``
    (None: not given; bare: the actor's default rule) checked with ``--final-approach``, which
    holds robots on their goals and so needs stall breaking. ValueError naming the option."""
    rule = None
    if break_stalls is not None:
        try:
            rule = StallRule.parse(break_stalls) if break_stalls else StallRule()
        except ValueError as e:
            raise ValueError(f"--break-stalls: {e}") from None
    if final_approach and rule is None:
        raise ValueError("--final-approach requires --break-stalls (its hold would deadlock "
                         "corridors without stall breaking)")
    return rule


def print_table(text: str, markdown: Path | None) -> None:
    """An evaluation CLI's last word: its Markdown table on stdout, and in ``markdown`` (the
    ``--markdown`` file) when one is named."""
    if markdown:
        markdown.write_text(text)
    print(text)
