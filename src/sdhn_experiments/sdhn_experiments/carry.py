"""Carry a suite's log directory from one machine to the next inside the repository, compactly.

Long suites (RWARE at 20 M steps, ten seeds per method) outlive the machine they run on: the
machines here are handed out for a few hours and keep nothing. ``save`` copies, for every run of
a log directory, what the runner needs to skip it (finished) or resume it (unfinished) into a
directory of the repository; ``restore`` puts it back under a log directory on the next machine,
where rerunning the suite's command carries on (``docs/experiments.md``). Every byte carried
stays in the repository's history, so a carried run is what the next machine and the reports
need and no more (``BUDGET_BYTES`` for all of ``carry/``, enforced by a test):

- its top-level files except TensorBoard event files (the curves are in ``metrics.csv``): the
  spec ``run.json``, the configs, ``summary.json``, ``DONE.json`` and the text logs, the logs
  xz-compressed (``metrics.csv.xz``, ``train.log.xz``, and the cached absolute metric
  ``heldout_large.json.xz`` / ``absolute_deliveries.json.xz``: ~8 % of their size), which the
  metrics readers (``sdhn_train.runs``) read as they are and ``restore`` unpacks;
- the exported actor (``actor.safetensors`` + ``actor.json``) of an unfinished run, and of a
  finished one until its absolute metric is cached (and, for a run that exported actors at
  ``log.actor_marks``, its deployed-mode result too, ``budget_marks``): what the report
  computes from it is then carried instead (the shipped policies live in ``models/``);
- an unfinished run's newest checkpoint (``checkpoints/step_<n>.json`` + ``.safetensors``);
  a finished run carries none;
- of the P_H snapshots (``hypergraph/``), a finished run's newest, the one the heatmaps read
  (``figures.latest_ph``);
- the actors exported at ``log.actor_marks`` (``actors/step_<n>.safetensors`` and sidecar),
  which judge one long run at several budgets.

A file over ``MAX_FILE_BYTES`` is left out and named; a checkpoint is carried whole or not at all
(a QMIX checkpoint holds its 1.3 GB replay buffer), so such a run starts again elsewhere and the
manifest says so. ``restore`` never replaces newer
progress: a run is copied back only if the log directory lacks it, or holds it at an earlier
checkpoint, or unfinished where the carried copy is finished.
"""

from __future__ import annotations

import argparse
import json
import lzma
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from sdhn_base.yaml_io import load_yaml
from sdhn_experiments.experiments import DONE, SPEC, ExperimentError, check_name
from sdhn_train.checkpoint import checkpoint_step, latest_checkpoint
from sdhn_train.run_files import PACKED_SUFFIX, packed

MAX_FILE_BYTES = 20 * 1024 * 1024
"""Above this a file is not carried (a checkpoint of the networks here is ~2 MB)."""
SKIP_PREFIXES = ("events.out.tfevents", ".")
SNAPSHOT_DIR = "hypergraph"
MARKED_ACTORS_DIR = "actors"  # the trainer's ACTOR_MARKS_DIR (no torch import here)
MANIFEST = "CARRY.json"
PACKED_FILES = ("metrics.csv", "train.log", "heldout_large.json", "absolute_deliveries.json")
"""Top-level text files carried xz-compressed (``<name>.xz``) and unpacked by ``restore``."""
ABSOLUTE_CACHES = ("heldout_large.json", "absolute_deliveries.json")  # protocol_report's
FINAL_ACTOR = ("actor.safetensors", "actor.json")
BUDGET_BYTES = 40_000_000
"""What all of ``carry/`` may hold (bytes of the working tree; test/test_carry_budget.py)."""
XZ_PRESET = 6  # the default: ~8 % of a metrics.csv; -9 gains nothing on these files


class CarryError(Exception):
    """A refused save or restore, in one line."""


@dataclass(frozen=True)
class RunProgress:
    """How far one run directory is: finished, else its newest checkpoint's step (-1: none)."""

    done: bool
    step: int

    def key(self) -> tuple[int, int]:
        return (int(self.done), self.step)

    def describe(self) -> str:
        return "finished" if self.done else (f"step {self.step:,}" if self.step >= 0
                                             else "no checkpoint")


def progress(run: Path) -> RunProgress:
    ckpt = latest_checkpoint(run)
    step = checkpoint_step(ckpt) if ckpt is not None else -1
    return RunProgress(done=(run / DONE).is_file(), step=step)


def run_dirs(logdir: Path) -> list[Path]:
    """The run directories of a log directory (those with a runner's spec), sorted."""
    if not logdir.is_dir():
        raise CarryError(f"{logdir}: no such directory")
    return sorted(d for d in logdir.iterdir() if d.is_dir() and (d / SPEC).is_file())


def _split_by_size(run: Path, files: list[Path], max_bytes: int,
                   why: str = "") -> tuple[list[Path], list[str]]:
    """(the files within ``max_bytes``; the others, named with their size and ``why``)."""
    kept: list[Path] = []
    left: list[str] = []
    for rel in files:
        size = (run / rel).stat().st_size
        if size > max_bytes:
            left.append(f"{run.name}/{rel} ({size:,} bytes > {max_bytes:,}{why})")
        else:
            kept.append(rel)
    return kept, left


def _carried_files(run: Path, done: bool, max_bytes: int) -> tuple[list[Path], list[str]]:
    """(files to carry, relative to ``run``; files left out, with why)."""
    top = [f for f in sorted(run.iterdir())
           if f.is_file() and not f.is_symlink() and not f.name.startswith(SKIP_PREFIXES)]
    cached = done and any((run / c).is_file() or packed(run / c).is_file()
                          for c in ABSOLUTE_CACHES) and _budgets_judged(run)
    files = [f.relative_to(run) for f in top if not (cached and f.name in FINAL_ACTOR)]
    logs = [f for f in files if f.name in PACKED_FILES]  # always carried: packed, they are small
    files = [f for f in files if f.name not in PACKED_FILES]
    if done:
        snaps = run / SNAPSHOT_DIR
        if snaps.is_dir():
            newest = sorted(f for f in snaps.glob("ph_*.npz") if f.is_file())[-1:]
            files += [f.relative_to(run) for f in newest]
    marked = run / MARKED_ACTORS_DIR
    if marked.is_dir():
        files += sorted(f.relative_to(run) for f in marked.glob("step_*")  # + JSON sidecars
                        if f.is_file())
    kept, left = _split_by_size(run, files, max_bytes)
    kept = logs + kept
    ckpt = None if done else latest_checkpoint(run)
    if ckpt is not None:
        pair = [ckpt.with_suffix(".json").relative_to(run),
                ckpt.with_suffix(".safetensors").relative_to(run)]
        within, over = _split_by_size(run, pair, max_bytes,
                                      "; the run starts again from scratch elsewhere")
        # Half a checkpoint resumes nothing: carry both halves or neither.
        kept += within if not over else []
        left += over
    return kept, left


def _budgets_judged(run: Path) -> bool:
    """A run that exported actors at marks is judged at several budgets (``budget_marks``),
    its final actor in the deployed mode too: that result must be cached before the final
    actor may stay behind."""
    if not (run / MARKED_ACTORS_DIR).is_dir():
        return True
    cfg = load_yaml(run / "config.yaml", what="run config") \
        if (run / "config.yaml").is_file() else None
    total = (cfg or {}).get("train", {}).get("total_steps")
    return total is not None and (run / MARKED_ACTORS_DIR /
                                  f"step_{int(total)}.deployed.json").is_file()


def _is_packable(rel: Path) -> bool:
    return len(rel.parts) == 1 and rel.name in PACKED_FILES


def _is_packed(rel: Path) -> bool:
    return (len(rel.parts) == 1 and rel.name.endswith(PACKED_SUFFIX)
            and rel.name.removesuffix(PACKED_SUFFIX) in PACKED_FILES)


def _pack(src: Path, dst: Path) -> None:
    with open(src, "rb") as fin, lzma.open(dst, "wb", preset=XZ_PRESET) as fout:
        shutil.copyfileobj(fin, fout, 1 << 20)
    shutil.copystat(src, dst)


def _unpack(src: Path, dst: Path) -> None:
    with lzma.open(src, "rb") as fin, open(dst, "wb") as fout:
        shutil.copyfileobj(fin, fout, 1 << 20)
    shutil.copystat(src, dst)


def _copy_run(src: Path, dst: Path, files: list[Path], mode: str) -> int:
    """Copy ``files`` of run ``src`` into a fresh ``dst`` (built beside it, then renamed, so a
    crash leaves the old copy or the new one, never half of each); ``mode`` "pack" compresses
    the text logs (``PACKED_FILES``), "unpack" restores them. Returns the bytes written."""
    tmp = dst.with_name(dst.name + ".carry-tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    written = 0
    for rel in files:
        (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
        if mode == "pack" and _is_packable(rel):
            out = packed(tmp / rel)
            _pack(src / rel, out)
        elif mode == "unpack" and _is_packed(rel):
            out = tmp / rel.name.removesuffix(PACKED_SUFFIX)
            _unpack(src / rel, out)
        else:
            out = tmp / rel
            shutil.copy2(src / rel, out)
        written += out.stat().st_size
    if dst.exists():
        old = dst.with_name(dst.name + ".carry-old")
        if old.exists():
            shutil.rmtree(old)
        dst.rename(old)
        tmp.rename(dst)
        shutil.rmtree(old)
    else:
        tmp.rename(dst)
    return written


def tree_bytes(root: Path) -> int:
    """Bytes of the regular files under ``root`` (what a checkout of it holds)."""
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file() and not f.is_symlink())


def check_apart(src: Path, dest: Path, src_name: str, dest_name: str) -> None:
    """CarryError when ``dest`` is ``src`` or one holds the other (symlinks resolved): saving a
    log directory into itself replaced every run by its trimmed copy."""
    a, b = src.resolve(), dest.resolve()
    if a == b or a in b.parents or b in a.parents:
        raise CarryError(f"{dest_name} {dest} overlaps {src_name} {src}; allowed: a directory "
                         f"outside it (e.g. carry/<suite>-<budget>)")


def save(logdir: Path, dest: Path, max_file_bytes: int = MAX_FILE_BYTES) -> list[str]:
    """Carry every run of ``logdir`` into ``dest`` (replacing what ``dest`` held for those runs;
    runs only in ``dest`` stay). Returns one line per run and per file left out, and one on
    ``dest`` and, where ``dest`` lies in a ``carry/`` folder, all of it against the budget."""
    lines = []
    check_apart(logdir, dest, "logdir", "dest")
    dest.mkdir(parents=True, exist_ok=True)
    for run in run_dirs(logdir):
        check_name(run.name, f"{run}")  # a path component we may write
        files, left = _carried_files(run, progress(run).done, max_file_bytes)
        size = _copy_run(run, dest / run.name, files, "pack")
        carried = progress(dest / run.name)  # what the next machine gets, read off the copy
        lines.append(f"{run.name}: {carried.describe()}, {len(files)} files, {size / 1e6:.1f} MB")
        lines += [f"  left out: {x}" for x in left]
    # The manifest describes what dest holds now: earlier runs carried from other log
    # directories stay, copies removed since drop out.
    runs = {r.name: progress(r).describe() for r in run_dirs(dest)}
    (dest / MANIFEST).write_text(json.dumps({"runs": runs}, indent=1,
                                            sort_keys=True) + "\n")
    lines.append(f"{dest}: {tree_bytes(dest) / 1e6:.1f} MB")
    if dest.resolve().parent.name == "carry":
        total = tree_bytes(dest.resolve().parent)
        over = " OVER BUDGET: drop finished suites' runs no report reads" \
            if total > BUDGET_BYTES else ""
        lines.append(f"carry/: {total / 1e6:.1f} MB of {BUDGET_BYTES / 1e6:.0f} MB{over}")
    return lines


def restore(src: Path, logdir: Path) -> list[str]:
    """Copy the carried runs of ``src`` into ``logdir`` where they are further along than what
    ``logdir`` holds, the packed logs unpacked (``metrics.csv``, as the trainer writes it and a
    resumed run appends to it). Returns one line per run."""
    lines = []
    check_apart(src, logdir, "src", "logdir")
    logdir.mkdir(parents=True, exist_ok=True)
    for run in run_dirs(src):
        check_name(run.name, f"{run}")  # carried from elsewhere: stays inside logdir
        target = logdir / run.name
        carried = progress(run)
        if target.exists():
            here = progress(target)
            if here.key() >= carried.key():
                lines.append(f"{run.name}: kept the log directory's ({here.describe()}; carried: "
                             f"{carried.describe()})")
                continue
        files = [f.relative_to(run) for f in sorted(run.rglob("*")) if f.is_file()]
        _copy_run(run, target, files, "unpack")
        lines.append(f"{run.name}: restored ({carried.describe()})")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="carry_runs", description=__doc__.split("\n\n")[0] if __doc__ else None)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("save", help="copy a log directory's runs into the repository")
    s.add_argument("logdir", type=Path)
    s.add_argument("dest", type=Path, help="e.g. carry/<suite>-<budget>")
    r = sub.add_parser("restore", help="put carried runs back under a log directory")
    r.add_argument("src", type=Path, help="a directory written by save")
    r.add_argument("logdir", type=Path)
    args = p.parse_args(argv)
    try:
        lines = (save(args.logdir, args.dest) if args.cmd == "save"
                 else restore(args.src, args.logdir))
    except (CarryError, ExperimentError, OSError) as e:
        print(f"carry_runs: {e}", file=sys.stderr)
        return 2
    print("\n".join(lines) if lines else "carry_runs: no runs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
