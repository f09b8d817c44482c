"""``train``: the in-process trainer's command line.

    train --env maif-10 --algo sdhn --seed 1 --total-steps 2000000
    train --config exp.yaml --set ppo.lr=3e-4 --set sdhn.skew_loss=false
    train --resume runs/<run>/checkpoints/step_000000409600   (or the run directory)

Resume takes the run's own saved config; flags may change only the fields in ``RESUME_SAFE``,
any other change is refused. A checkpoint that fails to load (truncated, checksum) falls back to
the previous one, said in one line. Nothing is written into the run before the checkpoint loaded.

Exit codes: 0 done (or stopped by Ctrl-C / SIGTERM after saving a checkpoint), 2 invalid
configuration or unusable checkpoint (one line; ``--debug`` for the traceback), 3 training
stopped on a non-finite loss, 1 another data-parallel rank failed (``train.learner_processes`` > 1;
one line naming it).
"""

from __future__ import annotations

import argparse
import errno
import sys
from pathlib import Path
from typing import Any

import yaml

from sdhn_sim.envs.registry import env_names
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.checkpoint import CheckpointError, checkpoints, load_checkpoint
from sdhn_train.config import (
    Config,
    ConfigError,
    apply_dict,
    describe,
    load_yaml,
    set_field,
    validate,
)
from sdhn_train.data_parallel import RankFailedError

SHORTCUTS = {  # --flag -> config field
    "env": "env.name", "algo": "algo.name", "seed": "train.seed",
    "total_steps": "train.total_steps", "num_envs": "env.num_envs", "run_name": "log.run_name",
}
# What a run writes: a directory holding any of them is a run (another run's; never merged).
# Other files (an experiment runner's spec or config beside it) do not make it one.
RUN_FILES = ("checkpoints", "config.yaml", "metrics.csv", "actor.safetensors", "summary.json")
# Fields a resume may change: they change neither the networks, the optimiser nor the data.
# log.root: a log directory carried to another machine (sdhn_experiments/carry.py) resumes
# from there.
RESUME_SAFE = frozenset({"train.total_steps", "log.checkpoint_interval", "log.keep_checkpoints",
                         "log.actor_marks",
                         "log.progress", "log.root",
                         "log.tensorboard", "eval.interval", "train.threads",
                         "train.retain_freed_memory"})


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
    p.add_argument("--debug", action="store_true", help="show tracebacks of refused inputs")
    return p


def config_from_args(args: argparse.Namespace, base: dict[str, Any] | None = None) -> Config:
    """Defaults (or the resumed run's saved config ``base``) <- --config <- shortcuts <- --set."""
    cfg = Config()
    if base is not None:
        apply_dict(cfg, base)
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
    validate(cfg, resuming=base is not None)
    return cfg


def _changed(saved: dict[str, Any], cfg: Config) -> list[str]:
    now = cfg.to_dict()
    return [f"{s}.{k}" for s, fields in now.items() for k, v in fields.items()
            if saved.get(s, {}).get(k, v) != v]


def resume_candidates(path: Path) -> list[Path]:
    """Checkpoint stems to try, newest first: a run directory's checkpoints, or one stem."""
    if path.is_dir():
        found = checkpoints(path)
        if not found:
            raise ConfigError(f"--resume {path}: no checkpoints in that directory")
        return found[::-1]
    stem = path.with_suffix("") if path.suffix in (".json", ".safetensors") else path
    if not stem.with_suffix(".json").is_file():
        raise ConfigError(f"--resume {path}: no such checkpoint or run directory")
    return [stem]


def pick_checkpoint(path: Path, out: Any = sys.stderr) -> tuple[Path, dict[str, Any]]:
    """The newest checkpoint that reads and passes its checksum, with its metadata; an older
    one (said in one line) when the newest is damaged."""
    errors = []
    for stem in resume_candidates(path):
        try:
            _, meta = load_checkpoint(stem)
        except CheckpointError as e:
            errors.append(str(e))
            continue
        if errors:
            print(f"train: newest checkpoint unusable ({errors[0]}); resuming from {stem}",
                  file=out)
        if not isinstance(meta.get("config"), dict):
            raise ConfigError(f"{stem}: checkpoint has no saved config")
        return stem, meta
    raise ConfigError(f"--resume {path}: no usable checkpoint ({'; '.join(errors)})")


def run_dir_of(stem: Path) -> Path | None:
    return stem.parent.parent if stem.parent.name == "checkpoints" else None


def _main(args: argparse.Namespace) -> int:
    resume: Path | None = None
    if args.resume is not None:
        resume, meta = pick_checkpoint(args.resume)
        saved = meta["config"]
        cfg = config_from_args(args, base=saved)
        refused = [f for f in _changed(saved, cfg) if f not in RESUME_SAFE]
        if refused:
            raise ConfigError(f"--resume: cannot change {', '.join(refused)} of a saved run "
                              f"(allowed: {', '.join(sorted(RESUME_SAFE))}); start a new run")
    else:
        cfg = config_from_args(args)
    if args.print_config:
        print(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
        return 0
    from sdhn_train.ranks import learner_ranks
    from sdhn_train.trainer import Trainer, default_run_dir

    run_dir = run_dir_of(resume) if resume is not None else None
    if resume is None:
        run_dir = default_run_dir(cfg)
        if run_dir.exists() and (not run_dir.is_dir()
                                 or any((run_dir / f).exists() for f in RUN_FILES)):
            raise ConfigError(f"log.run_name: run directory {run_dir} already holds a run; "
                              "choose another name or --resume it")
    # A resumed run's actor comes from its checkpoint: its warm-start file (kept in the config
    # as provenance) is neither needed nor read.
    with learner_ranks(cfg, run_dir, resume, resume is None) as group:  # K = 1: no process
        trainer = Trainer(cfg, run_dir=run_dir, warm_start=resume is None, group=group)
        return trainer.run(resume=resume)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return _main(args)
    except (ConfigError, CheckpointError, yaml.YAMLError, UnicodeDecodeError, OSError) as e:
        if args.debug:
            raise
        text = " ".join(str(e).split())
        if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
            # Not the configuration's fault: say so, and how to go on from the last checkpoint.
            print(f"train: the disk is full: {text}; free space (log.keep_checkpoints bounds "
                  "what a run keeps), then continue with --resume RUN_DIR", file=sys.stderr)
            return 1
        print(f"train: invalid configuration: {text}", file=sys.stderr)
        return 2
    except RankFailedError as e:  # another data-parallel rank failed (train.learner_processes)
        if args.debug:
            raise
        print(f"train: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # a second Ctrl-C while the checkpoint was being written
        print("train: interrupted twice; stopped without a final checkpoint", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
