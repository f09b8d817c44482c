#!/usr/bin/env python3
"""Install the environments alone (``src/sdhn_sim``, no ROS, no torch) into a fresh virtualenv,
as a user of PettingZoo or Gymnasium would, and check that they work there.

    .venv/bin/python scripts/check_env_install.py            # a temporary venv, removed after
    .venv/bin/python scripts/check_env_install.py --keep DIR  # the venv in DIR, kept

Steps, each timed: ``python -m venv``; ``pip install --no-deps ./src/sdhn_sim`` with NumPy,
PettingZoo, Gymnasium and their three small dependencies at the versions of
``requirements.lock`` (pip takes them from its cache when it has them); then, in the new venv,
import ``sdhn_sim.envs.pettingzoo_env``, run PettingZoo's ``parallel_api_test`` on maif-tiny, one
maif-10 episode from the held-out set and ``gymnasium.make("sdhn/rware-tiny-2ag-v0")``. Prints
one line per step with its seconds and a last line of JSON (the installed version, the modules
of rclpy/torch/mcap/yaml that got imported: none). Exit code 0 when everything worked.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("numpy", "pettingzoo", "gymnasium", "cloudpickle", "typing-extensions",
            "farama-notifications")  # the environments' whole dependency tree
CHECK = """
import importlib.metadata as md, json, sys
from sdhn_sim.envs.pettingzoo_env import parallel_env, register_gymnasium_envs
from pettingzoo.test import parallel_api_test
import gymnasium
parallel_api_test(parallel_env("maif-tiny", max_steps=20), num_cycles=30)
env = parallel_env("maif-10", seed=0, instance_set="heldout_large")
env.reset(seed=1)
while env.agents:
    _o, _r, _t, _tr, infos = env.step({a: 0 for a in env.agents})
register_gymnasium_envs()
obs, _ = gymnasium.make("sdhn/rware-tiny-2ag-v0").reset(seed=0)
print(json.dumps({"version": md.version("sdhn_sim"),
                  "episode": infos["robot_0"]["episode"],
                  "rware_obs_shape": list(obs.shape),
                  "heavy_modules": sorted({m.split(".")[0] for m in sys.modules} &
                                          {"rclpy", "torch", "mcap", "yaml", "sdhn_msgs"})}))
"""


def pins(lock: Path) -> list[str]:
    """``name==version`` of PACKAGES as requirements.lock pins them."""
    pinned = {}
    for line in lock.read_text().splitlines():
        name, sep, version = line.strip().partition("==")
        if sep:
            pinned[name.lower()] = version
    missing = [p for p in PACKAGES if p not in pinned]
    if missing:
        raise SystemExit(f"check_env_install: {lock} pins no {', '.join(missing)}")
    return [f"{p}=={pinned[p]}" for p in PACKAGES]


def timed(label: str, cmd: list[str]) -> tuple[float, str]:
    start = time.monotonic()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=ROOT)
    seconds = time.monotonic() - start
    if done.returncode != 0:
        raise SystemExit(f"check_env_install: {label} failed ({done.returncode}):\n"
                         f"{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    print(f"{label}: {seconds:.1f} s", flush=True)
    return seconds, done.stdout


def run(venv: Path) -> dict[str, object]:
    base = getattr(sys, "_base_executable", sys.executable)  # not the project venv's python
    t_venv, _ = timed("python -m venv", [base, "-m", "venv", str(venv)])
    py = str(venv / "bin" / "python")
    # pip builds a local folder in place (setuptools' build/ beside setup.py): build a copy, so
    # the working tree is left as it was
    source = venv.parent / "sdhn_sim-src"
    shutil.copytree(ROOT / "src" / "sdhn_sim", source,
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    t_pip, _ = timed("pip install --no-deps ./src/sdhn_sim + pinned deps",
                     [py, "-m", "pip", "install", "-q", "--disable-pip-version-check",
                      "--no-deps", str(source), *pins(ROOT / "requirements.lock")])
    t_check, out = timed("import and check", [py, "-c", CHECK])
    result: dict[str, object] = json.loads(out.strip().splitlines()[-1])
    result["seconds"] = {"venv": round(t_venv, 1), "pip": round(t_pip, 1),
                         "check": round(t_check, 1), "total": round(t_venv + t_pip + t_check, 1)}
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, default=None, help="create the venv here and keep it")
    args = ap.parse_args(argv)
    if args.keep is not None:
        result = run(args.keep)
    else:
        with tempfile.TemporaryDirectory(prefix="sdhn-env-install-") as tmp:
            result = run(Path(tmp) / "venv")
    print(json.dumps(result))
    return 0 if not result["heavy_modules"] else 1


if __name__ == "__main__":
    sys.exit(main())
