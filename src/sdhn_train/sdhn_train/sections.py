"""The configuration sections every run has (environment, algorithm name, actor, training,
evaluation, logging), the field helper and the error type. Stdlib only.

The learners own their sections (``ppo``: ``sdhn_train.learners.ppo.PPOConfig``) and every
algorithm owns one (``sdhn``: ``sdhn_train.algorithms.sdhn.SDHNConfig``, ...);
``sdhn_train.config.Config`` puts them together.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

from sdhn_base.errors import ConfigError


def opt(default: Any, help: str) -> Any:
    """A dataclass field with an immutable default and its help string."""
    return field(default=default, metadata={"help": help})


def need(ok: bool, path: str, allowed: str, value: object) -> None:
    """Raise ConfigError ``path = value is invalid; allowed: ...`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"{path} = {value!r} is invalid; allowed: {allowed}")


def need_positive(section: str, values: dict[str, int]) -> None:
    for name, v in values.items():
        need(v >= 1, f"{section}.{name}", "an integer >= 1", v)


class Section(Protocol):
    """A config section that checks its own values (ConfigError naming the field)."""

    def validate(self) -> None: ...


@dataclass
class EnvConfig:
    name: str = opt("maif-10", "environment, a name of sdhn_sim.envs.env_names()")
    num_envs: int = opt(32, "B: environments stepped together in one process")
    max_steps: int | None = opt(None, "episode step limit; null = the environment's (500 MAIF)")
    reward: str = opt("corrected", "MAIF reward, a name of sdhn_sim.envs.maif.MAIF_REWARDS "
                                   "(corrected, reference; ignored by RWARE)")
    instance_set: str = opt("train", "MAIF training instances: train (the 100 fixed), large "
                                     "(1000 from another seed), procedural (a fresh map per "
                                     "episode from a third seed); evaluation always uses "
                                     "train and heldout")
    features: str = opt("auto", "actor/critic input features: auto (maif-ego/1 for MAIF, "
                                "identity otherwise) or a name of sdhn_policy.features.TRANSFORMS")


@dataclass
class AlgoConfig:
    name: str = opt("sdhn", "algorithm, a name of sdhn_train.algorithms.registry.ALGO_NAMES "
                            "(sdhn/mappo/dicg: PPO, only the critic differs; qmix/hgcn_mix: "
                            "value mixing)")


@dataclass
class ActorConfig:
    hidden_sizes: list[int] = field(default_factory=lambda: [64],
                                    metadata={"help": "MLP encoder widths before the GRU"})
    gru_hidden: int = opt(64, "GRU hidden size; 0 = a feed-forward actor (no recurrence, as "
                              "EPyMARL's use_rnn: false)")
    use_robot_id: bool = opt(False, "append a one-hot robot id to each local observation")
    init_from: str | None = opt(None, "start from this exported actor (.safetensors), e.g. one "
                                      "trained on maif-solo or a smaller team (warm start; a "
                                      "new robot id starts as the mean of the trained ids)")
    init_temperature: float = opt(1.0, "warm start only: divide the loaded actor's logits by "
                                       "this (> 1 = a higher-entropy start, same greedy policy)")


@dataclass
class TrainConfig:
    total_steps: int = opt(1_000_000, "team env-steps to train for (summed over B envs)")
    seed: int = opt(1, "seed of everything (torch, numpy, environments)")
    deterministic: bool = opt(False, "torch deterministic algorithms")
    threads: int = opt(1, "torch intra-op threads")
    device: str = opt("cpu", "where the networks learn and the collector's actor runs: cpu, "
                             "cuda (refused when torch sees no GPU) or auto (cuda if torch sees "
                             "one, else cpu); checkpoints and exported actors are the same "
                             "files either way. PPO algorithms (sdhn, mappo, dicg) only")
    learner_processes: int = opt(
        1, "K data-parallel ranks (PPO learners): each collects on B/K envs and "
           "computes its share of every minibatch, gradients averaged before each step; rank 0 "
           "evaluates, logs and checkpoints (sdhn_train.data_parallel)")
    conditions: dict[str, Any] = field(default_factory=dict, metadata={"help": (
        "train under deployment conditions (domain randomisation): a conditions: block of "
        "sdhn_sim.envs.conditions wrapped around the training envs ({} = the ideal world), "
        "e.g. {latency: 1, lost_actions: 0.1, slow_fraction: 0.5, slow_rate: 0.5, randomise: "
        "true}; randomise draws every severity per episode between the ideal world and the "
        "given one. Evaluation stays in the ideal world")})
    retain_freed_memory: bool = opt(
        True, "glibc malloc keeps freed blocks up to 32 MiB for reuse instead of unmapping them "
              "(no page faults on every large temporary tensor; same numbers, fewer "
              "CPU-seconds); false = glibc's defaults")


@dataclass
class EvalConfig:
    interval: int = opt(50_000, "team env-steps between greedy evaluations (0 = never)")
    episodes: int = opt(16, "RWARE: evaluation episodes (one per env, from eval.seed)")
    instances: int = opt(100, "MAIF: instances 0..k-1 of the training and of the held-out set, "
                              "one greedy episode each")
    seed: int = opt(12345, "seed of the fixed evaluation instances")


@dataclass
class LogConfig:
    root: str = opt("runs", "directory holding run directories")
    run_name: str | None = opt(None, "run directory name; null = <env>__<algo>__<seed>__<time>")
    checkpoint_interval: int = opt(200_000, "team env-steps between checkpoints (0 = end only)")
    keep_checkpoints: int = opt(3, "newest checkpoints kept in the run directory, older ones "
                                   "deleted as each is written (0 = keep all; a value-mixing "
                                   "checkpoint holds its replay buffer, ~1.3 GB on maif-10)")
    progress: bool = opt(True, "show a progress bar")
    tensorboard: bool = opt(True, "write TensorBoard scalars")
    actor_marks: list[int] = field(default_factory=list, metadata={"help": (
        "team env-steps at which the actor is also exported to actors/step_<mark>.safetensors "
        "(the first iteration at or past each mark), so one long run is judged at several "
        "budgets; [] = the final actor only")})
