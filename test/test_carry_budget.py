"""The repository's ``carry/`` stays within its budget (bytes of the working tree), and every
carried run is in the compact form ``scripts/carry_runs.py save`` writes: a clone carries what
the next machine and the reports read, not the runs' full logs (docs/experiments.md)."""

from __future__ import annotations

from pathlib import Path

from sdhn_experiments.carry import BUDGET_BYTES, PACKED_FILES, run_dirs, tree_bytes

CARRY = Path(__file__).resolve().parents[1] / "carry"


def carried_runs() -> list[Path]:
    return [r for suite in sorted(CARRY.iterdir()) if suite.is_dir() for r in run_dirs(suite)]


def test_carry_is_within_its_budget() -> None:
    sizes = {d.name: tree_bytes(d) for d in CARRY.iterdir() if d.is_dir()}
    total = tree_bytes(CARRY)
    assert total <= BUDGET_BYTES, (
        f"carry/ holds {total / 1e6:.1f} MB > {BUDGET_BYTES / 1e6:.0f} MB: "
        + ", ".join(f"{k} {v / 1e6:.1f} MB" for k, v in sorted(sizes.items())))


def test_carried_runs_are_compact() -> None:
    runs = carried_runs()
    assert runs, "carry/ holds no runs: the checks below would pass on nothing"
    plain = [f"{r.parent.name}/{r.name}/{n}" for r in runs for n in PACKED_FILES
             if (r / n).exists()]
    assert not plain, f"uncompressed logs (re-save with scripts/carry_runs.py): {plain[:5]}"
    finished_ckpts = [f"{r.parent.name}/{r.name}" for r in runs
                      if (r / "DONE.json").is_file() and (r / "checkpoints").exists()]
    assert not finished_ckpts, f"finished runs carrying checkpoints: {finished_ckpts[:5]}"
    many_snaps = [f"{r.parent.name}/{r.name}" for r in runs
                  if len(list((r / "hypergraph").glob("ph_*.npz"))) > 1]
    assert not many_snaps, f"runs carrying more P_H snapshots than the newest: {many_snaps[:5]}"
