"""The one YAML loader (sdhn_base.yaml_io) and every reader routed through it: duplicate keys,
alias bombs, binary and oversized files are one line, never a silent winner or a MemoryError."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sdhn_base.yaml_io import MAX_BYTES, YamlError, load_yaml

ROOT = Path(__file__).resolve().parents[2]

BOMB = """\
a: &a [x, x, x, x, x, x, x, x, x, x]
b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]
c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]
d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]
e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]
f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]
g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f, *f]
h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g, *g]
i: &i [*h, *h, *h, *h, *h, *h, *h, *h, *h, *h]
"""


def test_duplicate_key_is_refused_with_both_lines() -> None:
    text = "methods:\n  sdhn: {algo: sdhn}\n  mappo: {algo: mappo}\n  sdhn: {algo: mappo}\n"
    with pytest.raises(YamlError, match=r"suite: duplicate key 'sdhn' at line 4 \(first at "
                                        r"line 2\)"):
        load_yaml(text, what="suite")


def test_duplicate_key_in_flow_mapping_and_nested() -> None:
    with pytest.raises(YamlError, match="duplicate key 'a'"):
        load_yaml("x: [{a: 1, a: 2}]", what="t")


def test_merge_keys_still_override() -> None:
    data = load_yaml("base: &b {a: 1, b: 2}\nrun: {<<: *b, b: 3}\n", what="t")
    assert data["run"] == {"a": 1, "b": 3}


def test_alias_bomb_is_refused_without_expanding(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(BOMB)
    assert bomb.stat().st_size < 600
    with pytest.raises(YamlError, match="aliases expand to more than"):
        load_yaml(bomb, what="suite")


def test_reasonable_aliases_pass() -> None:
    data = load_yaml("a: &a {x: 1}\nb: *a\nc: *a\n", what="t")
    assert data["b"] == data["c"] == {"x": 1}


def test_recursive_alias_is_refused() -> None:
    with pytest.raises(YamlError, match="recursive alias"):
        load_yaml("a: &a [1, *a]\n", what="t")


def test_binary_oversized_missing_and_malformed(tmp_path: Path) -> None:
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(YamlError, match=r"cfg .*bin.yaml: not a text file"):
        load_yaml(binary, what="cfg")
    big = tmp_path / "big.yaml"
    big.write_text("a: " + "x" * MAX_BYTES + "\n")
    with pytest.raises(YamlError, match="larger than"):
        load_yaml(big, what="cfg")
    with pytest.raises(YamlError, match="cannot read"):
        load_yaml(tmp_path / "missing.yaml", what="cfg")
    with pytest.raises(YamlError, match="malformed YAML at line 2"):
        load_yaml("a: [1,\nb: }\n", what="cfg")
    with pytest.raises(YamlError, match=r"nested too deeply|malformed"):
        load_yaml("[" * 100_000, what="cfg")
    assert load_yaml("", what="cfg") is None


@given(st.text(max_size=200))
def test_any_text_is_data_or_one_line_error(text: str) -> None:
    try:
        load_yaml(text, what="fuzz")
    except YamlError as e:
        assert "\n" not in str(e) and str(e).startswith("fuzz")


def test_every_yaml_read_in_src_and_scripts_goes_through_the_loader() -> None:
    """No module calls yaml.safe_load / yaml.load & co. directly: each would lose the
    duplicate-key and alias-bomb checks."""
    offenders = []
    for path in [*ROOT.glob("src/*/*/**/*.py"), *ROOT.glob("scripts/*.py")]:
        if path.name == "yaml_io.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id == "yaml"
                    and re.fullmatch(r"(safe_|full_|unsafe_)?load(_all)?|compose(_all)?",
                                     node.attr)):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} yaml.{node.attr}")
    assert not offenders, offenders


def test_a_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    """Same class as issue 54's FIFO weights_file: every YAML the project reads (launch
    configs, suites, training configs, parameters files) went through an open() that blocks on
    a FIFO until a writer comes."""
    import os
    import threading

    fifo = tmp_path / "config.yaml"
    os.mkfifo(fifo)
    errors: list[str] = []

    def load() -> None:
        try:
            load_yaml(fifo, what="config")
        except YamlError as e:
            errors.append(str(e))

    loader = threading.Thread(target=load, daemon=True)
    loader.start()
    loader.join(20)
    if loader.is_alive():
        with open(fifo, "wb"):  # unblock it so the test process can end
            pass
        pytest.fail("load_yaml blocked on a FIFO")
    assert len(errors) == 1 and "not a regular file" in errors[0], errors
