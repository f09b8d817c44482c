"""scripts/ holds thin wrappers; the logic lives in the packages, where tests import it.

1. Every ``scripts/*.py`` is a docstring, imports and ``sys.exit(main())`` under
   ``if __name__ == "__main__"``, with ``main`` imported from a module of one of our packages:
   a function, a class or a module-level assignment in a script is logic that a newcomer would
   look for in a package (and that a test could only load by path). The few scripts that are
   not wrappers say why below.
2. No test loads a file by path (``importlib``'s ``spec_from_file_location``, ``runpy``,
   ``SourceFileLoader``): tests import package modules, and run a script as a subprocess when
   its command line is what they test.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "scripts").glob("*.py"))
PACKAGES = ("sdhn_base", "sdhn_sim", "sdhn_policy", "sdhn_train", "sdhn_experiments",
            "sdhn_bringup")

NOT_WRAPPERS = {
    "example_pettingzoo_ppo.py": "a self-contained example of training through PettingZoo alone "
                                 "(the docs show it; it imports nothing of sdhn but the env)",
    "example_torchrl_mappo.py": "a self-contained TorchRL example, likewise",
    "freeze_lock.py": "maintains requirements.lock in the checkout, before any package matters",
    "check_env_install.py": "builds a fresh virtualenv from src/sdhn_sim to check the "
                            "environments install alone; it acts on the checkout, not a package",
}
"""Scripts that are not wrappers, and why."""

LOADS_BY_PATH = {"spec_from_file_location", "run_path", "SourceFileLoader",
                 "load_source"}
MAY_LOAD_BY_PATH = {
    "test_onnx_reference.py": "examples/onnx_reference/run_policy.py is a standalone example "
                              "that no package installs, on purpose (a port's reference)",
}
"""Tests that load a file by path, and why (never a script of scripts/)."""


def _main_import(tree: ast.Module) -> str | None:
    """The module ``main`` is imported from, when the script is nothing but a wrapper."""
    source = None
    for i, node in enumerate(tree.body):
        if i == 0 and isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue  # the docstring
        if isinstance(node, ast.Import):
            continue
        if isinstance(node, ast.ImportFrom):
            if any(a.name == "main" for a in node.names):
                source = node.module
            continue
        if (isinstance(node, ast.If) and isinstance(node.test, ast.Compare)
                and isinstance(node.test.left, ast.Name) and node.test.left.id == "__name__"):
            continue
        return None  # a def, a class, an assignment, a statement: logic
    return source


@pytest.mark.parametrize("script", [p for p in SCRIPTS if p.name not in NOT_WRAPPERS],
                         ids=lambda p: p.name)
def test_a_script_only_calls_a_packages_main(script: Path) -> None:
    tree = ast.parse(script.read_text(), str(script))
    source = _main_import(tree)
    assert source is not None, (
        f"{script.name} holds logic (a def, class or assignment): move it into a package module "
        "and import its main")
    assert source.split(".")[0] in PACKAGES, f"{script.name} imports main from {source}"
    assert callable(getattr(importlib.import_module(source), "main", None)), source
    guard = tree.body[-1]
    assert isinstance(guard, ast.If) and "main()" in ast.unparse(guard), (
        f"{script.name} does not end in `if __name__ == '__main__': sys.exit(main())`")


def test_the_scripts_that_are_not_wrappers_exist() -> None:
    names = {p.name for p in SCRIPTS}
    assert set(NOT_WRAPPERS) <= names, sorted(set(NOT_WRAPPERS) - names)


def test_no_test_loads_a_file_by_path() -> None:
    found = []
    for path in sorted((ROOT / "test").rglob("*.py")):
        if path.name in MAY_LOAD_BY_PATH or path == Path(__file__).resolve():
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            name = node.attr if isinstance(node, ast.Attribute) else (
                node.id if isinstance(node, ast.Name) else None)
            if name in LOADS_BY_PATH:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, f"tests that load a file by path (import the package module): {found}"
