"""Every launch graph in configs/launch/ loads and validates as shipped (deploy weights included:
they exist and fit the env), so a renamed model or a stale config fails here and not in front of
a user. The deploy configs name the shipped models, whose cards must say the same env."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from sdhn_bringup.launch_load import load_config, resolve_weights

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs" / "launch").glob("*.yaml"))


@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_launch_config_validates(path: Path) -> None:
    # The file's weights: paths resolve against the repository root from any directory
    # (test_launch_paths.py); the blank-weights override below is a --set, read from the cwd.
    raw = yaml.safe_load(path.read_text())
    # A deploy graph left without weights is run with --set weights=...: give it the shipped
    # model of its env, as the README does.
    blank = raw.get("mode") == "deploy" and not raw.get("weights")
    cfg = load_config(path, [f"weights={ROOT}/models/{raw['env']}-sdhn"] if blank else [])
    if cfg.mode == "deploy" and cfg.weights:
        card = resolve_weights(cfg.weights).parent / "card.json"
        if card.is_file():  # a shipped model: its card names the env it was evaluated on
            assert json.loads(card.read_text())["env"] == cfg.env
