"""Typed training configuration: one dataclass per concern, a help string per field.

Load order: defaults <- YAML (``--config``) <- CLI shortcuts (``--env`` ...) <- ``--set a.b=v``.
``validate`` runs before anything starts and raises ConfigError naming the field and the allowed
values.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

ENV_NAMES: tuple[str, ...] = (
    "maif-solo", "maif-tiny", "maif-10", "maif-16", "maif-20", "rware-3", "rware-6", "rware-9",
)
ALGO_NAMES: tuple[str, ...] = ("sdhn", "mappo", "qmix", "dicg", "hgcn_mix")
NOISES: tuple[str, ...] = ("logistic", "gumbel_paper")
MAIF_REWARD_NAMES: tuple[str, ...] = ("corrected", "reference")
FEATURES: tuple[str, ...] = ("auto", "identity", "maif-ego/1")


class ConfigError(ValueError):
    """Invalid configuration; the message names the field and the allowed values."""


def opt(default: Any, help: str) -> Any:
    """A dataclass field with an immutable default and its help string."""
    return field(default=default, metadata={"help": help})


@dataclass
class EnvConfig:
    name: str = opt("maif-10", f"environment, one of {', '.join(ENV_NAMES)}")
    num_envs: int = opt(32, "B: environments stepped together in one process")
    max_steps: int | None = opt(None, "episode step limit; null = the environment's (500 MAIF)")
    reward: str = opt("corrected", f"MAIF reward, one of {', '.join(MAIF_REWARD_NAMES)} "
                                   "(ignored by RWARE)")
    instance_set: str = opt("train", "MAIF training instances: train (the 100 fixed), large "
                                     "(1000 from another seed); evaluation always uses train "
                                     "and heldout")
    features: str = opt("auto", f"actor/critic input features, one of {', '.join(FEATURES)} "
                                "(auto = maif-ego/1 for MAIF, identity otherwise)")


@dataclass
class AlgoConfig:
    name: str = opt("sdhn", f"algorithm, one of {', '.join(ALGO_NAMES)} (sdhn/mappo/dicg: "
                            "PPO, only the critic differs; qmix/hgcn_mix: value mixing)")


@dataclass
class ActorConfig:
    hidden_sizes: list[int] = field(default_factory=lambda: [64],
                                    metadata={"help": "MLP encoder widths before the GRU"})
    gru_hidden: int = opt(64, "GRU hidden size")
    use_robot_id: bool = opt(False, "append a one-hot robot id to each local observation")
    init_from: str | None = opt(None, "start from this exported actor (.safetensors), e.g. one "
                                      "trained on maif-solo or a smaller team (warm start)")


@dataclass
class PPOConfig:
    rollout_len: int = opt(128, "T: steps per environment per rollout")
    lr: float | None = opt(None, "actor Adam learning rate; null = algorithm default "
                                 "(sdhn 6e-4, mappo 3e-4)")
    critic_lr: float | None = opt(None, "critic Adam learning rate; null = same as lr")
    gamma: float = opt(0.99, "discount factor")
    gae_lambda: float = opt(0.95, "GAE lambda")
    clip: float = opt(0.2, "PPO ratio clip epsilon")
    epochs: int = opt(4, "passes over each rollout")
    num_minibatches: int = opt(4, "minibatches per epoch, split over environments (<= B)")
    entropy_coef: float = opt(0.01, "entropy bonus weight")
    max_grad_norm: float = opt(10.0, "gradient-norm clip for actor and critic")
    normalize_advantages: bool = opt(True, "standardise advantages per minibatch")
    target_tau: float | None = opt(None, "target-critic soft-update rate per critic step; "
                                         "null = algorithm default (sdhn 0.01, mappo 1 = none)")
    reward_scale: float = opt(1.0, "multiply team rewards by this before GAE (logging unscaled)")
    normalize_rewards: bool = opt(False, "divide rewards by the running std of the discounted "
                                         "return (in-process trainer; logging unscaled)")


@dataclass
class SDHNConfig:
    num_hyperedges: int = opt(10, "M: hyperedges in the generated hypergraph")
    generator_hidden: int = opt(64, "f_g GRU hidden size")
    generator_layers: int = opt(3, "f_g GRU layers (paper: 3)")
    hgcn_hidden: int = opt(64, "HGCN feature size")
    hgcn_layers: int = opt(2, "HGCN layers (paper: 2)")
    state_hidden: int = opt(64, "global-state encoder size of the value head")
    tau: float = opt(1.0, "Binary Concrete temperature")
    noise: str = opt("logistic", f"Binary Concrete noise, one of {', '.join(NOISES)}")
    lambda_sk: float = opt(-0.6, "target skewness lambda_Sk, in (-1, 1)")
    lambda_cb: float = opt(1.0, "weight lambda_CB of L_Sk in the critic loss, >= 0")
    skew_loss: bool = opt(True, "add lambda_CB * L_Sk (false = ablation 'w/o L_Sk')")
    stochastic_hyperedges: bool = opt(True, "sample H (false = ablation 'w/o SHR', H=1{P_H>=0.5})")


@dataclass
class MAPPOConfig:
    critic_hidden: list[int] = field(default_factory=lambda: [64, 64],
                                     metadata={"help": "MLP critic widths"})


@dataclass
class QMIXConfig:
    """QMIX and HGCN-MIX (off-policy value mixing). They also use ppo.lr (null = 5e-4),
    ppo.gamma, ppo.rollout_len, ppo.reward_scale and ppo.max_grad_norm."""

    buffer_episodes: int = opt(500, "episode replay buffer capacity (whole episodes)")
    batch_episodes: int = opt(32, "episodes per gradient step")
    updates_per_rollout: int = opt(2, "gradient steps after each collected rollout")
    learning_starts: int = opt(2, "episodes in the buffer before the first gradient step")
    target_update_interval: int = opt(100, "gradient steps between hard target-network copies")
    double_q: bool = opt(True, "double Q-learning targets (argmax by the online agent net)")
    epsilon_start: float = opt(1.0, "epsilon-greedy exploration at step 0")
    epsilon_finish: float = opt(0.05, "epsilon after the anneal")
    epsilon_anneal_steps: int = opt(50_000, "team env-steps of the linear epsilon anneal")
    mixer_embed: int = opt(32, "mixing network embedding size")
    hypernet_hidden: int = opt(64, "hypernetwork hidden size")


@dataclass
class DICGConfig:
    embed: int = opt(64, "agent embedding size (attention and GCN width)")
    gcn_layers: int = opt(2, "GCN message-passing rounds over the soft adjacency")
    state_hidden: int = opt(64, "global-state encoder size of the value head")


@dataclass
class HGCNMixConfig:
    num_hyperedges: int = opt(10, "M: hyperedges of the learned deterministic hypergraph")
    hgcn_hidden: int = opt(64, "HGCN feature size")
    hgcn_layers: int = opt(2, "HGCN layers")


@dataclass
class TrainConfig:
    total_steps: int = opt(1_000_000, "team env-steps to train for (summed over B envs)")
    seed: int = opt(1, "seed of everything (torch, numpy, environments)")
    deterministic: bool = opt(False, "torch deterministic algorithms")
    threads: int = opt(1, "torch intra-op threads")


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
    progress: bool = opt(True, "show a progress bar")
    tensorboard: bool = opt(True, "write TensorBoard scalars")


@dataclass
class Config:
    env: EnvConfig = field(default_factory=EnvConfig)
    algo: AlgoConfig = field(default_factory=AlgoConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    sdhn: SDHNConfig = field(default_factory=SDHNConfig)
    mappo: MAPPOConfig = field(default_factory=MAPPOConfig)
    qmix: QMIXConfig = field(default_factory=QMIXConfig)
    dicg: DICGConfig = field(default_factory=DICGConfig)
    hgcn_mix: HGCNMixConfig = field(default_factory=HGCNMixConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    log: LogConfig = field(default_factory=LogConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# --- building from YAML / overrides -----------------------------------------------------------


def _coerce(path: str, tp: Any, value: Any) -> Any:
    """Convert ``value`` (YAML scalar or CLI string) to the annotated type ``tp``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        is_null = value is None or (isinstance(value, str) and value.lower() in ("null", "none"))
        if is_null and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(path, inner[0], value)
    if origin is list:
        if isinstance(value, str):
            value = yaml.safe_load(value if value.startswith("[") else f"[{value}]")
        if not isinstance(value, list):
            raise ConfigError(f"{path}: expected a list, got {value!r}")
        return [_coerce(path, args[0], v) for v in value]
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "1", "yes", "on", "false", "0",
                                                        "no", "off"):
            return value.lower() in ("true", "1", "yes", "on")
        raise ConfigError(f"{path}: expected true or false, got {value!r}")
    try:
        if tp is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError
            return int(float(value)) if isinstance(value, str) else int(value)
        if tp is float:
            return float(value)
        if tp is str:
            return str(value)
    except (TypeError, ValueError):
        pass
    else:
        raise ConfigError(f"{path}: unsupported type {tp}")
    raise ConfigError(f"{path}: expected {getattr(tp, '__name__', tp)}, got {value!r}")


def set_field(cfg: Config, dotted: str, value: Any) -> None:
    """Set ``section.field`` (e.g. ``ppo.lr``) with type conversion; ConfigError if unknown."""
    parts = dotted.split(".")
    if len(parts) != 2:
        raise ConfigError(f"{dotted}: expected <section>.<field>, sections: "
                          f"{', '.join(f.name for f in dataclasses.fields(Config))}")
    section_name, name = parts
    sections = {f.name: f for f in dataclasses.fields(Config)}
    if section_name not in sections:
        raise ConfigError(f"{dotted}: unknown section {section_name!r}; allowed: "
                          f"{', '.join(sections)}")
    section = getattr(cfg, section_name)
    hints = typing.get_type_hints(type(section))
    if name not in hints:
        raise ConfigError(f"{dotted}: unknown field; {section_name} has: {', '.join(hints)}")
    setattr(section, name, _coerce(dotted, hints[name], value))


def apply_dict(cfg: Config, data: dict[str, Any]) -> None:
    for section, values in data.items():
        if not isinstance(values, dict):
            raise ConfigError(f"{section}: expected a mapping of fields, got {values!r}")
        for name, value in values.items():
            set_field(cfg, f"{section}.{name}", value)


def load_yaml(path: str | Path) -> dict[str, Any]:
    data = yaml.safe_load(Path(path).read_text()) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of sections")
    return data


def validate(cfg: Config) -> None:
    """Reject bad values before anything starts (ConfigError naming field and allowed values)."""

    def need(ok: bool, path: str, allowed: str, value: Any) -> None:
        if not ok:
            raise ConfigError(f"{path} = {value!r} is invalid; allowed: {allowed}")

    need(cfg.env.name in ENV_NAMES, "env.name", ", ".join(ENV_NAMES), cfg.env.name)
    need(cfg.algo.name in ALGO_NAMES, "algo.name", ", ".join(ALGO_NAMES), cfg.algo.name)
    need(cfg.sdhn.noise in NOISES, "sdhn.noise", ", ".join(NOISES), cfg.sdhn.noise)
    need(cfg.env.reward in MAIF_REWARD_NAMES, "env.reward", ", ".join(MAIF_REWARD_NAMES),
         cfg.env.reward)
    need(cfg.env.features in FEATURES, "env.features", ", ".join(FEATURES), cfg.env.features)
    need(cfg.env.instance_set in ("train", "large"), "env.instance_set", "train, large",
         cfg.env.instance_set)
    positive = {
        "env.num_envs": cfg.env.num_envs, "train.total_steps": cfg.train.total_steps,
        "train.threads": cfg.train.threads, "ppo.rollout_len": cfg.ppo.rollout_len,
        "ppo.epochs": cfg.ppo.epochs, "ppo.num_minibatches": cfg.ppo.num_minibatches,
        "sdhn.num_hyperedges": cfg.sdhn.num_hyperedges,
        "sdhn.generator_hidden": cfg.sdhn.generator_hidden,
        "sdhn.generator_layers": cfg.sdhn.generator_layers,
        "sdhn.hgcn_hidden": cfg.sdhn.hgcn_hidden,
        "sdhn.hgcn_layers": cfg.sdhn.hgcn_layers, "sdhn.state_hidden": cfg.sdhn.state_hidden,
        "actor.gru_hidden": cfg.actor.gru_hidden, "eval.episodes": cfg.eval.episodes,
        "eval.instances": cfg.eval.instances,
        "qmix.buffer_episodes": cfg.qmix.buffer_episodes,
        "qmix.batch_episodes": cfg.qmix.batch_episodes,
        "qmix.updates_per_rollout": cfg.qmix.updates_per_rollout,
        "qmix.learning_starts": cfg.qmix.learning_starts,
        "qmix.target_update_interval": cfg.qmix.target_update_interval,
        "qmix.epsilon_anneal_steps": cfg.qmix.epsilon_anneal_steps,
        "qmix.mixer_embed": cfg.qmix.mixer_embed, "qmix.hypernet_hidden": cfg.qmix.hypernet_hidden,
        "dicg.embed": cfg.dicg.embed, "dicg.gcn_layers": cfg.dicg.gcn_layers,
        "dicg.state_hidden": cfg.dicg.state_hidden,
        "hgcn_mix.num_hyperedges": cfg.hgcn_mix.num_hyperedges,
        "hgcn_mix.hgcn_hidden": cfg.hgcn_mix.hgcn_hidden,
        "hgcn_mix.hgcn_layers": cfg.hgcn_mix.hgcn_layers,
    }
    for path, v in positive.items():
        need(v >= 1, path, "an integer >= 1", v)
    for path, v in {"eval.interval": cfg.eval.interval,
                    "log.checkpoint_interval": cfg.log.checkpoint_interval}.items():
        need(v >= 0, path, "an integer >= 0 (0 = never / end only)", v)
    need(cfg.env.max_steps is None or cfg.env.max_steps >= 1, "env.max_steps",
         "an integer >= 1 or null", cfg.env.max_steps)
    need(cfg.ppo.num_minibatches <= cfg.env.num_envs, "ppo.num_minibatches",
         f"1..env.num_envs ({cfg.env.num_envs})", cfg.ppo.num_minibatches)
    need(all(h >= 1 for h in cfg.actor.hidden_sizes), "actor.hidden_sizes", "widths >= 1",
         cfg.actor.hidden_sizes)
    need(len(cfg.mappo.critic_hidden) >= 1 and all(h >= 1 for h in cfg.mappo.critic_hidden),
         "mappo.critic_hidden", "one or more widths >= 1", cfg.mappo.critic_hidden)
    for path, lr in {"ppo.lr": cfg.ppo.lr, "ppo.critic_lr": cfg.ppo.critic_lr}.items():
        need(lr is None or lr > 0, path, "a number > 0 or null", lr)
    need(0.0 <= cfg.ppo.gamma <= 1.0, "ppo.gamma", "[0, 1]", cfg.ppo.gamma)
    need(0.0 <= cfg.ppo.gae_lambda <= 1.0, "ppo.gae_lambda", "[0, 1]", cfg.ppo.gae_lambda)
    need(0.0 < cfg.ppo.clip < 1.0, "ppo.clip", "(0, 1)", cfg.ppo.clip)
    need(cfg.ppo.entropy_coef >= 0, "ppo.entropy_coef", ">= 0", cfg.ppo.entropy_coef)
    need(cfg.ppo.max_grad_norm > 0, "ppo.max_grad_norm", "> 0", cfg.ppo.max_grad_norm)
    need(cfg.ppo.reward_scale > 0, "ppo.reward_scale", "> 0", cfg.ppo.reward_scale)
    need(cfg.ppo.target_tau is None or 0.0 < cfg.ppo.target_tau <= 1.0, "ppo.target_tau",
         "(0, 1] or null", cfg.ppo.target_tau)
    need(-1.0 < cfg.sdhn.lambda_sk < 1.0, "sdhn.lambda_sk", "(-1, 1) (the range of Sk)",
         cfg.sdhn.lambda_sk)
    need(cfg.sdhn.lambda_cb >= 0.0, "sdhn.lambda_cb", ">= 0", cfg.sdhn.lambda_cb)
    need(cfg.sdhn.tau > 0.0, "sdhn.tau", "> 0", cfg.sdhn.tau)
    for path, eps in {"qmix.epsilon_start": cfg.qmix.epsilon_start,
                      "qmix.epsilon_finish": cfg.qmix.epsilon_finish}.items():
        need(0.0 <= eps <= 1.0, path, "[0, 1]", eps)
    need(cfg.qmix.batch_episodes <= cfg.qmix.buffer_episodes, "qmix.batch_episodes",
         f"1..qmix.buffer_episodes ({cfg.qmix.buffer_episodes})", cfg.qmix.batch_episodes)


def describe() -> str:
    """Every field with its default and help string (for ``--help``)."""
    lines = []
    for sec in dataclasses.fields(Config):
        section = getattr(Config(), sec.name)
        for f in dataclasses.fields(section):
            lines.append(f"  {sec.name}.{f.name} = {getattr(section, f.name)!r}: "
                         f"{f.metadata.get('help', '')}")
    return "\n".join(lines)
