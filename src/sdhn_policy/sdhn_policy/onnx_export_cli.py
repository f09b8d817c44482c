"""Write ``actor.onnx``, its I/O contract ``actor.onnx.json`` and, for a model folder with a
``card.json``, ``deploy.json`` (observation layout, deployment mode, stall rule:
sdhn_policy.deploy_contract) next to an actor's weights.

    .venv/bin/python scripts/export_onnx.py models/maif-10-sdhn          # a model folder
    .venv/bin/python scripts/export_onnx.py runs/x/actor.safetensors     # or a weights file

The graph is built from the weights (no torch), checked by ``onnx.checker``, and verified before
it is kept: onnxruntime must give the NumPy runtime's logits to 1e-5 on observations of the
actor's environment. Exit codes: 0 written, 2 bad input (one line).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_contract import write_deploy_json
from sdhn_policy.onnx_export import write_onnx
from sdhn_policy.onnx_runtime import OnnxActorRuntime
from sdhn_policy.weights import WeightsError, decode_weights, load_actor_file

TOLERANCE = 1e-5


def _family(obs_size: int, features: str) -> str:
    return "maif" if features.startswith("maif") or obs_size == 57 else "rware"


def export(weights: Path) -> Path:
    blob = load_actor_file(weights)
    spec, tensors = decode_weights(blob)
    out = write_onnx(weights.with_name("actor.onnx"), spec, tensors,
                     _family(spec.obs_size, spec.features), version=blob.version)
    rt_np, rt_onnx = ActorRuntime.from_weights(blob), OnnxActorRuntime.from_onnx_file(out)
    obs = np.random.default_rng(0).uniform(0, 2, size=(64, spec.obs_size)).astype(np.float32)
    ids = np.arange(64) % spec.num_robots if spec.use_robot_id else None
    got = rt_onnx.step(obs, rt_onnx.initial_state(64), ids)[0]
    want = rt_np.step(obs, rt_np.initial_state(64), ids)[0]
    err = float(np.abs(got - want).max())
    if err > TOLERANCE:
        out.unlink()
        raise WeightsError(f"onnxruntime differs from the NumPy runtime by {err:.2e}")
    if (weights.parent / "card.json").exists():
        write_deploy_json(weights.parent, spec, _family(spec.obs_size, spec.features))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("paths", nargs="+", type=Path, help="model folders or actor .safetensors files")
    args = ap.parse_args(argv)
    for path in args.paths:
        weights = path / "actor.safetensors" if path.is_dir() else path
        try:
            out = export(weights)
        except (OSError, WeightsError, ValueError) as e:
            print(f"export_onnx: {weights}: {e}", file=sys.stderr)
            return 2
        print(f"wrote {out} and {out.name}.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
