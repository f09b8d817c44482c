"""The arrival probe: a policy's probabilities on its goal and one cell from it, per side."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sdhn_experiments import arrival_probe
from sdhn_policy.actor_runtime import ActorRuntime

MODEL = Path("models/maif-10-sdhn")


def test_a_trained_actor_stays_on_and_steps_onto_its_goal():
    """The shipped maif-10 policy completes its own task: robots on their goals stay and robots
    one cell from a free goal step onto it. A wrong side-to-action mapping, a goal counted as
    free while occupied, or probabilities at the wrong temperature read far lower."""
    policy = ActorRuntime.from_file(MODEL / "actor.safetensors")
    p = arrival_probe.probe(policy, "maif-10", "heldout", instances=4, steps=120)
    s = p.summary()
    assert p.completed >= 3, s
    on, one = s["on_goal"], s["one_away"]
    assert isinstance(on, dict) and isinstance(one, dict)
    assert on["robot_steps"] > 50 and on["p_stay"] > 0.9, s
    assert one["all"]["robot_steps"] == sum(one[k]["robot_steps"] for k in arrival_probe.SIDES)
    assert one["all"]["robot_steps"] > 10 and one["all"]["p_onto_goal"] > 0.8, s
    # at a higher temperature the same states read lower: the figures are the play's own
    hot = arrival_probe.probe(policy, "maif-10", "heldout", instances=4, steps=120,
                              temperature=4.0).summary()["on_goal"]
    assert isinstance(hot, dict) and hot["p_stay"] < on["p_stay"], (hot, on)


def test_a_finished_episode_stops_counting():
    """Robots of an episode that completed are not probed on the instance the env starts next."""
    policy = ActorRuntime.from_file(MODEL / "actor.safetensors")
    short = arrival_probe.probe(policy, "maif-10", "heldout", instances=2, steps=400)
    assert short.completed == 2
    # every step after completion would add 10 on-goal robot-steps per env: bounded by the
    # steps the two episodes took
    assert short.on_goal.count < 2 * 10 * 400


def test_cli_writes_json_and_refuses_bad_input(tmp_path, capsys):
    out = tmp_path / "probe.json"
    assert arrival_probe.main([str(MODEL), "--instances", "2", "--steps", "30",
                               "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["actor"] == "maif-10-sdhn" and data["task"] == "maif-10"
    assert np.isfinite(data["on_goal"]["p_stay"] or 0.0)
    for bad, says in ((["--instances", "0"], "instances: 0; allowed: 1..100"),
                      (["--steps", "0"], "steps: 0; allowed"),
                      (["--temperature", "0"], "temperature must be a finite number > 0")):
        assert arrival_probe.main([str(MODEL), *bad]) == 2
        assert says in capsys.readouterr().err


@pytest.mark.parametrize("task", ["rware-3"])
def test_cli_refuses_a_task_that_is_not_maif(task, capsys):
    assert arrival_probe.main([str(MODEL), "--task", task]) == 2
    assert "is not a MAIF task" in capsys.readouterr().err
