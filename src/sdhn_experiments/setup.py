"""ament_python package sdhn_experiments.

Installed by colcon on a full ROS install, or in editable mode by scripts/setup.sh.
"""

from setuptools import find_packages, setup

PACKAGE = "sdhn_experiments"

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
    description=(
        "SDHN experiments: suites, runner, held-out evaluation, protocol reports, figures, "
        "carried runs."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "run_experiments = sdhn_experiments.experiments_cli:main",
            "protocol_report = sdhn_experiments.protocol_report:main",
            "carry_runs = sdhn_experiments.carry:main",
            "evaluate_policy = sdhn_experiments.evaluate_policy:main",
            "ship_model = sdhn_experiments.ship_model:main",
            "train_curriculum = sdhn_experiments.curriculum:main",
        ],
    },
)
