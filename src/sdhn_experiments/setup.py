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
            "eval_conditions = sdhn_experiments.condition_eval_cli:main",
            "plot_conditions = sdhn_experiments.condition_figures:main",
            "eval_rware_baselines = sdhn_experiments.rware_baseline_eval:main",
            "eval_rware_policy = sdhn_experiments.rware_policy_eval:main",
            "eval_scripted = sdhn_experiments.scripted_eval:main",
            "compare_eval_modes = sdhn_experiments.eval_modes:main",
            "compare_ph = sdhn_experiments.ph_compare:main",
            "learning_onset = sdhn_experiments.learning_onset:main",
            "plot_curves = sdhn_experiments.curves:main",
            "tune_stall_rule = sdhn_experiments.stall_rule_cli:main",
            "card_heldout_large = sdhn_experiments.card_heldout:main",
            "make_figures = sdhn_experiments.figures:main",
            "robustness_suite = sdhn_experiments.robustness:main",
        ],
    },
)
