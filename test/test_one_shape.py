"""One shape per concept: a second definition or reader of the same thing fails here.

- ``ConfigError`` is defined once (``sdhn_base.errors``); narrower configuration errors
  subclass it.
- ``metrics.csv`` is read and written by ``sdhn_train.metrics_file`` only: any other module that
  mentions the file and parses CSV is a second reader.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted([*(ROOT / "src").rglob("*.py"), *(ROOT / "scripts").glob("*.py")])


def _classes(path: Path) -> list[ast.ClassDef]:
    return [n for n in ast.walk(ast.parse(path.read_text(), str(path)))
            if isinstance(n, ast.ClassDef)]


def _base_names(cls: ast.ClassDef) -> set[str]:
    return {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in cls.bases}


def test_config_error_is_defined_once_and_config_errors_derive_from_it() -> None:
    defined = [str(p.relative_to(ROOT)) for p in SOURCES for c in _classes(p)
               if c.name == "ConfigError"]
    assert defined == ["src/sdhn_base/sdhn_base/errors.py"], defined
    strays = [f"{p.relative_to(ROOT)}:{c.name}" for p in SOURCES for c in _classes(p)
              if c.name.endswith("ConfigError") and c.name != "ConfigError"
              and "ConfigError" not in _base_names(c)]
    assert not strays, f"configuration errors that do not derive from ConfigError: {strays}"


def _parses_csv(tree: ast.AST) -> bool:
    return any(isinstance(n, ast.Attribute) and n.attr in ("reader", "DictReader")
               and isinstance(n.value, ast.Name) and n.value.id == "csv" for n in ast.walk(tree))


def _names_metrics_csv(tree: ast.AST) -> bool:
    """The file name as a value in code (docstrings that mention it do not count)."""
    return any(isinstance(n, ast.Constant) and n.value == "metrics.csv" for n in ast.walk(tree))


def test_metrics_csv_has_one_reader_beside_its_writer() -> None:
    readers = []
    for path in SOURCES:
        tree = ast.parse(path.read_text(), str(path))
        if _names_metrics_csv(tree) and _parses_csv(tree):
            readers.append(str(path.relative_to(ROOT)))
    assert readers == ["src/sdhn_train/sdhn_train/metrics_file.py"], (
        f"metrics.csv parsed outside sdhn_train.metrics_file: {readers}")


def test_nodes_declare_parameters_through_the_one_helper() -> None:
    """Every node declares through ``sdhn_base.ros.params.declare`` (typed descriptors, one-line
    errors); a node calling rclpy's ``declare_parameter`` itself is a second way."""
    helper = ROOT / "src" / "sdhn_base" / "sdhn_base" / "ros" / "params.py"
    direct = [str(p.relative_to(ROOT)) for p in SOURCES if p != helper
              for n in ast.walk(ast.parse(p.read_text(), str(p)))
              if isinstance(n, ast.Attribute) and n.attr in ("declare_parameter",
                                                               "declare_parameters")]
    assert not direct, f"parameters declared outside sdhn_base.ros.params: {sorted(set(direct))}"


def test_simulator_settings_are_defined_once() -> None:
    """The simulator node's parameters are SimConfig's fields (help, range, default) plus what
    only the node has; a parameter written by hand beside them is a second definition."""
    import dataclasses

    from sdhn_sim.lockstep import SimConfig
    from sdhn_sim.sim_node import NODE_ONLY, PARAMETERS

    fields = {f.name: f for f in dataclasses.fields(SimConfig)}
    assert set(PARAMETERS) == set(fields) | set(NODE_ONLY), sorted(set(PARAMETERS) ^ set(fields))
    defaults = SimConfig()
    for name, f in fields.items():
        default, descriptor = PARAMETERS[name]
        assert descriptor.description == f.metadata["help"], name
        text = f.metadata["text_default"]
        assert default == (text if text is not None else getattr(defaults, name)), name
