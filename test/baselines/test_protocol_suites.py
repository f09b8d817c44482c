"""The protocol suites: per-group seeds (10 for SDHN and MAPPO on maif-10, 5 for the others),
a quick budget's one seed, seed-major order, the 1-layer generator as a named variant, the same
warm start for every method, and run_experiments --methods."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from sdhn_experiments.experiments import ExperimentError, load_suite
from sdhn_experiments.experiments_cli import main as run_experiments

SUITES = Path(__file__).resolve().parents[2] / "configs" / "suites"


def test_maif10_protocol_seeds_per_method() -> None:
    runs = load_suite(SUITES / "maif-10-protocol.yaml", "protocol")
    seeds = Counter(r.method for r in runs)
    assert seeds["sdhn"] == seeds["mappo"] == 10
    assert all(seeds[m] == 5 for m in ("qmix", "dicg", "hgcn_mix", "sdhn_wo_lsk", "sdhn_wo_shr",
                                       "sdhn_generator_1_layer", "sdhn_procedural_maps"))
    procedural = next(r for r in runs if r.method == "sdhn_procedural_maps")
    # the method's value, not the budget's
    assert procedural.overrides["env.instance_set"] == "procedural"
    assert next(r for r in runs if r.method == "sdhn").overrides["env.instance_set"] == "large"
    one_layer = next(r for r in runs if r.method == "sdhn_generator_1_layer")
    assert one_layer.overrides["sdhn.generator_layers"] == 1
    assert "sdhn.generator_layers" not in next(r for r in runs if r.method == "sdhn").overrides
    # seed-major: every method has seed 1..5 before SDHN and MAPPO go on to 6..10
    order = [r.seed for r in runs]
    assert order == sorted(order)
    assert {r.overrides["actor.init_from"] for r in runs} == {
        "models/maif-tiny-sdhn/actor.safetensors"}
    quick = load_suite(SUITES / "maif-10-protocol.yaml", "quick")
    assert {r.seed for r in quick} == {1} and len(quick) == 9


def test_scaling_suite_has_every_method_on_16_and_20_from_one_start() -> None:
    runs = load_suite(SUITES / "maif-scaling.yaml", "protocol")
    per = Counter((r.task, r.method) for r in runs)
    assert set(per.values()) == {3} and len(per) == 16
    assert len({r.overrides["actor.init_from"] for r in runs}) == 1


def test_a_group_with_bad_seeds_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("methods: {m: {algo: sdhn}}\ntasks: {maif-tiny: {}}\n"
                   "experiments: [{methods: [m], tasks: [maif-tiny], seeds: [a]}]\n"
                   "budgets: {quick: {}}\n")
    with pytest.raises(ExperimentError, match=r"experiments\[0\].seeds"):
        load_suite(bad, "quick")


def test_run_experiments_methods_filter(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                        ) -> None:
    suite = str(SUITES / "maif-10-protocol.yaml")
    assert run_experiments([suite, "--budget", "protocol", "--logdir", str(tmp_path), "--list",
                            "--methods", "sdhn", "mappo"]) == 0
    names = capsys.readouterr().out.split()
    listed = [n for n in names if n.startswith("maif-10__")]
    assert len(listed) == 20 and all("__sdhn__" in n or "__mappo__" in n for n in listed)
    assert run_experiments([suite, "--list", "--methods", "nope"]) == 2
    assert "--methods" in capsys.readouterr().err


def test_run_experiments_seeds_and_runs_filters(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    suite = str(SUITES / "rware.yaml")
    common = [suite, "--budget", "long", "--logdir", str(tmp_path), "--list"]
    assert run_experiments([*common, "--methods", "mappo_ent01_warm", "--seeds", "3"]) == 0
    assert capsys.readouterr().out.split()[1::2] == ["rware-3__mappo_ent01_warm__s3"]
    wanted = ["rware-3__sdhn_ent01_warm__s2", "rware-3__mappo_ent01_warm__s3"]
    assert run_experiments([*common, "--runs", *wanted]) == 0
    assert capsys.readouterr().out.split()[1::2] == wanted  # in the order given
    assert run_experiments([*common, "--seeds", "7"]) == 2
    assert "--seeds: [7]" in capsys.readouterr().err
    assert run_experiments([*common, "--runs", "rware-3__sdhn__s9"]) == 2
    assert "--runs" in capsys.readouterr().err


def test_paper_budget_suite_shares_the_protocol_settings_and_marks_2m_and_5m() -> None:
    """10 M steps, 5 seeds of SDHN and MAPPO (DICG optional) with maif-10-protocol's start and
    evaluation, the actor exported at 2 M and 5 M so the protocol's 2 M point is measured."""
    runs = load_suite(SUITES / "maif-10-paper-budget.yaml", "paper")
    protocol = {r.method: r for r in load_suite(SUITES / "maif-10-protocol.yaml", "protocol")}
    seeds = Counter(r.method for r in runs)
    assert seeds == {"sdhn": 5, "mappo": 5, "dicg": 5}
    for run in runs:
        assert run.overrides["train.total_steps"] == 10_000_000
        assert run.overrides["log.actor_marks"] == [2_000_000, 5_000_000]
        same = protocol[run.method].overrides
        for key in ("env.instance_set", "actor.init_from", "eval.interval"):
            assert run.overrides[key] == same[key], key
