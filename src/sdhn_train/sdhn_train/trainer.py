"""In-process trainer: vectorised rollouts -> the algorithm's learner -> logs, evaluation,
checkpoints.

Reads top to bottom in ``Trainer.run``. Seeding happens once, in ``runs.seed_everything``. Only
the ``Learner`` protocol is used: the same loop runs every algorithm of the registry.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch
import yaml

from sdhn_policy.weights import atomic_write_bytes, save_actor_file
from sdhn_sim.envs.api import BatchedEnv, EpisodeStats, reward_name
from sdhn_train import checkpoint as ckpt
from sdhn_train import metrics_file
from sdhn_train.algorithms.registry import get_algorithm
from sdhn_train.collector import RolloutCollector
from sdhn_train.config import Config
from sdhn_train.data_parallel import Command, Group
from sdhn_train.device import resolve_device
from sdhn_train.env_features import conditioned, make_training_env, unwrap
from sdhn_train.envinfo import EnvInfo
from sdhn_train.evaluation import evaluate_sets, headline, make_eval_envs
from sdhn_train.learners.base import Learner, NonFiniteLossError
from sdhn_train.learners.ppo import PPOLearner
from sdhn_train.metrics_file import MetricsLog
from sdhn_train.normalize import RewardNormalizer
from sdhn_train.rollout import Rollout
from sdhn_train.runs import (
    episode_metrics,
    retain_freed_memory,
    save_ph_snapshot,
    seed_everything,
)
from sdhn_train.sections import ConfigError
from sdhn_train.warm_start import load_actor_into

EnvFactory = Callable[..., BatchedEnv]  # (name, num_envs, seed, **overrides) -> env


def default_env_factory(name: str, num_envs: int, seed: int, **overrides: Any) -> BatchedEnv:
    from sdhn_sim.envs import make_env

    return make_env(name, num_envs=num_envs, seed=seed, **overrides)


def default_run_dir(cfg: Config) -> Path:
    """``<log.root>/<log.run_name>``, or a name from env, algorithm, seed and the time."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    name = cfg.log.run_name or f"{cfg.env.name}__{cfg.algo.name}__{cfg.train.seed}__{stamp}"
    return Path(cfg.log.root) / name


def rank_seed(seed: int, rank: int) -> int:
    """Data-parallel rank ``rank``'s seed (its environments and action draws): rank 0 keeps
    ``train.seed``, so one data-parallel rank is today's run exactly."""
    return seed + 1_000_003 * rank


class Trainer:
    """With ``group`` (``train.learner_processes`` > 1) this is one of K data-parallel ranks on
    B/K environments; only rank 0 runs ``run`` (evaluates, logs, checkpoints, exports), the
    others serve its commands (``sdhn_train.ranks``)."""

    def __init__(self, cfg: Config, env_factory: EnvFactory = default_env_factory,
                 run_dir: Path | None = None, warm_start: bool = True,
                 group: Group | None = None) -> None:
        self.cfg, self.group = cfg, group
        self.rank, self.world = (group.rank, group.world) if group is not None else (0, 1)
        seed = rank_seed(cfg.train.seed, self.rank)
        num_envs = cfg.env.num_envs // self.world
        self.np_rng = seed_everything(seed, cfg.train.deterministic, cfg.train.threads)
        if cfg.train.retain_freed_memory:
            retain_freed_memory()
        self.env = make_training_env(cfg, env_factory, num_envs, seed)
        # training set "" and held-out set; rank 0 alone evaluates
        self.eval_envs = make_eval_envs(cfg, env_factory) if self.rank == 0 else {}
        self.eval_env = self.eval_envs.get("")
        # Every rank draws the same minibatch permutations (of its own envs), so the learner
        # state rank 0 checkpoints is every rank's.
        learner_rng = self.np_rng if self.rank == 0 else np.random.default_rng(cfg.train.seed)
        self.learner: Learner = get_algorithm(cfg.algo.name).build_learner(
            cfg, EnvInfo.of(self.env), learner_rng)
        if cfg.actor.init_from and warm_start:  # warm start from an exported actor
            load_actor_into(self.learner.actor, cfg.actor.init_from, cfg.actor.init_temperature)
        self.device = resolve_device(cfg.train.device)
        if self.device.type != "cpu":  # validated: a PPO learner, one rank
            assert isinstance(self.learner, PPOLearner)
            self.learner.to(self.device)
        if group is not None:
            if not isinstance(self.learner, PPOLearner):
                raise ConfigError("train.learner_processes > 1 needs a PPO learner (sdhn, "
                                  f"mappo, dicg), not {cfg.algo.name}")
            self.learner.group = group
            group.broadcast_modules((self.learner.actor, self.learner.critic,
                                     self.learner.target_critic))
        self.collector = RolloutCollector(self.env, self.learner.actor, cfg.ppo.rollout_len,
                                          self.learner.sample_actions)
        self.critic_h = self.learner.initial_critic_hidden(num_envs)
        self.reward_norm = (RewardNormalizer(num_envs, cfg.ppo.gamma)
                            if cfg.ppo.normalize_rewards else None)
        self.global_step = 0
        self.last_checkpoint: Path | None = None
        self.last_rollout: Rollout | None = None  # for P_H snapshots (sdhn_experiments)
        self.run_dir = run_dir or default_run_dir(cfg)
        self.stop_requested = False  # set by SIGINT / SIGTERM: checkpoint, then stop

    # -- checkpoints ---------------------------------------------------------------------------

    def shard_state(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """What is this process's own: its environments, the collector's carry, the reward
        normaliser and (for ranks > 0, whose action draws differ) torch's RNG state."""
        env_arrays, env_values = ckpt.env_snapshot(unwrap(self.env))
        arrays = {f"env.{k}": v for k, v in env_arrays.items()}
        if (cond := conditioned(self.env)) is not None:  # train.conditions: its counters
            arrays.update({f"conditions.{k}": v for k, v in cond.model.state_dict().items()})
        arrays["collector.obs"] = self.collector.obs
        arrays["collector.state"] = self.collector.state
        arrays["collector.actor_h"] = self.collector.actor_h
        arrays["collector.critic_h"] = self.critic_h
        if self.reward_norm is not None:
            arrays.update({f"reward_norm.{k}": v for k, v in self.reward_norm.state().items()})
        if self.rank:
            arrays["rng.torch"] = torch.get_rng_state().numpy()
        return arrays, env_values

    def save_checkpoint(self) -> Path:
        """Rank 0 writes one checkpoint: the learner (identical in every process), its own
        shard under today's keys and rank r's shard under ``rank<r>.``."""
        arrays, meta = ckpt.learner_state(self.learner)
        shard, env_values = self.shard_state()
        arrays.update(shard)
        meta.update(global_step=self.global_step, config=self.cfg.to_dict(),
                    env_values=env_values)
        if self.group is not None:
            self.group.command(Command.SHARD)
            shards = self.group.gather(None) or []
            for r, (other, values) in enumerate(shards[1:], start=1):
                arrays.update({f"rank{r}.{k}": v for k, v in other.items()})
                meta[f"rank{r}.env_values"] = values
        path = ckpt.checkpoint_path(self.run_dir, self.global_step)
        ckpt.save_checkpoint(path, arrays, meta)
        self.last_checkpoint = path
        ckpt.prune_checkpoints(self.run_dir, self.cfg.log.keep_checkpoints)  # after it is complete
        return path

    def load_checkpoint(self, path: Path) -> None:
        """Load ``path``; CheckpointError (one line) when it does not fit this configuration."""
        arrays, meta = ckpt.load_checkpoint(path)
        saved = meta.get("config", {})
        for section, name in (("algo", "name"), ("env", "name"),
                              ("train", "learner_processes")):  # the shards must match
            have = getattr(getattr(self.cfg, section), name)
            was = saved.get(section, {}).get(name, have)
            if was != have:
                raise ckpt.CheckpointError(f"{path}: checkpoint is for {section}.{name}={was}, "
                                           f"not {have}")
        try:
            self._restore(arrays, meta)
        except (RuntimeError, KeyError, ValueError, IndexError, TypeError) as e:
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise ckpt.CheckpointError(f"{path}: does not fit this configuration: {first}"
                                       ) from e
        self.last_checkpoint = path

    def _restore(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        ckpt.restore_learner_state(self.learner, arrays, meta)
        prefix = f"rank{self.rank}." if self.rank else ""  # this process's shard
        if prefix:
            arrays = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
            torch.set_rng_state(torch.from_numpy(arrays["rng.torch"].copy()))
        ckpt.env_restore(unwrap(self.env),
                         {k[4:]: v for k, v in arrays.items() if k.startswith("env.")},
                         meta[f"{prefix}env_values"])
        if (cond := conditioned(self.env)) is not None:
            cond.model.load_state_dict({k[11:]: v for k, v in arrays.items()
                                        if k.startswith("conditions.")})
        self.collector.obs = arrays["collector.obs"].copy()
        self.collector.state = arrays["collector.state"].copy()
        self.collector.actor_h = arrays["collector.actor_h"].copy()
        self.critic_h = arrays["collector.critic_h"].copy()
        if self.reward_norm is not None:
            self.reward_norm.load_state({k[12:]: v for k, v in arrays.items()
                                         if k.startswith("reward_norm.")})
        self.global_step = int(meta["global_step"])

    def write_ph_snapshot(self) -> Path | None:
        """P_H arrays of the last rollout for the figures (critics with hypergraphs only); on a
        forked torch RNG, so a snapshot never changes the training run."""
        if self.last_rollout is None:
            return None
        with torch.random.fork_rng():
            samples = self.learner.hypergraphs(self.last_rollout)
        return save_ph_snapshot(self.run_dir, self.global_step, samples)

    def export_marked_actors(self) -> None:
        """``actors/step_<mark>.safetensors`` for every ``log.actor_marks`` mark now reached and
        not yet written (a resumed run never rewrites one it already holds)."""
        for mark in self.cfg.log.actor_marks:
            path = self.run_dir / ACTOR_MARKS_DIR / f"step_{mark}.safetensors"
            if self.global_step >= mark and not path.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
                save_actor_file(path, self.learner.export_actor(version=self.learner.num_updates))

    # -- the loop ------------------------------------------------------------------------------

    def evaluate(self) -> dict[str, float]:
        assert self.eval_env is not None
        self.eval_envs[""] = self.eval_env
        return evaluate_sets(self.eval_envs, self.learner.actor, self.cfg.eval.seed)

    def train_iteration(self) -> tuple[dict[str, float], list[EpisodeStats]]:
        """One rollout + one PPO update (the unit that checkpoints and resume line up on)."""
        if self.group is not None and self.rank == 0:
            self.group.command(Command.ITERATE)  # the other ranks run this method with us
        rollout, episodes = self.collector.collect(self.critic_h)
        self.last_rollout = rollout
        if self.reward_norm is not None:
            rollout = self.reward_norm(rollout)
        t0 = time.perf_counter()
        metrics = self.learner.update(rollout)
        self.collector.timings.update += time.perf_counter() - t0
        self.critic_h = self.learner.next_critic_hidden()
        self.global_step += rollout.rewards.size * self.world  # every rank's share is equal
        return metrics, episodes

    def run(self, resume: Path | None = None, out: TextIO = sys.stderr) -> int:
        cfg = self.cfg
        if resume is not None:  # nothing is written into the run before its checkpoint loaded
            self.load_checkpoint(resume)
            dropped = metrics_file.trim(self.run_dir / metrics_file.FILE, self.global_step)
            print(f"resumed from {resume} at step {self.global_step}"
                  + (f" (dropped {dropped} metric rows logged after it)" if dropped else ""),
                  file=out)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self.run_dir / "config.yaml",
                           yaml.safe_dump(cfg.to_dict(), sort_keys=False).encode())
        with _stop_on_signals(self):
            return self._loop(out)

    def _loop(self, out: TextIO) -> int:
        cfg = self.cfg
        log = MetricsLog(self.run_dir, cfg.log.tensorboard)
        bar = _progress(cfg.train.total_steps, self.global_step, cfg.log.progress, out)
        next_eval = _next_multiple(self.global_step, cfg.eval.interval)
        next_ckpt = _next_multiple(self.global_step, cfg.log.checkpoint_interval)
        start_time, start_step = time.perf_counter(), self.global_step
        recent: list[EpisodeStats] = []
        try:
            while self.global_step < cfg.train.total_steps and not self.stop_requested:
                metrics, episodes = self.train_iteration()
                recent = (recent + episodes)[-100:]
                sps = (self.global_step - start_step) / (time.perf_counter() - start_time)
                metrics["charts/steps_per_second"] = sps
                metrics.update(episode_metrics("charts", episodes))
                if self.eval_env is not None and self.global_step >= next_eval:
                    metrics.update(evaluated := self.evaluate())
                    print(f"step {self.global_step}: {headline(evaluated)} "
                          f"({reward_name(self.env)} reward)", file=out)
                    self.write_ph_snapshot()
                    next_eval = _next_multiple(self.global_step, cfg.eval.interval)
                log.write(self.global_step, metrics)
                self.export_marked_actors()
                if cfg.log.checkpoint_interval and self.global_step >= next_ckpt:
                    self.save_checkpoint()
                    next_ckpt = _next_multiple(self.global_step, cfg.log.checkpoint_interval)
                bar.update(self.global_step, {
                    "sps": f"{sps:.0f}",
                    "ret": f"{np.mean([e.episode_return for e in recent]):.1f}" if recent else "-",
                    "succ": f"{np.mean([e.completed for e in recent]):.2f}" if recent else "-"})
        except NonFiniteLossError as e:
            bar.close()
            log.close()
            last = self.last_checkpoint or "none (no checkpoint was written yet)"
            print(f"error: {e} at step {self.global_step}; last good checkpoint: {last}", file=out)
            return 3
        bar.close()
        self.save_checkpoint()
        if self.stop_requested:
            log.close()
            print(f"train: stopped at step {self.global_step}; checkpoint "
                  f"{self.last_checkpoint}; continue with: train --resume {self.run_dir}",
                  file=out)
            return 0
        self.write_ph_snapshot()
        final = self.evaluate() if self.eval_env is not None else {}
        if final:
            log.write(self.global_step, final)
        log.close()
        blob = self.learner.export_actor(version=self.learner.num_updates)
        save_actor_file(self.run_dir / "actor.safetensors", blob)
        summary = {**final, "reward": reward_name(self.env), "global_step": self.global_step,
                   "run_dir": str(self.run_dir), "actor": str(self.run_dir / "actor.safetensors"),
                   "timings": asdict(self.collector.timings)}
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
        print(json.dumps(summary), file=out)
        return 0


ACTOR_MARKS_DIR = "actors"
"""Where ``log.actor_marks`` exports go, inside the run directory."""


class _stop_on_signals:
    """SIGINT / SIGTERM ask the loop to stop after the current iteration (which then saves a
    checkpoint); a second signal stops at once. Main thread only; handlers restored on exit."""

    def __init__(self, trainer: Trainer) -> None:
        self.trainer = trainer
        self.saved: dict[int, Any] = {}

    def _handle(self, signum: int, frame: object) -> None:
        if self.trainer.stop_requested:
            raise KeyboardInterrupt
        self.trainer.stop_requested = True

    def __enter__(self) -> _stop_on_signals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.saved[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self.saved.items():
            signal.signal(sig, handler)


def _next_multiple(step: int, interval: int) -> int:
    return (step // interval + 1) * interval if interval > 0 else 1 << 62


class _progress:
    """tqdm bar with steps/s and ETA (a no-op when disabled)."""

    def __init__(self, total: int, initial: int, enabled: bool, out: TextIO) -> None:
        self._bar: Any = None
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=initial, unit="step", unit_scale=True,
                             dynamic_ncols=True, file=out)
        self._n = initial

    def update(self, step: int, postfix: dict[str, str]) -> None:
        if self._bar is not None:
            self._bar.update(step - self._n)
            self._bar.set_postfix(postfix, refresh=False)
        self._n = step

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
