"""Clean up what killed processes of ours leave behind, only where the owner is provably gone.

- Fast DDS shared-memory segments in ``/dev/shm`` (``fastrtps_<id>`` with its ``fastrtps_<id>_el``
  lock file, ~0.5 MB each): a live participant holds an exclusive ``flock`` on the ``_el`` file
  for as long as it runs, so a lock we can take means its owner is dead. The shared port files
  (``fastrtps_port*``) are never touched, nor anything younger than ``MIN_AGE_S``.
- Temporary files of atomic writes (``.<name>.<pid>.<random>.tmp``, see
  ``sdhn_policy.weights.atomic_write_bytes``): removed when process ``pid`` no longer exists.

Stdlib only; every function is safe to call from several processes at once.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import time
from pathlib import Path

SHM = Path("/dev/shm")
MIN_AGE_S = 10.0  # never judge a file a starting process may still be setting up
_SEGMENT_LOCK = re.compile(r"^fastrtps_([0-9a-f]{16})_el$")
_TMP = re.compile(r"^\..+\.(\d+)\.[^.]+\.tmp$")


def _old(path: Path, now: float) -> bool:
    try:
        return now - path.stat().st_mtime >= MIN_AGE_S
    except OSError:
        return False


def clean_fastdds_shm(shm: Path = SHM) -> int:
    """Remove the Fast DDS segments whose owner process is gone; returns how many."""
    removed = 0
    now = time.time()
    try:
        names = os.listdir(shm)
    except OSError:
        return 0
    for name in names:
        m = _SEGMENT_LOCK.match(name)
        if m is None or not _old(shm / name, now):
            continue
        try:
            fd = os.open(shm / name, os.O_RDWR)
        except OSError:
            continue  # not ours (permissions) or already gone
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                continue  # held: its participant is alive
            with contextlib.suppress(FileNotFoundError):
                (shm / f"fastrtps_{m.group(1)}").unlink()
                removed += 1
            with contextlib.suppress(FileNotFoundError):
                (shm / name).unlink()
        finally:
            os.close(fd)
    return removed


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_tmp(directory: Path) -> int:
    """Remove ``.<name>.<pid>.<random>.tmp`` files in ``directory`` whose writer is gone."""
    removed = 0
    try:
        names = os.listdir(directory)
    except OSError:
        return 0
    for name in names:
        m = _TMP.match(name)
        if m is None or int(m.group(1)) == os.getpid() or pid_alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            (directory / name).unlink()
            removed += 1
    return removed
