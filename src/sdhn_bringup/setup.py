"""ament_python package sdhn_bringup: the launcher, on top of the three node packages (it starts
their executables and checks weights with sdhn_policy before any process starts).

Installed by colcon on a full ROS install, or in editable mode by scripts/setup.sh.
"""

from setuptools import find_packages, setup

PACKAGE = "sdhn_bringup"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    package_data={PACKAGE: []},
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="sdhn developers",
    maintainer_email="sdhn-dev@example.com",
    description="SDHN bringup: one YAML config starts a whole graph (python -m sdhn_bringup).",
    license="Apache-2.0",
)
