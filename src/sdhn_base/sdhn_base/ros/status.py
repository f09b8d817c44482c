"""What a node tells its supervisor, as files (never log text): readiness and simulator events.

- Ready file: when the environment variable ``SDHN_READY_FILE`` names a path, the node runner
  writes it (one JSON object: node, namespace, pid, time) once the node is built and about to
  spin. The launcher deletes it before (re)starting a child and counts the child ready when it
  exists.
- Events file: the simulator's ``events_file`` parameter names a JSON-lines file it appends to:
  ``{"event": "started"}`` when every actor matched, ``{"event": "progress", "episode", "step",
  "steps_per_s", "missed"}`` every few seconds, ``{"event": "episode", ...}`` with every field of
  :class:`sdhn_sim.lockstep.EpisodeResult` per finished episode, ``{"event": "done", ...}``,
  and ``{"event": "stopped", "steps", "missed", "drops"}`` when it stops, however (its totals).
  :class:`EventReader` reads what was appended since its last call.
- Status file: a node with counters the launcher shows (the trainer: transitions, drops per
  cause) rewrites ``<name>.status.json`` next to its ready file (:func:`write_status`, atomic);
  the launcher reads every ``*.status.json`` of the status directory (:func:`read_statuses`).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

from sdhn_base import bounded_json

READY_ENV = "SDHN_READY_FILE"


def write_ready(node_name: str, namespace: str) -> Path | None:
    """Write the ready file named by ``$SDHN_READY_FILE`` (atomically); None when unset."""
    target = os.environ.get(READY_ENV, "")
    if not target:
        return None
    path = Path(target)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"node": node_name, "namespace": namespace, "pid": os.getpid(),
                               "time": time.time()}) + "\n")
    tmp.replace(path)
    return path


STATUS_SUFFIX = ".status.json"


def write_status(node_name: str, fields: dict[str, Any]) -> Path | None:
    """Rewrite ``<status dir>/<node_name>.status.json`` (the directory of ``$SDHN_READY_FILE``)
    atomically; None when the node runs without a supervisor."""
    target = os.environ.get(READY_ENV, "")
    if not target:
        return None
    path = Path(target).with_name(node_name + STATUS_SUFFIX)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps({"node": node_name, "time": time.time(), **fields}) + "\n")
    tmp.replace(path)
    return path


def read_statuses(status_dir: Path) -> dict[str, dict[str, Any]]:
    """Every node's last status, by node name (unreadable or half-written files are skipped)."""
    out: dict[str, dict[str, Any]] = {}
    for path in sorted(status_dir.glob("*" + STATUS_SUFFIX)):
        try:
            obj = bounded_json.loads(path.read_bytes(), finite=False,
                                      max_int_digits=bounded_json.STATE_FILE_INT_DIGITS)
        except (OSError, ValueError):
            continue
        if isinstance(obj, dict):
            out[path.name.removesuffix(STATUS_SUFFIX)] = obj
    return out


class EventWriter:
    """Appends one JSON object per line; a no-op without a path."""

    def __init__(self, path: str) -> None:
        self.path = Path(path) if path else None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)

    def write(self, event: str, **fields: Any) -> None:
        if self.path is None:
            return
        with self.path.open("a") as f:
            f.write(json.dumps({"event": event, "time": time.time(), **fields}) + "\n")


class EventReader:
    """Reads the complete lines appended to an events file since the last call."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._offset = 0

    def new(self) -> list[dict[str, Any]]:
        try:
            with self.path.open("rb") as f:
                f.seek(self._offset)
                data = f.read()
        except OSError:
            return []
        cut = data.rfind(b"\n") + 1
        self._offset += cut
        events = []
        for line in data[:cut].splitlines():
            try:
                obj = bounded_json.loads(
                    line, finite=False, max_int_digits=bounded_json.STATE_FILE_INT_DIGITS)
            except ValueError:
                continue  # never written by our writer; skip rather than stop the supervisor
            if isinstance(obj, dict) and isinstance(obj.get("event"), str):
                events.append(obj)
        return events
