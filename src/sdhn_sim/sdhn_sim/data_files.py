"""The one way to find the data files shipped inside the packages (``sdhn_sim/data/``).

Every lookup goes through :mod:`importlib.resources`, so it finds the files wherever the package
is installed (editable checkout, wheel, colcon install) and never by walking ``__file__``
parents: a module that moved once pointed the launcher at a Fast DDS profile that did not exist,
and Fast DDS silently ran with its defaults. :data:`SHIPPED` names every file the code uses; a
test asserts that each one exists in the installed package and is listed in its package data.

    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(data_files.fastdds_profile())
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

PACKAGE = "sdhn_sim"
DATA_DIR = "data"

FASTDDS_PROFILE = "fastdds.xml"
"""Fast DDS profile of every launched node (faster announcements and heartbeats, see the file)."""
FASTDDS_REPLAY_PROFILE = "fastdds-replay.xml"
"""Fast DDS profile of ``replay --rate`` (publisher flow control for whole recordings)."""
MAIF_SHIPPED = ("maif-tiny", "maif-10", "maif-16", "maif-20")
"""MAIF instance sets shipped as ``<name>.npz``; larger ones are generated on demand."""

SHIPPED = (FASTDDS_PROFILE, FASTDDS_REPLAY_PROFILE, *(f"{n}.npz" for n in MAIF_SHIPPED))
"""Every data file the code references."""


class DataFileMissing(FileNotFoundError):
    """A data file the code needs is not in the installed package (a packaging bug)."""


def data_dir() -> Path:
    """The installed package's data directory, as a file system path (the package is installed
    unzipped, ``zip_safe=False``: Fast DDS and NumPy need real paths)."""
    root = resources.files(PACKAGE).joinpath(DATA_DIR)
    if not isinstance(root, Path):
        raise DataFileMissing(f"{PACKAGE} is not installed as plain files ({root!r}); "
                              "install it unzipped")
    return root


def data_file(name: str) -> Path:
    """The path of the shipped data file ``name``; :class:`DataFileMissing` if it is not there."""
    path = data_dir() / name
    if not path.is_file():
        raise DataFileMissing(f"{PACKAGE} data file {name} is missing from {path.parent} "
                              "(the package was installed without its data)")
    return path


def fastdds_profile() -> Path:
    return data_file(FASTDDS_PROFILE)


def fastdds_replay_profile() -> Path:
    return data_file(FASTDDS_REPLAY_PROFILE)


def maif_instance_file(name: str) -> Path:
    """Where the instance set of MAIF config ``name`` is (shipped) or would be written (by
    ``scripts/make_maif_instances.py``); it may not exist for a config that is not shipped."""
    return data_dir() / f"{name}.npz"
