"""Final per-seed actors restored from git history, verified against a committed manifest.

The protocol suites' actors left the working tree when ``carry/`` was compacted, but their bytes
are still in git: the manifest (``docs/results/robustness/actors.json``) names, per run, the
commit and path of ``actor.safetensors`` and its ``actor.json`` sidecar with the sha256 of each.
``restore`` reads them with ``git cat-file`` into a cache outside the repository and refuses
bytes whose checksum differs from the manifest's.

    entries = load_manifest(Path("docs/results/robustness/actors.json"))
    path = restore(entries[0], repo=Path("."), cache=default_cache())   # .../actor.safetensors
    entries = manifest_from_tree(Path("."), "e97fb25...", ["carry/maif-10-protocol-protocol"])

A clone without that history (a shallow clone) gives one line saying how to fetch it.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sdhn_policy.weights import atomic_write_bytes

FILES = ("actor.safetensors", "actor.json")
RUN_NAME = re.compile(r"^(?P<task>[a-z0-9-]+)__(?P<method>[a-z0-9_]+)__s(?P<seed>\d+)$")


class ActorHistoryError(RuntimeError):
    """An actor cannot be restored: history missing, checksum mismatch, bad manifest."""


@dataclass(frozen=True)
class ActorEntry:
    """One run's final actor in git history."""

    run: str  # the run directory's name, e.g. maif-10__sdhn__s3
    suite: str  # the carried suite, e.g. maif-10-protocol-protocol
    task: str
    method: str
    seed: int
    commit: str  # 40 hex digits: a commit whose tree holds the files
    path: str  # the run directory in that tree
    sha256: dict[str, str]  # file name (FILES) -> sha256 of its bytes

    def key(self) -> str:
        """A name unique across suites (a run name may recur in two suites)."""
        return f"{self.suite}__{self.run}"


def _git(repo: Path, *args: str) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, check=False)


def load_manifest(path: Path) -> list[ActorEntry]:
    """The manifest's entries (ActorHistoryError naming the field when one is malformed)."""
    try:
        data = json.loads(path.read_text())
        rows = data["actors"]
        out = []
        for i, r in enumerate(rows):
            e = ActorEntry(run=str(r["run"]), suite=str(r["suite"]), task=str(r["task"]),
                           method=str(r["method"]), seed=int(r["seed"]),
                           commit=str(r["commit"]), path=str(r["path"]),
                           sha256={str(k): str(v) for k, v in r["sha256"].items()})
            if not re.fullmatch(r"[0-9a-f]{40}", e.commit):
                raise ValueError(f"actors[{i}].commit: {e.commit!r} is not 40 hex digits")
            if set(e.sha256) != set(FILES):
                raise ValueError(f"actors[{i}].sha256: needs exactly {list(FILES)}")
            out.append(e)
    except (OSError, KeyError, TypeError, ValueError) as ex:
        raise ActorHistoryError(f"manifest {path}: {ex}") from ex
    return out


def write_manifest(path: Path, entries: list[ActorEntry], note: str) -> None:
    body = {"note": note, "actors": [asdict(e) for e in entries]}
    atomic_write_bytes(path, (json.dumps(body, indent=1) + "\n").encode())


def _missing_history(e: ActorEntry, repo: Path) -> ActorHistoryError:
    shallow = _git(repo, "rev-parse", "--is-shallow-repository").stdout.strip() == b"true"
    how = ("this clone is shallow: run `git fetch --unshallow`" if shallow
           else f"fetch it: `git fetch origin {e.commit}` (or clone without --depth)")
    return ActorHistoryError(f"{e.key()}: commit {e.commit[:12]} ({e.path}) is not in the git "
                             f"history of {repo}; {how}")


def read_blob(e: ActorEntry, name: str, repo: Path) -> bytes:
    """The bytes of ``name`` in ``e``'s run directory at ``e.commit``, checksum-verified."""
    if _git(repo, "cat-file", "-e", f"{e.commit}^{{commit}}").returncode != 0:
        raise _missing_history(e, repo)
    r = _git(repo, "cat-file", "blob", f"{e.commit}:{e.path}/{name}")
    if r.returncode != 0:
        raise ActorHistoryError(f"{e.key()}: {e.path}/{name} is not in commit {e.commit[:12]}")
    got = hashlib.sha256(r.stdout).hexdigest()
    if got != e.sha256[name]:
        raise ActorHistoryError(f"{e.key()}: {name} at {e.commit[:12]} has sha256 {got[:16]}..., "
                                f"the manifest says {e.sha256[name][:16]}...; refused")
    return r.stdout


def default_cache() -> Path:
    """$XDG_CACHE_HOME/sdhn/actors (outside the repository)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "sdhn" / "actors"


def restore(e: ActorEntry, repo: Path, cache: Path) -> Path:
    """``cache/<key>/actor.safetensors`` (with its sidecar), restored from git unless the cache
    already holds the manifest's bytes. Returns the weights file's path."""
    d = cache / e.key()
    for name in FILES:
        f = d / name
        if f.is_file() and hashlib.sha256(f.read_bytes()).hexdigest() == e.sha256[name]:
            continue
        atomic_write_bytes(f, read_blob(e, name, repo))
    return d / FILES[0]


def manifest_from_tree(repo: Path, commit: str, dirs: list[str]) -> list[ActorEntry]:
    """Entries for every run directory under ``dirs`` at ``commit`` that holds both FILES (run
    names ``task__method__sN``), with the checksums of the bytes in git."""
    full = _git(repo, "rev-parse", "--verify", f"{commit}^{{commit}}")
    if full.returncode != 0:
        raise ActorHistoryError(f"commit {commit!r} is not in the git history of {repo}")
    sha = full.stdout.decode().strip()
    ls = _git(repo, "ls-tree", "-r", "--name-only", sha, "--", *dirs)
    names = set(ls.stdout.decode().splitlines())
    out: list[ActorEntry] = []
    for p in sorted(n for n in names if n.endswith("/" + FILES[0])):
        run_dir = p.rsplit("/", 1)[0]
        if f"{run_dir}/{FILES[1]}" not in names:
            continue
        suite, run = run_dir.split("/")[-2:]
        m = RUN_NAME.match(run)
        if m is None:
            continue
        sums = {}
        for name in FILES:
            blob = _git(repo, "cat-file", "blob", f"{sha}:{run_dir}/{name}").stdout
            sums[name] = hashlib.sha256(blob).hexdigest()
        out.append(ActorEntry(run=run, suite=suite, task=m["task"], method=m["method"],
                              seed=int(m["seed"]), commit=sha, path=run_dir, sha256=sums))
    return out


def entries_json(entries: list[ActorEntry]) -> list[dict[str, Any]]:
    return [asdict(e) for e in entries]
