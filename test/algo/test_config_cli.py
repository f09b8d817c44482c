"""Configuration: YAML + CLI overrides, validation errors with exit code 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from sdhn_train import cli
from sdhn_train.algorithms.mappo import MAPPO
from sdhn_train.algorithms.sdhn import SDHN
from sdhn_train.config import Config, ConfigError, set_field, validate
from sdhn_train.learners.ppo import resolve_ppo


def test_defaults_are_valid_and_resolve_per_algorithm() -> None:
    cfg = Config()
    validate(cfg)
    sdhn = resolve_ppo(cfg.ppo, SDHN.default_lr, SDHN.default_target_tau)
    mappo = resolve_ppo(cfg.ppo, MAPPO.default_lr, MAPPO.default_target_tau)
    assert (sdhn.lr, sdhn.target_tau) == (6e-4, 0.01)
    assert (mappo.lr, mappo.critic_lr, mappo.target_tau) == (3e-4, 3e-4, 1.0)


def test_yaml_then_shortcuts_then_set(tmp_path: Path) -> None:
    y = tmp_path / "exp.yaml"
    y.write_text("env: {name: maif-16, num_envs: 8}\nppo: {lr: 0.001}\nsdhn: {skew_loss: false}\n")
    args = cli.build_parser().parse_args(
        ["--config", str(y), "--env", "maif-20", "--seed", "3", "--set", "ppo.lr=3e-4",
         "--set", "actor.hidden_sizes=[32,32]", "--set", "ppo.critic_lr=null"])
    cfg = cli.config_from_args(args)
    assert cfg.env.name == "maif-20" and cfg.env.num_envs == 8 and cfg.train.seed == 3
    assert cfg.ppo.lr == 3e-4 and cfg.ppo.critic_lr is None and cfg.sdhn.skew_loss is False
    assert cfg.actor.hidden_sizes == [32, 32]
    assert Config().actor.hidden_sizes == [64], "list defaults must not be shared"


@pytest.mark.parametrize(("argv", "field", "allowed"), [
    (["--env", "maif-11"], "env.name", "maif-10"),
    (["--algo", "qmix2"], "algo.name", "sdhn, mappo"),
    (["--total-steps", "-5"], "train.total_steps", ">= 1"),
    (["--set", "sdhn.num_hyperedges=0"], "sdhn.num_hyperedges", ">= 1"),
    (["--set", "sdhn.lambda_sk=1.5"], "sdhn.lambda_sk", "(-1, 1)"),
    (["--set", "sdhn.lambda_cb=-1"], "sdhn.lambda_cb", ">= 0"),
    (["--set", "sdhn.noise=gauss"], "sdhn.noise", "logistic, gumbel_paper"),
    (["--set", "ppo.clip=2"], "ppo.clip", "(0, 1)"),
    (["--set", "ppo.nope=1"], "ppo.nope", "ppo has"),
    (["--set", "bogus.x=1"], "bogus.x", "allowed"),
    (["--set", "ppo.epochs=two"], "ppo.epochs", "expected int"),
    (["--set", "sdhn.skew_loss=maybe"], "sdhn.skew_loss", "true or false"),
])
def test_invalid_config_exits_2_naming_field(argv: list[str], field: str, allowed: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert field in err and allowed in err, err


def test_print_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--algo", "mappo", "--print-config"]) == 0
    assert "name: mappo" in capsys.readouterr().out


def test_set_field_rejects_bad_path() -> None:
    with pytest.raises(ConfigError, match="section"):
        set_field(Config(), "lr", 1)
