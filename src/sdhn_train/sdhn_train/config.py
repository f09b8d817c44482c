"""Typed training configuration: one dataclass per concern, a help string per field.

The shared sections (``env``, ``algo``, ``actor``, ``train``, ``eval``, ``log``) live in
``sdhn_train.sections``, the PPO learner's (``ppo``) beside it, and one section per algorithm
(``sdhn``, ``mappo``, ``qmix``, ``dicg``, ``hgcn_mix``) in that algorithm's module, collected from
the algorithm registry. ``cfg.section(SDHNConfig)`` is the typed way to one of them (``cfg.sdhn``
also works, untyped).

Load order: defaults <- YAML (``--config``) <- CLI shortcuts (``--env`` ...) <- ``--set a.b=v``,
all through ``sdhn_base.overrides``. ``validate`` runs before anything starts and raises
ConfigError naming the field and the allowed values.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from sdhn_base import overrides, yaml_io
from sdhn_policy.features import TRANSFORMS
from sdhn_sim.envs.conditions import Conditions, ConditionsError, conditions_from_dict
from sdhn_sim.envs.maif import MAIF_REWARDS
from sdhn_sim.envs.registry import TRAINING_SETS, env_names
from sdhn_train.algorithms.registry import ALGO_NAMES, ALGORITHMS, get_algorithm
from sdhn_train.device import DEVICES, PPO_ONLY, cuda_available, resolve_device
from sdhn_train.learners.ppo import PPOConfig
from sdhn_train.sections import (
    ActorConfig,
    AlgoConfig,
    ConfigError,
    EnvConfig,
    EvalConfig,
    LogConfig,
    Section,
    TrainConfig,
    need,
)

__all__ = ["Config", "ConfigError", "apply_dict", "describe", "load_yaml", "set_field",
           "validate"]

SectionT = TypeVar("SectionT")
_BEFORE = ("env", "algo", "actor", "ppo")  # shared sections written before the algorithms'


def _algorithm_sections() -> dict[str, Section]:
    return {a.name: a.config() for a in ALGORITHMS}


@dataclass
class Config:
    env: EnvConfig = field(default_factory=EnvConfig)
    algo: AlgoConfig = field(default_factory=AlgoConfig)
    actor: ActorConfig = field(default_factory=ActorConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    log: LogConfig = field(default_factory=LogConfig)
    algorithms: dict[str, Section] = field(default_factory=_algorithm_sections, repr=False)

    def section(self, cls: type[SectionT]) -> SectionT:
        """The algorithm section of type ``cls`` (e.g. ``cfg.section(SDHNConfig)``)."""
        for s in self.algorithms.values():
            if type(s) is cls and isinstance(s, cls):
                return s
        raise KeyError(f"no config section of type {cls.__name__}")

    def __getattr__(self, name: str) -> object:
        """``cfg.sdhn`` for an algorithm's section (untyped; code uses ``section``)."""
        sections = self.__dict__.get("algorithms", {})
        if name in sections:
            return sections[name]
        raise AttributeError(f"{type(self).__name__} has no attribute or section {name!r}")

    def sections(self) -> dict[str, object]:
        """Every section by its name, in the order they are written."""
        shared = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                  if f.name != "algorithms"}
        first = {k: v for k, v in shared.items() if k in _BEFORE}
        rest = {k: v for k, v in shared.items() if k not in _BEFORE}
        return {**first, **self.algorithms, **rest}

    def to_dict(self) -> dict[str, Any]:
        return {name: dataclasses.asdict(s) for name, s in self.sections().items()
                if dataclasses.is_dataclass(s) and not isinstance(s, type)}


# --- building from YAML / overrides -----------------------------------------------------------


def set_field(cfg: Config, dotted: str, value: Any) -> None:
    """Set ``section.field`` (e.g. ``ppo.lr``) with type conversion; ConfigError if unknown."""
    sections = cfg.sections()
    parts = dotted.split(".")
    if len(parts) != 2:
        raise ConfigError(f"{dotted}: expected <section>.<field>, sections: "
                          f"{', '.join(sections)}")
    section_name, name = parts
    if section_name not in sections:
        raise ConfigError(f"{dotted}: unknown section {section_name!r}; allowed: "
                          f"{', '.join(sections)}")
    if dotted == "train.conditions":  # a mapping, which the override engine does not type
        cfg.train.conditions = _conditions_block(value)
        return
    try:
        overrides.set_field(sections[section_name], name, value, prefix=f"{section_name}.")
    except overrides.OverrideError as e:
        raise ConfigError(str(e)) from None


def apply_dict(cfg: Config, data: dict[str, Any]) -> None:
    for section, values in data.items():
        if not isinstance(values, dict):
            raise ConfigError(f"{section}: expected a mapping of fields, got {values!r}")
        for name, value in values.items():
            set_field(cfg, f"{section}.{name}", value)


_CONDITIONS_ALLOWED = ("allowed: a conditions: mapping (sdhn_sim.envs.conditions), e.g. "
                       "{latency: 1, randomise: true}; {} = the ideal world")


def _conditions_block(value: Any) -> dict[str, Any]:
    """``train.conditions`` from YAML (a mapping) or ``--set`` (its text, YAML flow style)."""
    if isinstance(value, str):
        try:
            value = yaml_io.load_yaml(value, what="train.conditions")
        except yaml_io.YamlError as e:
            raise ConfigError(f"{e}; {_CONDITIONS_ALLOWED}") from None
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"train.conditions = {value!r} is invalid; {_CONDITIONS_ALLOWED}")
    return {str(k): v for k, v in value.items()}


def train_conditions(cfg: Config) -> Conditions:
    """``train.conditions`` validated (ConfigError naming the condition's field)."""
    try:
        return conditions_from_dict(cfg.train.conditions,
                                    maif=cfg.env.name.startswith("maif"))
    except ConditionsError as e:
        raise ConfigError(f"train.{e}") from None


_YAML_ALLOWED = "allowed: a YAML file holding {section: {field: value}}"


def load_yaml(path: str | Path) -> dict[str, Any]:
    """A YAML mapping; ConfigError (one line) for a missing, unreadable, binary or malformed
    file, a key given twice or an alias bomb (``sdhn_base.yaml_io``)."""
    try:
        data = yaml_io.load_yaml(Path(path), what="config") or {}
    except yaml_io.YamlError as e:
        raise ConfigError(f"{e}; {_YAML_ALLOWED}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of sections")
    return data


def validate(cfg: Config, resuming: bool = False) -> None:
    """Reject bad values before anything starts (ConfigError naming field and allowed values).
    ``resuming``: the weights come from a checkpoint, so ``actor.init_from`` need not exist."""
    envs = env_names()
    need(cfg.env.name in envs, "env.name", ", ".join(envs), cfg.env.name)
    need(cfg.algo.name in ALGO_NAMES, "algo.name", ", ".join(ALGO_NAMES), cfg.algo.name)
    need(cfg.env.reward in MAIF_REWARDS, "env.reward", ", ".join(MAIF_REWARDS), cfg.env.reward)
    features = ("auto", *TRANSFORMS)
    need(cfg.env.features in features, "env.features", ", ".join(features), cfg.env.features)
    need(cfg.env.instance_set in TRAINING_SETS, "env.instance_set", ", ".join(TRAINING_SETS),
         cfg.env.instance_set)
    positive = {
        "env.num_envs": cfg.env.num_envs, "train.total_steps": cfg.train.total_steps,
        "train.threads": cfg.train.threads, "train.learner_processes": cfg.train.learner_processes,
        "eval.episodes": cfg.eval.episodes, "eval.instances": cfg.eval.instances,
    }
    for path, v in positive.items():
        need(v >= 1, path, "an integer >= 1", v)
    need(cfg.actor.gru_hidden >= 0, "actor.gru_hidden", "an integer >= 0 (0 = feed-forward)",
         cfg.actor.gru_hidden)
    for path, v in {"train.seed": cfg.train.seed, "eval.seed": cfg.eval.seed}.items():
        need(0 <= v < 2**32, path, "an integer in 0..2**32-1", v)
    need(cfg.train.device in DEVICES, "train.device", ", ".join(DEVICES), cfg.train.device)
    need(cfg.train.device != "cuda" or cuda_available(), "train.device",
         "cpu or auto (torch sees no CUDA GPU here)", cfg.train.device)
    on_cpu = resolve_device(cfg.train.device).type == "cpu"
    need(on_cpu or get_algorithm(cfg.algo.name).data_parallel, "train.device",
         f"cpu for {cfg.algo.name} (another device is for {PPO_ONLY})", cfg.train.device)
    need(on_cpu or cfg.train.learner_processes == 1, "train.device",
         "cpu when train.learner_processes > 1 (the ranks average gradients on the CPU)",
         cfg.train.device)
    cfg.ppo.validate()
    train_conditions(cfg)
    for section in cfg.algorithms.values():
        section.validate()
    for path, v in {"eval.interval": cfg.eval.interval,
                    "log.checkpoint_interval": cfg.log.checkpoint_interval}.items():
        need(v >= 0, path, "an integer >= 0 (0 = never / end only)", v)
    need(all(isinstance(m, int) and not isinstance(m, bool) and m >= 1
             for m in cfg.log.actor_marks), "log.actor_marks",
         "a list of integers >= 1 (team env-steps)", cfg.log.actor_marks)
    need(cfg.log.keep_checkpoints >= 0, "log.keep_checkpoints", "an integer >= 0 (0 = keep all)",
         cfg.log.keep_checkpoints)
    need(cfg.env.max_steps is None or cfg.env.max_steps >= 1, "env.max_steps",
         "an integer >= 1 or null", cfg.env.max_steps)
    need(cfg.ppo.num_minibatches <= cfg.env.num_envs, "ppo.num_minibatches",
         f"1..env.num_envs ({cfg.env.num_envs})", cfg.ppo.num_minibatches)
    _validate_learner_processes(cfg)
    # The run directory is <log.root>/<log.run_name>: a name with a separator or "." / ".."
    # would put the run (and what a resume cuts back) outside the root.
    need(cfg.log.run_name in ("", None) or ("/" not in cfg.log.run_name
                                            and "\\" not in cfg.log.run_name
                                            and cfg.log.run_name not in (".", "..")
                                            and "\x00" not in cfg.log.run_name),
         "log.run_name", "one directory name (no / or \\, not . or ..)", cfg.log.run_name)
    need(math.isfinite(cfg.actor.init_temperature) and cfg.actor.init_temperature > 0,
         "actor.init_temperature", "a finite number > 0 (1 = the loaded actor unchanged)",
         cfg.actor.init_temperature)
    need(all(h >= 1 for h in cfg.actor.hidden_sizes), "actor.hidden_sizes", "widths >= 1",
         cfg.actor.hidden_sizes)
    # A missing warm-start file is refused here, not after the environments are built.
    if cfg.actor.init_from is not None and not resuming:
        init = Path(cfg.actor.init_from)
        need(init.is_file() and init.with_suffix(".json").is_file(), "actor.init_from",
             "an exported actor: a .safetensors file beside its .json (relative paths from "
             "the current directory)", cfg.actor.init_from)


def _validate_learner_processes(cfg: Config) -> None:
    """K > 1 splits every minibatch into K equal shares (so the averaged gradient is the whole
    minibatch's) and issues collectives in one fixed order (so no second thread may)."""
    k = cfg.train.learner_processes
    if k == 1:
        return
    b = cfg.env.num_envs
    need(b % k == 0, "train.learner_processes", f"a divisor of env.num_envs ({b})", k)
    serial = [a.name for a in ALGORITHMS if not a.data_parallel]
    need(get_algorithm(cfg.algo.name).data_parallel, "train.learner_processes",
         f"1 for {', '.join(serial)} (no data-parallel learner)", k)
    need((b // k) % cfg.ppo.num_minibatches == 0, "ppo.num_minibatches",
         f"a divisor of env.num_envs / train.learner_processes ({b // k}) when "
         "train.learner_processes > 1", cfg.ppo.num_minibatches)
    need(not cfg.ppo.concurrent_actor_critic, "ppo.concurrent_actor_critic",
         "false when train.learner_processes > 1", cfg.ppo.concurrent_actor_critic)


def describe() -> str:
    """Every field with its default and help string (for ``--help``)."""
    lines = []
    for name, section in Config().sections().items():
        if not dataclasses.is_dataclass(section):
            continue
        for f in dataclasses.fields(section):
            lines.append(f"  {name}.{f.name} = {getattr(section, f.name)!r}: "
                         f"{f.metadata.get('help', '')}")
    return "\n".join(lines)
