"""Write requirements.lock from the current venv: every installed distribution, exact versions.

Why not ``pip freeze``: the ROS 2 wheels carry ``*.egg-info`` folders of their original colcon
builds (``rclpy``, ``action_msgs`` ...), which pip freeze lists as packages that no index serves.
Only real ``*.dist-info`` installs are locked; our own editable packages are left out.
"""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

HEADER = """\
# Exact versions of everything in the venv; scripts/setup.sh installs from this file.
# torch==2.13.0 is the CPU build (a newer or unpinned torch pulls GBs of CUDA wheels).
# Regenerate after a deliberate change: .venv/bin/python scripts/freeze_lock.py
"""
SKIP = {"pip", "sdhn-sim", "sdhn-policy", "sdhn-train", "sdhn-msgs"}


def main() -> int:
    pins: dict[str, str] = {}
    for dist in metadata.distributions():
        path = getattr(dist, "_path", None)
        if path is None or not str(path).endswith(".dist-info"):
            continue
        name = dist.metadata["Name"].lower().replace("_", "-")
        if name in SKIP or "editable" in (dist.read_text("direct_url.json") or ""):
            continue
        pins[name] = dist.version.split("+", 1)[0]  # '2.13.0+cpu' -> '2.13.0'
    lock = Path(__file__).resolve().parents[1] / "requirements.lock"
    lock.write_text(HEADER + "".join(f"{n}=={v}\n" for n, v in sorted(pins.items())))
    print(f"wrote {len(pins)} pins to {lock}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
