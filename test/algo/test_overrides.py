"""The one override engine (``sdhn_base.overrides``) used by the trainer config and the launcher."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from sdhn_base.overrides import OverrideError, coerce, set_field


@pytest.mark.parametrize(("text", "want"), [
    ("true", True), ("False", False), ("1", True), ("0", False), ("yes", True), ("no", False),
    ("on", True), ("OFF", False), (True, True), (0, False),
])
def test_booleans(text: object, want: bool) -> None:
    assert coerce("x.flag", bool, text) is want


@pytest.mark.parametrize("bad", ["maybe", "2", 2, 0.5, None])
def test_bad_booleans_name_field_and_allowed(bad: object) -> None:
    with pytest.raises(OverrideError, match=r"x\.flag: .*allowed: true/1/yes/on"):
        coerce("x.flag", bool, bad)


@pytest.mark.parametrize(("value", "want"), [("4", 4), (4.0, 4), ("1e3", 1000), (-3, -3)])
def test_ints(value: object, want: int) -> None:
    assert coerce("n", int, value) == want


@pytest.mark.parametrize("bad", [2.7, "2.7", "inf", float("inf"), "1e400", "nan", True, "two",
                                 None])
def test_ints_refuse_fractions_infinities_and_bools(bad: object) -> None:
    with pytest.raises(OverrideError, match="n: expected int") as err:
        coerce("n", int, bad)
    assert "\n" not in str(err.value)


def test_optional_list_str_float() -> None:
    assert coerce("a", float | None, "null") is None
    assert coerce("a", float | None, "3e-4") == 3e-4
    assert coerce("a", list[int], "[32, 32]") == [32, 32]
    assert coerce("a", list[int], "8,4") == [8, 4]
    assert coerce("a", str, None) == ""
    with pytest.raises(OverrideError, match="a: expected float"):
        coerce("a", float, True)


@dataclass
class Inner:
    rate: float = 0.1
    on: bool = False


@dataclass
class Outer:
    name: str = "x"
    inner: Inner = field(default_factory=Inner)


def test_set_field_nested_and_mapping() -> None:
    o = Outer()
    set_field(o, "inner.rate", "0.5")
    set_field(o, "inner", {"on": "yes"})
    set_field(o, "name", 7)
    assert (o.inner.rate, o.inner.on, o.name) == (0.5, True, "7")


@pytest.mark.parametrize(("path", "value", "match"), [
    ("inner.nope", 1, r"inner\.nope: unknown field; allowed: .*rate, on"),
    ("name.x", 1, r"name: is not a section"),
    ("inner", 3, r"inner: expected a mapping .*allowed: rate, on"),
])
def test_set_field_errors_name_the_field(path: str, value: object, match: str) -> None:
    with pytest.raises(OverrideError, match=match):
        set_field(Outer(), path, value)
