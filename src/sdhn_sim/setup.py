"""ament_python package sdhn_sim.

Installed by colcon on a full ROS install, or in editable mode by scripts/setup.sh.
"""

from setuptools import find_packages, setup

PACKAGE = "sdhn_sim"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    package_data={PACKAGE: ["data/*.npz", "data/*.xml"]},
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="sdhn developers",
    maintainer_email="sdhn-dev@example.com",
    description=(
        "SDHN simulation: MAIF and RWARE environments, simulator node, MCAP recorder and replay."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim = sdhn_sim.sim_node:main",
            "recorder = sdhn_sim.recording.recorder_node:main",
            "replay = sdhn_sim.recording.replay:main",
            "viz = sdhn_sim.viz.viz_node:main",
        ],
    },
)
