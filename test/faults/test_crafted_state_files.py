"""Files the trainer and the launcher read back (checkpoint sidecars, node status and event
files) with crafted JSON: a refusal or a skipped line, never an escaping RecursionError."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sdhn_base.ros.status import EventReader, read_statuses
from sdhn_train.checkpoint import CheckpointError, load_checkpoint, save_checkpoint

DEEP = "[" * 100_000 + "]" * 100_000


@pytest.mark.parametrize("sidecar", [DEEP, "[1, 2]", '"text"'])
def test_a_crafted_checkpoint_sidecar_is_a_checkpoint_error(tmp_path: Path, sidecar: str
                                                            ) -> None:
    path = tmp_path / "checkpoint"
    save_checkpoint(path, {"w": np.zeros(3, np.float32)}, {"global_step": 1})
    assert load_checkpoint(path)[1]["global_step"] == 1
    path.with_suffix(".json").write_text(sidecar)
    with pytest.raises(CheckpointError):
        load_checkpoint(path)


def test_a_forged_checkpoint_blob_is_a_checkpoint_error(tmp_path: Path) -> None:
    """The sha256 matches (forged with the payload), the blob is not safetensors."""
    from sdhn_policy.weights import sha256_hex

    path = tmp_path / "checkpoint"
    save_checkpoint(path, {"w": np.zeros(3, np.float32)}, {"global_step": 1})
    junk = b"\xff" * 64
    path.with_suffix(".safetensors").write_bytes(junk)
    meta = json.loads(path.with_suffix(".json").read_text())
    meta["tensors_sha256"] = sha256_hex(junk)
    path.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match="not a valid safetensors"):
        load_checkpoint(path)


def test_crafted_status_and_event_lines_are_skipped(tmp_path: Path) -> None:
    (tmp_path / "a.status.json").write_text(DEEP)
    statuses = read_statuses(tmp_path)
    assert "a" not in statuses
    events = tmp_path / "events.jsonl"
    events.write_text(DEEP + "\n" + json.dumps({"event": "episode", "return": float("nan")})
                      + "\n")
    got = EventReader(events).new()
    assert [e["event"] for e in got] == ["episode"], got
