"""The packages stack in one direction: sdhn_sim (envs, simulator, recording) at the bottom, then
sdhn_policy (the actor), sdhn_train (training), and sdhn_bringup (the launcher) on top. A module
may import only its own package and the ones below it, so a newcomer can read the house floor by
floor and the actor process never pulls in the trainer."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
FLOORS = ("sdhn_sim", "sdhn_policy", "sdhn_train", "sdhn_bringup")


def _imported_packages(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", FLOORS)
def test_a_package_imports_only_itself_and_the_packages_below(package: str) -> None:
    above = set(FLOORS[FLOORS.index(package) + 1:])
    files = sorted((SRC / package / package).rglob("*.py"))
    assert files, f"no modules found for {package}"
    upward = {str(f.relative_to(SRC)): sorted(_imported_packages(f) & above) for f in files}
    assert not {f: p for f, p in upward.items() if p}, "imports that run up a floor"
