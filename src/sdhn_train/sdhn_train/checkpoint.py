"""Checkpoints: one safetensors file (every tensor) + one JSON file (everything else), atomic.

Holds the learner's state (``Learner.state_dict``: networks, optimisers, its NumPy generator,
replay buffer where it has one), torch's and Python's RNG states, and what the trainer adds (the
collector's live state and a snapshot of the environments), so a resumed run continues exactly
like an uninterrupted one. Never pickles.

One naming scheme for the in-process trainer and the ROS trainer node:
``<run_dir>/checkpoints/step_<team env-steps learned from, 12 digits>.{safetensors,json}``; the
JSON is written last, so a checkpoint whose JSON exists is complete (``latest_checkpoint``).
"""

from __future__ import annotations

import json
import random
import re
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.numpy import load as st_load
from safetensors.numpy import save as st_save

from sdhn_base import bounded_json
from sdhn_policy.weights import atomic_write_bytes, sha256_hex
from sdhn_train.learners.base import Arrays, JsonDict, Learner

CHECKPOINT_FORMAT = "sdhn-checkpoint/1"
CHECKPOINT_DIR = "checkpoints"
_STEM = re.compile(r"^step_(\d{12,})$")  # a checkpoint is STEM.json + STEM.safetensors


class CheckpointError(ValueError):
    pass


# --- environment snapshots --------------------------------------------------------------------


def env_snapshot(env: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Snapshot a NumPy environment: ``env.state_dict()`` if it has one, else its NumPy arrays,
    scalars and random generators (attributes of other types are static configuration or
    per-step scratch and are not saved). Returns (arrays, JSON-able values)."""
    if hasattr(env, "state_dict"):
        return dict(env.state_dict()), {}
    arrays: dict[str, np.ndarray] = {}
    values: dict[str, Any] = {}
    for k, v in vars(env).items():
        if isinstance(v, np.ndarray) and v.dtype != object:
            arrays[k] = v
        elif isinstance(v, bool | int | float | str) or v is None:
            values[k] = v
        elif isinstance(v, np.random.Generator):
            values[k] = {"__rng__": v.bit_generator.state}
        elif isinstance(v, list) and v and all(isinstance(g, np.random.Generator) for g in v):
            values[k] = {"__rngs__": [g.bit_generator.state for g in v]}
    return arrays, values


def env_restore(env: Any, arrays: dict[str, np.ndarray], values: dict[str, Any]) -> None:
    if hasattr(env, "load_state_dict"):
        env.load_state_dict(arrays)
        return
    for k, a in arrays.items():
        cur = getattr(env, k)
        if cur.shape != a.shape:
            raise CheckpointError(f"env.{k}: checkpoint shape {a.shape} != env shape {cur.shape}")
        cur[...] = a  # in place: other attributes may be views of this array
    for k, v in values.items():
        if isinstance(v, dict) and "__rng__" in v:
            getattr(env, k).bit_generator.state = v["__rng__"]
        elif isinstance(v, dict) and "__rngs__" in v:
            for g, s in zip(getattr(env, k), v["__rngs__"], strict=True):
                g.bit_generator.state = s
        else:
            setattr(env, k, v)


# --- optimiser state --------------------------------------------------------------------------


def optimizer_to_arrays(prefix: str, opt: torch.optim.Optimizer
                        ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    sd = opt.state_dict()
    arrays: dict[str, np.ndarray] = {}
    scalars: dict[str, Any] = {}
    for pid, st in sd["state"].items():
        for key, val in st.items():
            name = f"{prefix}.{pid}.{key}"
            if isinstance(val, torch.Tensor):
                arrays[name] = val.detach().cpu().numpy().copy()
            else:
                scalars[name] = val
    return arrays, {"param_groups": sd["param_groups"], "scalars": scalars}


def optimizer_from_arrays(prefix: str, opt: torch.optim.Optimizer, arrays: dict[str, np.ndarray],
                          meta: dict[str, Any]) -> None:
    state: dict[int, dict[str, Any]] = {}
    for name, a in arrays.items():
        if name.startswith(prefix + "."):
            pid, key = name[len(prefix) + 1 :].split(".", 1)
            state.setdefault(int(pid), {})[key] = torch.from_numpy(a.copy())
    for name, v in meta["scalars"].items():
        pid, key = name[len(prefix) + 1 :].split(".", 1)
        state.setdefault(int(pid), {})[key] = v
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


# --- files ------------------------------------------------------------------------------------


def save_checkpoint(path: str | Path, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """Write ``<path>.safetensors`` and ``<path>.json`` (tensors file first, JSON last, so a
    checkpoint whose JSON exists is complete)."""
    path = Path(path)
    payload = st_save({k: np.ascontiguousarray(v) for k, v in arrays.items()})
    atomic_write_bytes(path.with_suffix(".safetensors"), payload)
    full = {"format": CHECKPOINT_FORMAT, "tensors_sha256": sha256_hex(payload), **meta}
    atomic_write_bytes(path.with_suffix(".json"), json.dumps(full, indent=1).encode())


def load_checkpoint(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    path = Path(path)
    try:  # bounded: a crafted sidecar (deep nesting) is a CheckpointError, not a crash
        meta = bounded_json.loads(path.with_suffix(".json").read_bytes(), finite=False,
                                  max_int_digits=bounded_json.STATE_FILE_INT_DIGITS)
        payload = path.with_suffix(".safetensors").read_bytes()
    except (OSError, bounded_json.JsonInputError) as e:
        raise CheckpointError(f"cannot read checkpoint {path}: {e}") from e
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path}: metadata is not a JSON object")
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{path}: format {meta.get('format')!r}, expected {CHECKPOINT_FORMAT}")
    if sha256_hex(payload) != meta.get("tensors_sha256"):
        raise CheckpointError(f"{path}: tensors file does not match its sha256")
    try:
        return st_load(payload), meta
    except Exception as e:  # safetensors' own error type: a blob whose sha256 was forged too
        raise CheckpointError(f"{path}: tensors file is not a valid safetensors blob: {e}"
                              ) from e


def module_arrays(prefix: str, module: torch.nn.Module) -> dict[str, np.ndarray]:
    return {f"{prefix}.{k}": v.detach().cpu().numpy().copy()
            for k, v in module.state_dict().items()}


def load_module(prefix: str, module: torch.nn.Module, arrays: dict[str, np.ndarray]) -> None:
    sd = {k[len(prefix) + 1 :]: torch.from_numpy(v.copy()) for k, v in arrays.items()
          if k.startswith(prefix + ".")}
    module.load_state_dict(sd, strict=True)


def modules_state(modules: dict[str, torch.nn.Module],
                  optimizers: dict[str, torch.optim.Optimizer]) -> tuple[Arrays, JsonDict]:
    """Networks (``<prefix>.<parameter>``) and optimisers (``<prefix>.<param id>.<key>``) as
    arrays, with the optimisers' scalars in ``meta["optimizers"]``."""
    arrays: Arrays = {}
    for prefix, module in modules.items():
        arrays.update(module_arrays(prefix, module))
    opt_meta = {}
    for prefix, opt in optimizers.items():
        a, m = optimizer_to_arrays(prefix, opt)
        arrays.update(a)
        opt_meta[prefix] = m
    return arrays, {"optimizers": opt_meta}


def load_modules_state(modules: dict[str, torch.nn.Module],
                       optimizers: dict[str, torch.optim.Optimizer], arrays: Arrays,
                       meta: JsonDict) -> None:
    """Inverse of :func:`modules_state`."""
    for prefix, module in modules.items():
        load_module(prefix, module, arrays)
    for prefix, opt in optimizers.items():
        optimizer_from_arrays(prefix, opt, arrays, meta["optimizers"][prefix])


def learner_state(learner: Learner) -> tuple[Arrays, JsonDict]:
    """The learner's state plus torch's and Python's global RNG states.

    Shared by the in-process trainer and the ROS trainer node, which add their own fields."""
    arrays, meta = learner.state_dict()
    arrays["rng.torch"] = torch.get_rng_state().numpy()
    meta["rng_python"] = list(random.getstate()[1])
    return arrays, meta


def restore_learner_state(learner: Learner, arrays: Arrays, meta: JsonDict) -> None:
    """Inverse of :func:`learner_state`."""
    learner.load_state_dict(arrays, meta)
    torch.set_rng_state(torch.from_numpy(arrays["rng.torch"].copy()))
    random.setstate((3, tuple(meta["rng_python"]), None))


# --- names ------------------------------------------------------------------------------------


def checkpoint_path(run_dir: Path, step: int) -> Path:
    """The checkpoint stem of ``run_dir`` after ``step`` team env-steps."""
    return run_dir / CHECKPOINT_DIR / f"step_{step:012d}"


def checkpoints(run_dir: Path) -> list[Path]:
    """Every complete checkpoint stem under ``run_dir`` (or in it, if it is the checkpoints
    directory itself), oldest first."""
    found = []
    for directory in (run_dir / CHECKPOINT_DIR, run_dir):
        if directory.is_dir():
            for p in directory.iterdir():
                m = _STEM.match(p.stem) if p.suffix == ".json" else None
                if m and p.with_suffix(".safetensors").is_file():
                    found.append((int(m.group(1)), p.with_suffix("")))
        if found:
            break
    return [p for _, p in sorted(found)]


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest complete checkpoint under ``run_dir``, or None."""
    found = checkpoints(run_dir)
    return found[-1] if found else None


def checkpoint_step(stem: Path) -> int:
    """The team step a checkpoint was written at, from its name (``step_<12 digits>``)."""
    m = _STEM.match(stem.name)
    if m is None:
        raise ValueError(f"{stem} is not a checkpoint name (step_<12+ digits>)")
    return int(m.group(1))


def resolve_checkpoint(path: Path) -> Path | None:
    """A checkpoint stem from a stem, a .json/.safetensors file, or a run directory (its newest
    checkpoint; None if it has none)."""
    if path.is_dir():
        return latest_checkpoint(path)
    return path.with_suffix("") if path.suffix in (".json", ".safetensors") else path


def prune_checkpoints(run_dir: Path, keep: int) -> None:
    """Delete all but the newest ``keep`` checkpoints (``log.keep_checkpoints``; 0 keeps all),
    each JSON first: a checkpoint without it is never used."""
    if keep <= 0:
        return
    for old in checkpoints(run_dir)[:-keep]:
        old.with_suffix(".json").unlink(missing_ok=True)
        old.with_suffix(".safetensors").unlink(missing_ok=True)
