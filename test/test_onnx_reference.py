"""The reference deployment outside the packages (examples/onnx_reference/run_policy.py: NumPy,
onnxruntime and the model folder's JSON only) against the project's own actor: the per-robot
``ActorCore`` with the NumPy runtime, as every actor process runs it, in the mode the model's
card chose. Same instances, same seeds: the same action for every robot at every step, so the
same outcomes. Also: ``deploy.json`` is what the export writes from the card (not hand-edited)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from sdhn_policy.actor_core import ActorCore, Decision
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_contract import FILE_NAME, deploy_contract
from sdhn_policy.final_approach import FinalApproach
from sdhn_policy.stall_breaker import StallRule
from sdhn_sim.envs.maif_scripted import GreedyPolicy
from sdhn_sim.envs.pettingzoo_env import parallel_env

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "examples" / "onnx_reference" / "run_policy.py"


def reference() -> ModuleType:
    spec = importlib.util.spec_from_file_location("run_policy", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def project_team(model: Path, n: int, seed: int) -> list[ActorCore]:
    """The robots as the launcher deploys them with the card's mode (deploy.json's source)."""
    mode = deploy_contract(ActorRuntime.from_file(model / "actor.safetensors").spec, "maif",
                           json.loads((model / "card.json").read_text()))["mode"]
    rule = StallRule.parse(mode["stall_rule"]) if mode["break_stalls"] else None
    card = json.loads((model / "card.json").read_text())
    approach = FinalApproach.for_env(card["env"]) if mode.get("final_approach") else None
    rt = ActorRuntime.from_file(model / "actor.safetensors")
    return [ActorCore(i, n, bool(mode["greedy"]), seed, rt, temperature=mode["temperature"],
                      stall_rule=rule, approach=approach) for i in range(n)]


def play_project(env: Any, cores: list[ActorCore]) -> tuple[list[np.ndarray], dict[str, Any]]:
    obs, _ = env.reset()
    taken, step = [], 0
    while True:
        decisions = [c.on_obs(0, step, i, len(cores), obs[a])
                     for i, (c, a) in enumerate(zip(cores, env.possible_agents, strict=True))]
        assert all(isinstance(d, Decision) for d in decisions), decisions
        joint = np.array([d.action for d in decisions if isinstance(d, Decision)])
        taken.append(joint)
        obs, _r, _t, _tr, infos = env.step({a: int(joint[i])
                                            for i, a in enumerate(env.possible_agents)})
        step += 1
        if not env.agents:
            return taken, infos[env.possible_agents[0]]["episode"]


@pytest.mark.parametrize(("model", "instances"), [
    ("maif-10-sdhn", [0, 1, 2, 3]),   # greedy with stall breaking 2,10,2
    ("maif-20-sdhn", [0]),            # sampled at T = 0.25
    ("maif-tiny-sdhn", [0, 1]),       # sampled at T = 1
])
def test_reference_takes_the_project_actors_actions(model: str, instances: list[int]) -> None:
    run_policy = reference()
    folder = REPO / "models" / model
    contract = json.loads((folder / FILE_NAME).read_text())
    sampled = 0
    for k in instances:
        make = dict(seed=5, instance_set="heldout_large", instance_order="round_robin",
                    instance_ids=[k])
        env_a, env_b = parallel_env(contract["env"], **make), parallel_env(contract["env"], **make)
        n = len(env_a.possible_agents)
        ours, ours_episode = play_project(env_a, project_team(folder, n, seed=11))
        team = run_policy.DeployedTeam(folder, n, seed=11)
        theirs, their_episode = run_policy.run_episode(env_b, team)
        assert len(ours) == len(theirs), (model, k, len(ours), len(theirs))
        for t, (a, b) in enumerate(zip(ours, theirs, strict=True)):
            assert np.array_equal(a, b), f"{model} instance {k} step {t}: {a} vs {b}"
        assert ours_episode == their_episode, (ours_episode, their_episode)
        sampled += team.sampled
    if not contract["mode"]["greedy"]:
        assert sampled > 0, "no sampled step: the comparison of random streams proved nothing"


def test_stall_rule_in_the_reference_matches_the_breaker_on_random_play() -> None:
    """The stall rule alone, on observations where it fires often (random moves of maif-10):
    the reference's per-robot rule says 'sample' exactly when StallBreaker does."""
    from sdhn_policy.stall_breaker import StallBreaker

    run_policy = reference()
    spec = json.loads((REPO / "models" / "maif-10-sdhn" / FILE_NAME).read_text())["stall_breaking"]
    env = parallel_env("maif-10", seed=3, instance_set="heldout_large")
    rng = np.random.default_rng(0)
    obs, _ = env.reset()
    n = len(env.possible_agents)
    breaker = StallBreaker(StallRule.parse("2,10,2"), n)
    rules = [run_policy.StallRule(spec) for _ in range(n)]
    fired = 0
    for _ in range(200):
        o = np.stack([obs[a] for a in env.possible_agents])
        want = breaker.update(o)
        got = np.array([r.update(o[i]) for i, r in enumerate(rules)])
        assert np.array_equal(want, got)
        fired += int(want.sum())
        # mostly stay: robots stand still beside each other, the rule's first trigger
        joint = np.where(rng.random(n) < 0.8, 0, rng.integers(0, 5, n))
        obs, *_rest = env.step({a: int(joint[i]) for i, a in enumerate(env.possible_agents)})
        if not env.agents:
            obs, _ = env.reset()
            breaker.reset()
            for r in rules:
                r.reset()
    assert fired > 0, "the rule never fired: the comparison proved nothing"


def final_approach_model(tmp_path: Path, env: str = "maif-10") -> Path:
    """maif-10-sdhn's folder with a card that deploys stall breaking 2,10,2 and the final
    approach on ``env``, and the deploy.json the export writes from it."""
    import shutil

    from sdhn_policy.deploy_contract import write_deploy_json

    folder = tmp_path / "model"
    shutil.copytree(REPO / "models" / "maif-10-sdhn", folder)
    card = json.loads((folder / "card.json").read_text())
    card["env"] = env
    card["heldout_large"]["deploy"] = {"greedy": True, "temperature": 1.0, "break_stalls": True,
                                       "stall_rule": "2,10,2", "final_approach": True}
    (folder / "card.json").write_text(json.dumps(card))
    write_deploy_json(folder, ActorRuntime.from_file(folder / "actor.safetensors").spec, "maif")
    return folder


def test_final_approach_round_trip_through_deploy_json(tmp_path: Path) -> None:
    """The rule as deploy.json states it: the reference re-implements it from the data and
    takes the project's actors' actions step for step (maif-10's actor on maif-16, where its
    robots need the rule), and its per-robot rule equals FinalApproach on real observations."""
    run_policy = reference()
    folder = final_approach_model(tmp_path, "maif-16")
    contract = json.loads((folder / FILE_NAME).read_text())
    assert contract["mode"]["final_approach"] is True
    assert contract["final_approach"]["constants"]["grid_size"] == 48
    make = dict(seed=5, instance_set="heldout", instance_order="round_robin", instance_ids=[0],
                max_steps=120)
    env_a, env_b = parallel_env("maif-16", **make), parallel_env("maif-16", **make)
    n = len(env_a.possible_agents)
    ours, _ = play_project(env_a, project_team(folder, n, seed=11))
    theirs, _ = run_policy.run_episode(env_b, run_policy.DeployedTeam(folder, n, seed=11))
    for t, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        assert np.array_equal(a, b), f"step {t}: {a} vs {b}"
    # the rule alone, where it fires often: random actions and sampling flags
    rule, theirs_rule = FinalApproach(48), run_policy.FinalApproach(contract["final_approach"])
    env = parallel_env("maif-16", seed=1, instance_set="heldout")
    obs, _ = env.reset()
    rng = np.random.default_rng(0)
    walker = GreedyPolicy(0)
    changed = 0
    for _ in range(150):
        o = np.stack([obs[a] for a in env.possible_agents])
        act, sampled = rng.integers(0, 5, n), rng.random(n) < 0.3
        want = rule.apply(o, act, sampled)
        got = [theirs_rule.apply(o[i], int(act[i]), bool(sampled[i])) for i in range(n)]
        assert want.tolist() == got
        changed += int(np.sum(want != act))
        # the scripted walker mostly, so that robots arrive and stand on their goals
        joint = np.where(rng.random(n) < 0.8, walker.act(o), rng.integers(0, 5, n))
        obs, *_rest = env.step({a: int(joint[i]) for i, a in enumerate(env.possible_agents)})
        if not env.agents:
            obs, _ = env.reset()
    assert changed > 0, "the rule never fired: the comparison proved nothing"


def test_deploy_json_is_the_exports_output() -> None:
    """Every shipped deploy.json equals what sdhn_policy.deploy_contract writes from the card."""
    for folder in sorted((REPO / "models").iterdir()):
        path = folder / FILE_NAME
        if not path.exists():
            continue
        spec = ActorRuntime.from_file(folder / "actor.safetensors").spec
        family = "maif" if spec.obs_size == 57 else "rware"
        card = json.loads((folder / "card.json").read_text())
        assert json.loads(path.read_text()) == deploy_contract(spec, family, card), folder.name


def test_script_prints_success_with_an_interval() -> None:
    done = subprocess.run([sys.executable, str(SCRIPT), "models/maif-10-sdhn", "--instances",
                           "2", "--seed", "1"], capture_output=True, text=True, timeout=300,
                          check=False, cwd=REPO)
    assert done.returncode == 0, done.stderr
    assert "mode greedy_with_stall_breaking: success" in done.stdout, done.stdout
