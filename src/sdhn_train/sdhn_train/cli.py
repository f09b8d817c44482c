"""``train``: the in-process trainer's command line.

    train --env maif-10 --algo sdhn --seed 1 --total-steps 2000000
    train --config exp.yaml --set ppo.lr=3e-4 --set sdhn.skew_loss=false
    train --resume runs/<run>/checkpoints/step_000000409600   (or the run directory)

Exit codes: 0 done, 2 invalid configuration, 3 training stopped on a non-finite loss.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sdhn_sim.envs.registry import env_names
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.checkpoint import resolve_checkpoint
from sdhn_train.config import (
    Config,
    ConfigError,
    apply_dict,
    describe,
    load_yaml,
    set_field,
    validate,
)

SHORTCUTS = {  # --flag -> config field
    "env": "env.name", "algo": "algo.name", "seed": "train.seed",
    "total_steps": "train.total_steps", "num_envs": "env.num_envs", "run_name": "log.run_name",
}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="train", description="Train an algorithm in-process on vectorised environments.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="config fields (--set section.field=value):\n" + describe())
    p.add_argument("--config", type=Path, help="YAML file with {section: {field: value}}")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                   help="override one config field (repeatable)")
    choices = {"env": env_names(), "algo": list(ALGO_NAMES)}
    for flag, target in SHORTCUTS.items():
        allowed = f" ({', '.join(choices[flag])})" if flag in choices else ""
        p.add_argument(f"--{flag.replace('_', '-')}", dest=flag,
                       help=f"same as --set {target}=...{allowed}")
    p.add_argument("--resume", type=Path, help="checkpoint path (without suffix) or run directory")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--print-config", action="store_true", help="print the final config and exit")
    return p


def config_from_args(args: argparse.Namespace) -> Config:
    cfg = Config()
    if args.config is not None:
        apply_dict(cfg, load_yaml(args.config))
    for flag, target in SHORTCUTS.items():
        value = getattr(args, flag)
        if value is not None:
            set_field(cfg, target, value)
    for item in args.set:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected SECTION.FIELD=VALUE")
        key, value = item.split("=", 1)
        set_field(cfg, key.strip(), value.strip())
    if args.no_progress:
        cfg.log.progress = False
    validate(cfg)
    return cfg


def latest_checkpoint(path: Path) -> Path:
    """A checkpoint stem from a stem, a .json/.safetensors file, or a run directory (latest)."""
    found = resolve_checkpoint(path)
    if found is None:
        raise ConfigError(f"--resume {path}: no checkpoints in that directory")
    return found


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(args)
        resume = latest_checkpoint(args.resume) if args.resume is not None else None
    except (ConfigError, OSError) as e:
        print(f"train: invalid configuration: {e}", file=sys.stderr)
        return 2
    if args.print_config:
        import yaml

        print(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
        return 0
    from sdhn_train.trainer import Trainer

    run_dir = None
    if resume is not None and resume.parent.name == "checkpoints":
        run_dir = resume.parent.parent  # keep logging into the run being resumed
    return Trainer(cfg, run_dir=run_dir).run(resume=resume)


if __name__ == "__main__":
    sys.exit(main())
