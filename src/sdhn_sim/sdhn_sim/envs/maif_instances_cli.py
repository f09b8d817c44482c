"""Write the shipped MAIF instance sets to src/sdhn_sim/sdhn_sim/data/<name>.npz.

Deterministic: each set comes from its configuration's ``instance_seed``, so re-running this
rewrites identical arrays. maif-30/maif-40 are not shipped; the envs generate them on demand
with the same function.

    PYTHONPATH=src/sdhn_sim python scripts/make_maif_instances.py [--check]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from sdhn_sim.envs.maif_instances import (
    MAIF_CONFIGS,
    SHIPPED,
    data_path,
    generate_instances,
    save_instances,
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="verify the files instead of writing")
    ap.add_argument("names", nargs="*", default=list(SHIPPED), help=f"default: {list(SHIPPED)}")
    args = ap.parse_args(argv)
    bad = 0
    for name in args.names:
        cfg = MAIF_CONFIGS[name]
        t0 = time.perf_counter()
        inst = generate_instances(cfg)
        path = data_path(name)
        if args.check:
            from sdhn_sim.envs.maif_instances import _load_file

            stored = _load_file(cfg, path)
            same = all(
                np.array_equal(getattr(inst, f), getattr(stored, f))
                for f in ("obstacles", "starts", "goals")
            )
            bad += not same
            print(f"{name}: {'ok' if same else 'DIFFERS'}")
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        save_instances(inst, path)
        print(
            f"{name}: {inst.num_instances} instances, {cfg.num_robots} robots, "
            f"{cfg.size}x{cfg.size}, fs {cfg.fs} -> {path} "
            f"({path.stat().st_size} B, {time.perf_counter() - t0:.2f} s)"
        )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
