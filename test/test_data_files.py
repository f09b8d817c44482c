"""The one packaged-data rule: every data file the code references is found through
``sdhn_sim.data_files`` (importlib.resources), exists in the installed package, is listed in the
package's package data (so a wheel or colcon install carries it), and no module walks ``__file__``
to find data. The launcher hands its children a Fast DDS profile that exists."""

from __future__ import annotations

import ast
import fnmatch
import io
from pathlib import Path

import pytest

from sdhn_bringup.launch_load import load_config
from sdhn_bringup.supervisor import Launcher
from sdhn_sim import data_files

SRC = Path(__file__).resolve().parents[1] / "src"


def package_data_globs(setup_py: Path) -> list[str]:
    """The ``package_data`` patterns of the package's own setup.py (read, not run)."""
    for node in ast.walk(ast.parse(setup_py.read_text())):
        if isinstance(node, ast.keyword) and node.arg == "package_data":
            value = ast.literal_eval(ast.unparse(node.value).replace("PACKAGE", repr(
                data_files.PACKAGE)))
            return list(value[data_files.PACKAGE])
    return []


@pytest.mark.parametrize("name", data_files.SHIPPED)
def test_every_referenced_data_file_is_installed_and_packaged(name: str) -> None:
    path = data_files.data_file(name)
    assert path.is_file() and path.stat().st_size > 0, path
    globs = package_data_globs(SRC / data_files.PACKAGE / "setup.py")
    relative = f"{data_files.DATA_DIR}/{name}"
    assert any(fnmatch.fnmatch(relative, g) for g in globs), (
        f"{relative} is not in package_data {globs}: an installed package would lack it")


def test_a_missing_data_file_is_an_error_naming_it() -> None:
    with pytest.raises(data_files.DataFileMissing, match=r"no-such\.xml"):
        data_files.data_file("no-such.xml")


def test_no_module_finds_data_by_walking_its_own_path() -> None:
    """``Path(__file__)...`` lookups broke once when a module moved packages (the launcher
    pointed Fast DDS at a file that did not exist); data goes through sdhn_sim.data_files."""
    offenders = []
    for path in sorted(SRC.rglob("*.py")):
        if path.name == "setup.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Name) and node.id == "__file__":
                offenders.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert not offenders, f"__file__ used in {offenders}; use sdhn_sim.data_files"


def test_launched_children_get_the_fast_dds_profile_that_exists(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch
                                                              ) -> None:
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    cfg = load_config(None, ["mode=train", "env=maif-tiny", f"run_dir={tmp_path / 'run'}"])
    launcher = Launcher(cfg, out=io.StringIO())
    profiles = {c.env["FASTRTPS_DEFAULT_PROFILES_FILE"] for c in launcher.children}
    assert len(profiles) == 1, profiles
    profile = Path(profiles.pop())
    assert profile.is_file(), f"children run with Fast DDS defaults: {profile} does not exist"
    assert "sdhn_participant" in profile.read_text()
