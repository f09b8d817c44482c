"""The robustness suite (sdhn_experiments.robustness, .actor_history, .robustness_report):
actors restored from git history only with the manifest's bytes, one result per actor that a
rerun skips, and the report's statistics and verdict on synthetic results."""

from __future__ import annotations

import hashlib
import json
import lzma
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sdhn_experiments import protocol_stats as ps
from sdhn_experiments import robustness as rb
from sdhn_experiments.actor_history import (
    ActorHistoryError,
    load_manifest,
    manifest_from_tree,
    restore,
    write_manifest,
)
from sdhn_experiments.condition_eval import Mode
from sdhn_experiments.robustness_report import (
    boot_mean,
    boot_poi,
    claim_verdict,
    marl_eval,
    write_report,
)
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_eval import run_actor
from sdhn_sim.envs.registry import make_env

TINY = Path("models/maif-tiny-sdhn")
RUN = "carry/suite-a/maif-tiny__sdhn__s1"


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c",
                           "user.email=t@example.com", *args], check=True, capture_output=True,
                          text=True).stdout.strip()


@pytest.fixture
def history(tmp_path: Path) -> tuple[Path, str]:
    """A tiny repository whose first commit holds a run's actor and whose second drops it."""
    repo = tmp_path / "repo"
    (repo / RUN).mkdir(parents=True)
    _git(tmp_path, "init", "-q", str(repo))
    for name in ("actor.safetensors", "actor.json"):
        shutil.copy(TINY / name, repo / RUN / name)
    _git(repo, "add", "-A")
    _git(repo, "commit", "-q", "-m", "run")
    first = _git(repo, "rev-parse", "HEAD")
    _git(repo, "rm", "-q", "-r", "carry")
    _git(repo, "commit", "-q", "-m", "compact")
    return repo, first


def test_an_actor_is_restored_from_history_with_the_manifests_bytes(
        history: tuple[Path, str], tmp_path: Path) -> None:
    repo, first = history
    [e] = manifest_from_tree(repo, first, ["carry/suite-a"])
    assert (e.task, e.method, e.seed, e.suite) == ("maif-tiny", "sdhn", 1, "suite-a")
    write_manifest(tmp_path / "actors.json", [e], "test")
    [e2] = load_manifest(tmp_path / "actors.json")
    path = restore(e2, repo, tmp_path / "cache")
    assert path.read_bytes() == (TINY / "actor.safetensors").read_bytes()
    assert ActorRuntime.from_file(path).spec == ActorRuntime.from_file(
        TINY / "actor.safetensors").spec
    path.write_bytes(b"tampered")  # a damaged cache is restored again, not used
    assert restore(e2, repo, tmp_path / "cache").read_bytes() == (
        TINY / "actor.safetensors").read_bytes()


def test_a_checksum_mismatch_is_refused(history: tuple[Path, str], tmp_path: Path) -> None:
    repo, first = history
    [e] = manifest_from_tree(repo, first, ["carry/suite-a"])
    bad = replace(e, sha256={**e.sha256, "actor.safetensors": "0" * 64})
    with pytest.raises(ActorHistoryError, match="refused"):
        restore(bad, repo, tmp_path / "cache")
    assert not (tmp_path / "cache" / bad.key() / "actor.safetensors").exists()


def test_a_shallow_clone_says_how_to_fetch_the_history(history: tuple[Path, str],
                                                       tmp_path: Path) -> None:
    repo, first = history
    [e] = manifest_from_tree(repo, first, ["carry/suite-a"])
    shallow = tmp_path / "shallow"
    _git(tmp_path, "clone", "-q", "--depth", "1", f"file://{repo}", str(shallow))
    with pytest.raises(ActorHistoryError) as err:
        restore(e, shallow, tmp_path / "cache")
    msg = str(err.value)
    assert "\n" not in msg and "git fetch --unshallow" in msg and first[:12] in msg


def test_a_malformed_manifest_names_the_field(tmp_path: Path) -> None:
    p = tmp_path / "actors.json"
    p.write_text(json.dumps({"actors": [{"run": "r", "suite": "s", "task": "maif-10",
                                         "method": "sdhn", "seed": 1, "commit": "abc",
                                         "path": "p", "sha256": {}}]}))
    with pytest.raises(ActorHistoryError, match=r"actors\[0\]\.commit"):
        load_manifest(p)


def _tiny_actor() -> rb.Actor:
    return rb.Actor(key="tiny", policy="sdhn", seed=1, task="maif-tiny",
                    path=TINY / "actor.safetensors", mode=Mode(), mode_name="greedy",
                    source={"suite": "test", "run": "maif-tiny__sdhn__s1"})


def test_one_actor_result_holds_every_setting_with_its_planner_ratio(tmp_path: Path) -> None:
    settings = rb.plan_settings(["latency", "failures"], maif=True, severities=1)
    assert [(s.condition, s.level) for s in settings] == [
        ("ideal", 0), ("latency", 1), ("failures", 1)]
    res = rb.evaluate_actor(_tiny_actor(), settings, instances=2, seed=0,
                            planner_cache=tmp_path)
    assert len(res["planner_makespan"]) == 2 and res["instances"] == 2
    for s in res["settings"]:
        recs = s["records"]
        assert len(recs) == 2
        assert s["summary"]["success_rate"] == np.mean([r[0] for r in recs])
        done = [r[1] / p for r, p in zip(recs, res["planner_makespan"], strict=True)
                if r[1] and p]
        assert s["summary"]["makespan_over_planner"] == (np.mean(done) if done else None)
    assert res["settings"][1]["conditions"] == {"latency": 1}


def test_rware_ideal_deliveries_are_the_deployed_evaluations() -> None:
    rt = ActorRuntime.from_file("models/rware-tiny-2ag-mappo/actor.safetensors")
    [ideal] = rb.plan_settings([], maif=False)
    got = rb._records_rware(rt, "rware-tiny-2ag", ideal, Mode(), episodes=2, seed=7)
    want = run_actor(rt, make_env("rware-tiny-2ag", num_envs=2, seed=7), 7)
    assert got == [e.deliveries for e in want]
    assert [s.condition for s in rb.plan_settings(["latency", "position_noise"], False)] == [
        "ideal", "latency", "latency", "latency", "latency"]  # MAIF-only noise dropped
    assert [s.severity for s in rb.plan_settings(["failures"], False, num_robots=3)] == [
        0.0, 1.0, 2.0]  # one of three robots must survive


def test_a_present_result_is_skipped_and_another_plan_redone(tmp_path: Path) -> None:
    a = _tiny_actor()
    one = rb.plan_settings(["lost_actions"], maif=True, severities=1)
    logs: list[str] = []
    assert rb.run_suite([a], lambda _: one, lambda _: 2, tmp_path, seed=0, log=logs.append) == 1
    first = rb.result_path(tmp_path, a).read_bytes()
    assert rb.run_suite([a], lambda _: one, lambda _: 2, tmp_path, seed=0, log=logs.append) == 0
    assert any("present, skipped" in s for s in logs)
    assert rb.result_path(tmp_path, a).read_bytes() == first
    assert rb.run_suite([a], lambda _: one, lambda _: 3, tmp_path, seed=0, log=logs.append) == 1


def _synthetic(method: str, seed: int, ideal: float, losses: list[float]) -> dict[str, Any]:
    """A result file as ``evaluate_actor`` writes it, with chosen success rates."""
    settings = []
    for lvl, v in enumerate([ideal, *[ideal - x for x in losses]]):
        succ = np.zeros(20, dtype=int)
        succ[: round(v * 20)] = 1
        recs = [[int(s), 60 if s else None] for s in succ]
        settings.append({"condition": "ideal" if lvl == 0 else "latency", "level": lvl,
                         "severity": float(lvl), "conditions": {},
                         "summary": {"success_rate": float(succ.mean()),
                                     "makespan_over_planner": 1.2 if succ.any() else None},
                         "records": recs})
    return {"format": rb.FORMAT, "key": f"{method}{seed}", "policy": method, "seed": seed,
            "task": "maif-10", "source": {"suite": "s"}, "instances": 20,
            "planner_makespan": [50] * 20, "settings": settings, "cpu_s": 1.0}


def test_the_claim_verdict_follows_the_loss_under_conditions(tmp_path: Path) -> None:
    robust = [_synthetic("sdhn", s, 0.9, [0.05, 0.1, 0.15, 0.2]) for s in (1, 2, 3)]
    fragile = [_synthetic("sdhn_wo_shr", s, 0.9, [0.3, 0.4, 0.5, 0.6]) for s in (1, 2, 3)]
    assert claim_verdict(robust, fragile, "success_rate")["verdict"] == "reproduced"
    assert claim_verdict(fragile, robust, "success_rate")["verdict"] == "contradicted"
    same = claim_verdict(robust, [_synthetic("sdhn_wo_shr", s, 0.9, [0.05, 0.1, 0.15, 0.2])
                                  for s in (4, 5, 6)], "success_rate")
    assert same["verdict"] == "inconclusive"
    assert claim_verdict(robust[:2], fragile, "success_rate")["verdict"] == "no verdict"
    for r in robust:
        (tmp_path / f"{r['key']}.json").write_text(json.dumps(r))
    for r in fragile:  # as committed: compressed
        (tmp_path / f"{r['key']}.json.xz").write_bytes(lzma.compress(json.dumps(r).encode()))
    js = write_report(tmp_path, tmp_path / "out")
    m = js["maif-10"]["methods"]["sdhn"]["settings"]["latency/4"]
    assert m["success_rate"]["point"] == pytest.approx(0.7) and m["seeds_n"] == 3
    assert m["success_rate"]["ci95_low"] == pytest.approx(0.7)  # no spread over seeds
    assert js["maif-10"]["poi"]["sdhn_wo_shr"]["latency/4"]["point"] == 1.0
    assert (tmp_path / "out" / "robustness_maif-10.png").stat().st_size > 0
    me = marl_eval(robust + fragile)
    runs = me["MAIF-conditions"]["maif-10-latency-4"]["sdhn_wo_shr"]
    assert sorted(runs) == ["1", "2", "3"]
    assert np.mean(runs["1"]["absolute_metrics"]["success_rate"]) == pytest.approx(0.3)


def test_the_committed_manifest_is_well_formed() -> None:
    entries = load_manifest(rb.MANIFEST)
    keys = [e.key() for e in entries]
    assert len(keys) == len(set(keys))
    assert {e.method for e in entries if e.task == "maif-10"} >= {
        "sdhn", "mappo", "dicg", "qmix", "hgcn_mix", "sdhn_wo_shr", "sdhn_wo_lsk",
        "sdhn_generator_1_layer"}
    assert all(len(h) == 64 and int(h, 16) >= 0 for e in entries for h in e.sha256.values())
    assert hashlib.sha256(b"").hexdigest() not in {h for e in entries for h in e.sha256.values()}


def test_the_vectorised_bootstrap_agrees_with_the_protocols_rliable() -> None:
    rng = np.random.default_rng(3)
    x, y = rng.random((5, 2)), rng.random((4, 2)) * 0.8
    want = ps.probability_of_improvement(x, y, reps=1000)
    got = boot_poi(x, y, reps=1000)
    assert got.point == pytest.approx(want.point)
    assert got.low == pytest.approx(want.low, abs=0.06)
    assert got.high == pytest.approx(want.high, abs=0.06)
    m = ps.interval_estimates({"a": x[:, :1]}, reps=1000)["a"]["mean"]
    b = boot_mean(x[:, 0], reps=1000)
    assert b.point == pytest.approx(m.point)
    assert (b.low, b.high) == pytest.approx((m.low, m.high), abs=0.06)
