"""The README and docs/ state what the code does: the paths they name exist, the defaults their
tables state are the code's defaults, and the README stays a short front door that starts with
the two commands. (Links between pages: `mkdocs build --strict`, run by scripts/test.sh.)"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from sdhn_bringup.launch_config import LaunchConfig
from sdhn_sim.envs.maif import DEFAULT_REWARD, MAIF_REWARDS
from sdhn_sim.envs.maif_instances import MAIF_CONFIGS
from sdhn_train.sections import EnvConfig

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
README_MAX_LINES = 250
README_RESULTS_MAX_LINES = 15
NOTEBOOK = DOCS / "notebook"
REFERENCE = sorted(p for p in DOCS.rglob("*.md")  # the home page lists the notebook, as the nav
                   if NOTEBOOK not in p.parents and p != DOCS / "index.md")
# `scripts/X` or `configs/X` as a path of its own (not the tail of another path such as
# `sdhn_sim/data/...`); placeholders (`<run dir>`) and globs end the match.
REPO_PATH = re.compile(r"(?<![\w./-])((?:scripts|configs)/[\w./-]*)")


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def _table(text: str, header_start: str) -> tuple[list[str], list[list[str]]]:
    """The header cells and the body rows (as cells) of the first Markdown table whose header row
    starts with ``header_start``."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(header_start)), None)
    assert start is not None, f"no table whose header starts with {header_start!r}"
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(_cells(line))
    return _cells(lines[start]), rows


def _number(cell: str) -> float:
    """A table cell such as `-0.075`, `+1.0`, `0.0` (typographic minus allowed) as a float."""
    return float(cell.strip("`* ").replace("−", "-").replace("+", ""))


def _literal(cell: str) -> str:
    return cell.strip().strip("`")


def test_readme_is_a_front_door_starting_with_the_two_commands() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    lines = text.splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines (at most {README_MAX_LINES})")
    first_block = re.search(r"```bash\n(.*?)```", text, re.S)
    assert first_block is not None, "README.md has no bash block"
    commands = [line.split("#")[0].strip() for line in first_block.group(1).splitlines()]
    commands = [c for c in commands if c]
    assert commands == ["./scripts/demo.sh", "./scripts/test.sh"], (
        f"README's first commands are {commands}, not the two scripts")
    assert text.index("```bash") < text.index("\n## "), "the two commands come before any section"
    assert not re.search(r"\bissue \d+", text, re.I), "README.md names an issue number"


def _sections(text: str) -> dict[str, list[str]]:
    """{heading: its lines} of a page's ``## `` sections (code blocks skipped)."""
    out: dict[str, list[str]] = {}
    current = None
    fenced = False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("## "):
            current = line[3:].strip()
            out[current] = []
        elif current is not None:
            out[current].append(line)
    return out


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-")


def test_readme_has_a_table_of_contents_and_a_short_results_part() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    sections = _sections(text)
    first = text.index("\n## ")
    linked = set(re.findall(r"\]\(#([\w-]+)\)", text[:first]))
    missing = [h for h in sections if _anchor(h) not in linked]
    assert not missing, f"README's contents (before the first section) omit {missing}"
    results = [ln for ln in sections.get("Results", []) if ln.strip()]
    assert results, "README.md has no Results section"
    assert len(results) <= README_RESULTS_MAX_LINES, (
        f"README's Results part has {len(results)} lines (at most {README_RESULTS_MAX_LINES}): "
        "the figures belong in docs/results.md")
    assert "docs/results/claims.md" in "\n".join(results), "README's results do not link the claims"


@pytest.mark.parametrize("page", REFERENCE, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_reference_pages_stand_without_the_notebook(page: Path) -> None:
    """Dated entries (run status, what is left, scheduling) live in docs/notebook/; a reference
    page neither links into it nor keeps a to-do or UTC-timed section of its own."""
    text = page.read_text(encoding="utf-8")
    links = [m for m in re.findall(r"\]\(([^)#]+)", text) if "notebook/" in m]
    assert not links, f"{page.name} depends on the notebook: {links}"
    headings = [ln for ln in text.splitlines() if ln.startswith("#")
                and re.search(r"UTC|next session|left for|to ?do", ln, re.I)]
    assert not headings, f"{page.name}: notebook headings in a reference page: {headings}"


NARRATION = re.compile(r"\b(sessions?|this round|in progress|stopped for time|today|yesterday"
                       r"|so far|carried between \w+)\b", re.I)
"""Words that tell how the project's own work went (its sessions, what was running, what is left)
rather than what the code does and what was measured."""


@pytest.mark.parametrize("page", sorted({*PAGES, *REFERENCE}),
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_reference_pages_do_not_narrate_the_work(page: Path) -> None:
    """The README, the reference pages and the committed reports say what the code does and what
    was measured (machine, date, load); how the runs went, session by session, is the notebook's
    (docs/notebook/)."""
    found = [f"{i}: {m.group(0)!r}" for i, line in enumerate(page.read_text().splitlines(), 1)
             for m in NARRATION.finditer(line)]
    assert not found, f"{page.name} narrates the work (move it to docs/notebook/): {found}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_named_scripts_and_configs_exist(page: Path) -> None:
    text = page.read_text(encoding="utf-8")
    missing = sorted({m.rstrip(".") for m in REPO_PATH.findall(text)
                      if not (ROOT / m.rstrip(".")).exists()})
    assert not missing, f"{page.name} names paths that do not exist: {missing}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_issue_numbers_in_headings(page: Path) -> None:
    headings = [line for line in page.read_text(encoding="utf-8").splitlines()
                if line.startswith("#") and re.search(r"\bissue \d+", line, re.I)]
    assert not headings, f"{page.name}: headings name issue numbers: {headings}"


def test_maif_reward_table_is_the_code() -> None:
    """docs/maif.md's reward table: one row per MaifRewards field, both named sets, and the
    environment's and the training config's default named as the code has it."""
    text = (DOCS / "maif.md").read_text(encoding="utf-8")
    header, rows = _table(text, "| term | field |")
    by_field = {_literal(r[1]): r for r in rows}
    fields = {f.name for f in dataclasses.fields(MAIF_REWARDS["reference"])} - {"name"}
    assert set(by_field) == fields, f"table: {sorted(by_field)}, MaifRewards: {sorted(fields)}"
    columns = header[2:]
    names = [_literal(c.split()[0]) for c in columns]
    assert sorted(names) == sorted(MAIF_REWARDS), f"columns {names} != {sorted(MAIF_REWARDS)}"
    for field_name, row in by_field.items():
        for name, cell in zip(names, row[2:], strict=True):
            want = getattr(MAIF_REWARDS[name], field_name)
            assert _number(cell) == pytest.approx(want), (
                f"maif.md: {field_name} under {name} is {cell}, the code has {want}")
    default_column = next(c for c in columns if "default" in c)
    assert _literal(default_column.split()[0]) == DEFAULT_REWARD == EnvConfig().reward
    assert f"**`{DEFAULT_REWARD}`**" in text


def test_maif_configuration_table_is_the_code() -> None:
    _, rows = _table((DOCS / "maif.md").read_text(encoding="utf-8"), "| name | robots N |")
    documented = {r[0]: (int(r[1]), int(r[2]), int(r[3])) for r in rows}
    code = {name: (c.num_robots, c.size, c.fs) for name, c in MAIF_CONFIGS.items()}
    assert documented == code


def test_launcher_config_table_defaults_are_the_code() -> None:
    """docs/running-the-stack.md: every plain default in the launcher's config table (a number,
    a word, true/false) equals LaunchConfig's; descriptive ones (`runs/<mode>-...`) are skipped."""
    _, rows = _table((DOCS / "running-the-stack.md").read_text(encoding="utf-8"),
                     "| config field | default |")
    defaults = {f.name: f.default for f in dataclasses.fields(LaunchConfig)
                if f.default is not dataclasses.MISSING}
    checked = 0
    for row in rows:
        names = [_literal(n) for n in row[0].split(",")]
        values = [_literal(v) for v in row[1].split(",")] if row[1] else []
        assert all(n in {f.name for f in dataclasses.fields(LaunchConfig)} for n in names), (
            f"running-the-stack.md documents unknown launcher fields: {names}")
        if len(values) != len(names):
            continue
        for name, value in zip(names, values, strict=True):
            if name not in defaults or not re.fullmatch(r"[\w./-]*", value):
                continue
            want = defaults[name]
            if isinstance(want, bool):
                assert value == str(want).lower(), f"{name}: docs {value}, code {want}"
            elif isinstance(want, (int, float)):
                assert float(value) == want, f"{name}: docs {value}, code {want}"
            else:
                assert value == want, f"{name}: docs {value!r}, code {want!r}"
            checked += 1
    assert checked >= 10, f"only {checked} launcher defaults could be checked"
