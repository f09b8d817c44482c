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
    # What the environments need when installed alone (pip install ./src/sdhn_sim; no ROS, no
    # torch: docs/onnx-and-pettingzoo.md). The nodes' rclpy comes from the ROS wheels or a ROS
    # install, as for every package here.
    install_requires=["setuptools", "numpy>=2.0", "gymnasium>=1.0", "pettingzoo>=1.24"],
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
