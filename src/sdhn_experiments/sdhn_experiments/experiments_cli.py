"""The ``run_experiments`` command: a suite on the local backend (``experiments.run_suite``) or
on Ray (``ray_backend.run_suite_ray``). Kept apart from both so neither imports the other's
caller. Usage: see ``sdhn_experiments.experiments``."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Any

from sdhn_experiments import experiments
from sdhn_experiments.experiments import (
    ExperimentError,
    RunSpec,
    check_jobs,
    check_runs,
    list_line,
    load_suite,
    run_suite,
)
from sdhn_train.config import ConfigError


def select_runs(runs: list[RunSpec], methods: list[str] | None, seeds: list[int] | None,
                names: list[str] | None) -> list[RunSpec]:
    """The runs the filters keep, in the suite's order, or in the order of ``names`` when given;
    a filter value the suite does not have is an error (a typo must not run nothing)."""
    def check(flag: str, wanted: list[Any], known: set[Any]) -> None:
        unknown = [w for w in wanted if w not in known]
        if unknown:
            raise ExperimentError(f"{flag}: {unknown} not in the suite; allowed: {sorted(known)}")

    if methods:
        check("--methods", methods, {r.method for r in runs})
        runs = [r for r in runs if r.method in methods]
    if seeds:
        check("--seeds", seeds, {r.seed for r in runs})
        runs = [r for r in runs if r.seed in seeds]
    if names:
        by_name = {r.name: r for r in runs}
        check("--runs", names, set(by_name))
        runs = [by_name[n] for n in dict.fromkeys(names)]
    return runs


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="run_experiments", description=experiments.__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("suite", type=Path, help="suite YAML (configs/suites/*.yaml)")
    p.add_argument("--budget", default="quick", help="budget named in the suite (quick, paper)")
    p.add_argument("--logdir", type=Path, help="default: runs/<suite>-<budget>")
    p.add_argument("--jobs", type=int, default=None,
                   help="local backend: runs at once (default: CPU cores)")
    p.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="local: subprocesses on this machine; ray: one Ray task per run")
    p.add_argument("--address", default=None,
                   help="ray backend: an existing cluster (default: RAY_ADDRESS, else a local "
                        "Ray started here); --logdir must then be shared by every node")
    p.add_argument("--num-cpus", type=int, default=None,
                   help="ray backend, local Ray only: CPUs it offers (default: all cores)")
    p.add_argument("--list", action="store_true", help="print the runs and their state, run none")
    p.add_argument("--methods", nargs="+", default=None,
                   help="run only these methods of the suite (e.g. sdhn mappo first)")
    p.add_argument("--seeds", nargs="+", type=int, default=None,
                   help="run only these seeds of the suite (e.g. 3 to add a seed)")
    p.add_argument("--runs", nargs="+", default=None,
                   help="run only these runs, by name (TASK__METHOD__sSEED, as --list prints), "
                        "in the order given: which runs the cores take first")
    args = p.parse_args(argv)

    def _terminated(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt  # stop the runs this process started, then exit

    signal.signal(signal.SIGTERM, _terminated)
    # A shell without job control (`bash -c '... &'`, a script) starts background commands with
    # SIGINT ignored, and Python keeps an inherited SIG_IGN: `kill -INT` would then be silently
    # dropped by a runner that is meant to stop cleanly and resume. Take SIGINT explicitly.
    signal.signal(signal.SIGINT, _terminated)
    try:
        runs = select_runs(load_suite(args.suite, args.budget), args.methods, args.seeds,
                           args.runs)
        check_runs(runs)
        check_jobs(args.jobs)
        if args.num_cpus is not None and args.num_cpus < 1:
            raise ExperimentError(f"--num-cpus {args.num_cpus}: allowed: an integer >= 1 (CPUs "
                                  "the local Ray offers; a run needs at least one)")
        logdir = args.logdir or Path("runs") / f"{runs[0].suite}-{args.budget}"
        if args.list:
            for r in runs:
                print(list_line(r, logdir))
            return 0
        if args.backend == "ray":
            from sdhn_experiments.ray_backend import run_suite_ray

            counts = run_suite_ray(runs, logdir, args.address, num_cpus=args.num_cpus)
        else:
            counts = run_suite(runs, logdir, args.jobs)
    except (ExperimentError, ConfigError, OSError) as e:
        print(f"run_experiments: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("run_experiments: interrupted; rerun the same command to resume", file=sys.stderr)
        return 130
    return 1 if counts["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
