"""What ships in the repository stays consistent: every launch config under configs/launch passes
the launcher's own validation (its weights exist and fit its task), and every model under models/
is the model its card describes (the card's weights checksum is the file's, the card's task is
one the weights fit). A shipped policy retrained without its card, or a launch config pointing at
a model that moved, fails here instead of at a user's first `scripts/launch.sh`."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from sdhn_bringup.launch_load import check_weights_fit, load_config

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_CONFIGS = sorted((ROOT / "configs" / "launch").glob("*.yaml"))
MODELS = sorted(p for p in (ROOT / "models").iterdir() if (p / "card.json").is_file())


def test_the_repository_ships_launch_configs_and_models() -> None:
    # The parametrised tests below pass vacuously on an empty list.
    assert LAUNCH_CONFIGS and MODELS


@pytest.mark.parametrize("path", LAUNCH_CONFIGS, ids=lambda p: p.name)
def test_every_launch_config_validates(path: Path) -> None:
    cfg = load_config(path, [])  # names its weights from the repository root, from any cwd
    if cfg.mode == "deploy":
        assert Path(cfg.weights).is_file(), cfg.weights


@pytest.mark.parametrize("model", MODELS, ids=lambda p: p.name)
def test_every_model_card_matches_its_weights(model: Path) -> None:
    card = json.loads((model / "card.json").read_text())
    weights = model / "actor.safetensors"
    assert hashlib.sha256(weights.read_bytes()).hexdigest() == card["weights_sha256"], (
        f"{model.name}: card.json's weights_sha256 is not actor.safetensors' (retrained without "
        "re-running scripts/ship_model.py?)")
    check_weights_fit(weights, card["env"])
