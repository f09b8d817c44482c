"""ament_python package sdhn_policy.

Installed by colcon on a full ROS install, or in editable mode by scripts/setup.sh.
"""

from setuptools import find_packages, setup

PACKAGE = "sdhn_policy"

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
    description=("SDHN decentralised actor: NumPy runtime, weight files, per-robot actor node."),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "actor = sdhn_policy.actor_node:main",
            "export_onnx = sdhn_policy.onnx_export_cli:main",
        ],
    },
)
