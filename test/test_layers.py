"""The house's floors, one idea held two ways.

1. The packages stack in one direction: sdhn_base (shared utilities and ROS plumbing) at the
   bottom, then sdhn_sim (environments, simulator, recording, viz), sdhn_policy (the actor),
   sdhn_train (training), sdhn_experiments (suites, evaluation, reports) and sdhn_bringup (the
   launcher) on top. A module may import only its own package and the ones below it, so a
   newcomer reads the house floor by floor and the actor process never pulls in the trainer.
2. The cores (environments, the lock-step core, the actor's NumPy runtime, the trainer) import
   neither rclpy nor ROS messages, so they train and evaluate without a ROS install; only node
   files, recording code and ``sdhn_base.ros`` do.
3. No two modules import each other, directly or round a longer circle (an import inside a
   function counts too): a circle means neither can be read, tested or moved without the other,
   and what they share belongs in a third module both import.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
FLOORS = ("sdhn_base", "sdhn_sim", "sdhn_policy", "sdhn_train", "sdhn_experiments",
          "sdhn_bringup")
CORE = ["sdhn_sim.envs", "sdhn_sim.lockstep", "sdhn_base.drops", "sdhn_policy.actor_core",
        "sdhn_policy.actor_runtime", "sdhn_train.trainer", "sdhn_train.transitions",
        "sdhn_train.cli", "sdhn_experiments.experiments"]
ROS_PACKAGES = ("rclpy", "sdhn_msgs", "lifecycle_msgs", "diagnostic_msgs")


def _imported_packages(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_every_python_package_under_src_is_a_floor() -> None:
    found = {p.parent.name for p in SRC.glob("*/setup.py")}
    assert found == set(FLOORS), f"packages under src/ {sorted(found)} vs floors {FLOORS}"


@pytest.mark.parametrize("package", FLOORS)
def test_a_package_imports_only_itself_and_the_packages_below(package: str) -> None:
    above = set(FLOORS[FLOORS.index(package) + 1:])
    files = sorted((SRC / package / package).rglob("*.py"))
    assert files, f"no modules found for {package}"
    upward = {str(f.relative_to(SRC)): sorted(_imported_packages(f) & above) for f in files}
    assert not {f: p for f, p in upward.items() if p}, "imports that run up a floor"


def test_core_modules_import_no_ros() -> None:
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE)
            + f"print(sorted(m for m in sys.modules if m.split('.')[0] in {ROS_PACKAGES!r}))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout


def _modules() -> dict[str, Path]:
    """Every module of our packages by dotted name (a package by its ``__init__``)."""
    found: dict[str, Path] = {}
    for package in FLOORS:
        for path in (SRC / package / package).rglob("*.py"):
            parts = path.relative_to(SRC / package).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of ours that ``path`` imports (``from a.b import c`` is a.b.c when c is a
    module, else a.b), at any depth of the file."""
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names += [f"{node.module}.{a.name}" for a in node.names]
    found = set()
    for name in names:
        known = name
        while known and known not in modules:
            known = known.rpartition(".")[0]
        if known:
            found.add(known)
    return found


def _circles(graph: dict[str, set[str]]) -> Iterator[list[str]]:
    """The strongly connected groups of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    for start, edges_out in graph.items():
        if start in index:
            continue
        work = [(start, iter(sorted(edges_out)))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, edges = work[-1]
            w = next(edges, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                group = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    group.append(w)
                    if w == v:
                        break
                if len(group) > 1:
                    yield sorted(group)


def test_no_import_circles() -> None:
    modules = _modules()
    graph = {m: _imports(p, modules) - {m} for m, p in modules.items()}
    circles = list(_circles(graph))
    assert not circles, f"modules that import each other (move what they share): {circles}"


def test_the_circle_finder_finds_a_circle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert list(_circles(graph)) == [["a", "b", "c"]]
