"""Child process for the disk test: write weights files and trainer checkpoints in a loop, as
fast as possible, until killed. ``python disk_writer.py DIR``; prints 'writing' once started."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sdhn_policy.weights import ActorSpec, encode_actor, save_actor_file
from sdhn_train.checkpoint import save_checkpoint


def main() -> None:
    out = Path(sys.argv[1])
    spec = ActorSpec(obs_size=57, num_actions=5, hidden_sizes=(256, 256), gru_hidden=256)
    rng = np.random.default_rng(0)
    tensors = {k: rng.normal(0, 1, s).astype(np.float32) for k, s in spec.tensor_shapes().items()}
    big = {"w": rng.normal(0, 1, (512, 1024)).astype(np.float32)}  # 2 MB checkpoint
    print("writing", flush=True)
    version = 0
    while True:
        version += 1
        save_actor_file(out / "actor.safetensors", encode_actor(spec, tensors, version))
        save_checkpoint(out / "checkpoint", big, {"version": version})


if __name__ == "__main__":
    main()
