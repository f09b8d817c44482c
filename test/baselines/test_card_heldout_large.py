"""sdhn_experiments.card_heldout (scripts/card_heldout_large.py): a shipped card gains the large
held-out set (greedy and a sampled mode) without losing what ship_model wrote, rerunning
replaces that section, and a card whose checksum names other weights is refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from sdhn_experiments import card_heldout

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "maif-solo-mappo"


def test_card_gains_the_large_set_and_keeps_the_rest(tmp_path: Path) -> None:
    card = card_heldout
    model = tmp_path / "maif-solo-mappo"
    shutil.copytree(MODEL, model)
    before = (model / "card.md").read_text()
    assert card.main([str(model), "--temperature", "0.5", "--no-planner"]) == 0
    data = json.loads((model / "card.json").read_text())
    entry = data["heldout_large"]
    assert entry["instances"] == 1000 and entry["maps"] == 200
    assert set(entry["modes"]) == {"greedy", "sampled at T=0.5"}
    assert entry["deploy"] == {"greedy": False, "temperature": 0.5, "break_stalls": False}
    for m in entry["modes"].values():
        lo, hi = m["success_ci95_maps"]
        assert lo <= m["success_rate"] <= hi
    md = (model / "card.md").read_text()
    assert md.startswith(before.rstrip("\n")) and md.count(card.TITLE) == 1
    assert "`temperature: 0.5`" in md
    # again, greedy only: the section is replaced, not appended
    assert card.main([str(model), "--no-planner"]) == 0
    md = (model / "card.md").read_text()
    assert md.count(card.TITLE) == 1 and "sampled at" not in md
    assert json.loads((model / "card.json").read_text())["evaluation"] == data["evaluation"]
    # stall breaking: evaluated and recommended, unless --deploy names another evaluated mode
    assert card.main([str(model), "--break-stalls", "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert entry["deploy"] == {"greedy": True, "temperature": 1.0, "break_stalls": True}
    assert any(m.startswith("greedy, stall breaking") for m in entry["modes"])
    assert "`break_stalls: true`" in (model / "card.md").read_text()
    assert card.main([str(model), "--temperature", "0.5", "--break-stalls", "--deploy",
                      "sampled", "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert len(entry["modes"]) == 3 and entry["deploy"]["temperature"] == 0.5
    assert card.main([str(model), "--deploy", "break-stalls", "--no-planner"]) == 2
    # a rule other than the actor's default is named in the card, for the launch config
    assert card.main([str(model), "--break-stalls", "2,10,2", "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert entry["deploy"]["stall_rule"] == "2,10,2"
    assert "greedy, stall breaking 2,10,2" in entry["modes"]
    assert '`stall_rule: "2,10,2"`' in (model / "card.md").read_text()
    assert card.main([str(model), "--break-stalls", "2,10", "--no-planner"]) == 2
    # dead reckoning in the recommended mode: the launcher and deploy.json take it from here
    assert card.main([str(model), "--dead-reckoning", "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert entry["deploy"] == {"greedy": True, "temperature": 1.0, "break_stalls": False,
                               "dead_reckoning": True}
    assert "`dead_reckoning: true`" in (model / "card.md").read_text()
    contract = json.loads((model / "deploy.json").read_text())
    assert contract["mode"]["dead_reckoning"] and "dead_reckoning" in contract


def test_card_of_other_weights_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                          ) -> None:
    card = card_heldout
    model = tmp_path / "m"
    shutil.copytree(MODEL, model)
    data = json.loads((model / "card.json").read_text())
    data["weights_sha256"] = "0" * 64
    (model / "card.json").write_text(json.dumps(data))
    assert card.main([str(model), "--no-planner"]) == 2
    assert "ship it again" in capsys.readouterr().err
    assert "heldout_large" not in json.loads((model / "card.json").read_text())


def test_card_recommends_the_final_approach(tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """--final-approach: stall breaking evaluated without and with the rule, the card's deploy
    names it, and deploy.json carries it as data (with the grid's size). On the 100-instance
    held-out set instead of the large one, to keep the test short."""
    card = card_heldout
    monkeypatch.setattr(card, "SET", "heldout")
    model = tmp_path / "maif-solo-mappo"
    shutil.copytree(MODEL, model)
    assert card.main([str(model), "--final-approach", "--no-planner"]) == 2
    assert card.main([str(model), "--break-stalls", "--deploy", "final-approach",
                      "--no-planner"]) == 2
    assert card.main([str(model), "--break-stalls", "2,10,2", "--final-approach",
                      "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert entry["deploy"] == {"greedy": True, "temperature": 1.0, "break_stalls": True,
                               "stall_rule": "2,10,2", "final_approach": True}
    assert {"greedy, stall breaking 2,10,2",
            "greedy, stall breaking 2,10,2, final approach"} <= set(entry["modes"])
    assert "`final_approach: true`" in (model / "card.md").read_text()
    contract = json.loads((model / "deploy.json").read_text())
    assert contract["mode"]["final_approach"] is True
    assert contract["mode"]["measured"]["success_rate"] == \
        entry["modes"]["greedy, stall breaking 2,10,2, final approach"]["success_rate"]
    assert contract["final_approach"]["constants"]["grid_size"] == 12
    # the card may still recommend stall breaking alone: then the contract has no rule
    assert card.main([str(model), "--break-stalls", "2,10,2", "--final-approach", "--deploy",
                      "break-stalls", "--no-planner"]) == 0
    contract = json.loads((model / "deploy.json").read_text())
    assert "final_approach" not in contract and "final_approach" not in contract["mode"]


def test_only_the_recommended_mode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--only-deploy: the recommended mode is measured and recorded alone (a fleet's modes cost
    half an hour each), and it is still the one the card recommends."""
    card = card_heldout
    monkeypatch.setattr(card, "SET", "heldout")
    model = tmp_path / "maif-solo-mappo"
    shutil.copytree(MODEL, model)
    assert card.main([str(model), "--break-stalls", "2,10,2", "--final-approach",
                      "--only-deploy", "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert list(entry["modes"]) == ["greedy, stall breaking 2,10,2, final approach"]
    assert entry["deploy"]["final_approach"] is True
    assert card.main([str(model), "--temperature", "0.5", "--only-deploy", "--no-planner"]) == 0
    entry = json.loads((model / "card.json").read_text())["heldout_large"]
    assert list(entry["modes"]) == ["sampled at T=0.5"]
    assert card.main([str(model), "--only-deploy", "--no-planner"]) == 0
    assert list(json.loads((model / "card.json").read_text())["heldout_large"]["modes"]) == \
        ["greedy"]
