"""``deploy.json``: how to deploy a shipped policy, as data precise enough to re-implement.

``actor.onnx.json`` says what the graph computes (inputs, outputs, the action map, the GRU
state). ``deploy.json`` beside it says the rest a deployment needs, so a C++ or plain-NumPy user
reproduces the project's deployed behaviour from the two JSON files and ``actor.onnx`` alone
(``examples/onnx_reference/run_policy.py`` does, and a test holds it to the project's runtime):

- ``observation``: the layout of the input floats: each coordinate's name, meaning and scaling;
  the local window's size, order and cell encoding (MAIF, docs/maif.md); RWARE's is rware's own;
- ``mode``: the deployment mode chosen on the model's card (greedy; greedy with stall breaking and
  the rule's parameters; or sampling at a temperature), with the success the card measured for
  that mode where it did;
- ``action_selection``: argmax and sampling exactly as :mod:`sdhn_policy.actor_runtime` does
  them (the float32 log-softmax, inverse-CDF sampling in float64, one uniform per sampled step
  from a per-robot NumPy generator seeded ``[seed, robot_id]``);
- ``stall_breaking``: :mod:`sdhn_policy.stall_breaker` as state, constants and an ordered list of
  update steps;
- ``final_approach`` (where the card's mode includes it, ``heldout_large.deploy.final_approach``,
  always with stall breaking): :mod:`sdhn_policy.final_approach`, the capture, path and hold rule,
  as constants and an ordered list of steps;
- ``dead_reckoning`` (where the card's mode includes it, ``heldout_large.deploy.dead_reckoning``):
  :mod:`sdhn_policy.dead_reckoning`, the rule that moves an observation lagging behind the robot's
  own actions forward by them, in words precise enough to re-implement.

Written by ``scripts/export_onnx.py`` (and ``scripts/ship_model.py``) from the weights and the
model's ``card.json``; never by hand.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from sdhn_policy.dead_reckoning import HORIZON, OBSTACLE
from sdhn_policy.final_approach import CENTRE_INDEX, FREE_CELL, STAY, FinalApproach
from sdhn_policy.stall_breaker import _EPS, _NEIGHBOURS, ROBOT_CELL, StallRule
from sdhn_policy.weights import ActorSpec, atomic_write_bytes
from sdhn_sim.envs.maif import ACTION_DELTAS, COORD_FEATURES, OBS_SIZE, RADIUS, WINDOW

DEPLOY_CONTRACT_VERSION = 1
FILE_NAME = "deploy.json"
COORDINATES = [  # MAIF's first 8 floats, in order (sdhn_sim.envs.maif)
    ("x", "own column"), ("y", "own row"),
    ("mean_x", "team centroid column (mean over robots)"), ("mean_y", "team centroid row"),
    ("goal_x", "own goal column"), ("goal_y", "own goal row"),
    ("mean_goal_x", "goal centroid column (mean over the robots' goals)"),
    ("mean_goal_y", "goal centroid row"),
]


def maif_observation() -> dict[str, Any]:
    """The 57 floats of a MAIF observation (docs/maif.md)."""
    centre = RADIUS * WINDOW + RADIUS
    return {
        "size": OBS_SIZE,
        "dtype": "float32",
        "coordinates": [{"index": i, "name": n, "meaning": m,
                         "scaling": "cell index / (grid_size - 1), in [0, 1]"}
                        for i, (n, m) in enumerate(COORDINATES)],
        "axes": "x = column, 0 at the left; y = row, 0 at the top (action 'up' is y - 1)",
        "window": {
            "offset": COORD_FEATURES,
            "size": WINDOW,
            "radius": RADIUS,
            "order": "row-major: index = offset + (dy + radius) * size + (dx + radius) for the "
                     "cell at (x + dx, y + dy), dy and dx from -radius to +radius",
            "centre_index": COORD_FEATURES + centre,
            "cells": {"0": "free (also the robot's own centre cell)",
                      "1": "obstacle, or outside the grid",
                      "2": "another robot"},
        },
        "features_inside_graph": "maif-ego/1 (the ONNX graph computes it: feed the raw floats)",
    }


def rware_observation(spec: ActorSpec) -> dict[str, Any]:
    return {"size": spec.obs_size, "dtype": "float32",
            "layout": "rware 2.0.0's flattened vector observation of one agent, unchanged "
                      "(docs/rware.md); features identity"}


def stall_mode_name(rule: StallRule, final_approach: bool = False) -> str:
    """The name of greedy play with stall breaking (and the final approach) under which cards
    (``heldout_large.modes``) and evaluations record its measured figures."""
    return f"greedy, stall breaking {rule.text()}" + (", final approach" if final_approach else "")


def stall_breaking(rule: StallRule) -> dict[str, Any]:
    """:class:`sdhn_policy.stall_breaker.StallBreaker` for one robot, as data."""
    return {
        "parameters": {"calm_steps": rule.calm_steps, "progress_steps": rule.progress_steps,
                       "sample_steps": rule.sample_steps, "temperature": rule.temperature},
        "constants": {"robot_cell": ROBOT_CELL, "eps": _EPS,
                      "position_indices": [0, 1], "goal_indices": [4, 5],
                      "neighbour_indices": [int(i) for i in _NEIGHBOURS],
                      "neighbours": "window cells left, right, above, below the robot"},
        "state": {"last_obs": "none", "calm": 0, "best": "+infinity (float64)",
                  "no_progress": 0, "left": 0},
        "reset": "every field to its initial value at an episode's first observation (step 0)",
        "update": [
            "calm = calm + 1 if last_obs is not none and all 57 floats of obs equal last_obs "
            "exactly, else 0; then last_obs = obs",
            "dist = |obs[0] - obs[4]| + |obs[1] - obs[5]| (float32)",
            "off_goal = dist > eps",
            "improved = dist < best - eps; best = min(best, dist)",
            "no_progress = 0 if improved else no_progress + 1",
            "neighbour = any(obs[i] == robot_cell for i in neighbour_indices)",
            "stalled = (calm >= calm_steps and neighbour) or "
            "(no_progress >= progress_steps and off_goal)",
            "if stalled and left == 0: left = sample_steps",
            "sample = left > 0; left = max(left - 1, 0)",
            "if sample: this step's action is sampled at parameters.temperature, else argmax",
        ],
        "order": "update runs on every observation of the episode, before the action is chosen",
    }


def final_approach(env: str) -> dict[str, Any]:
    """:class:`sdhn_policy.final_approach.FinalApproach` for one robot of MAIF task ``env``, as
    data (ValueError for a task that is not a MAIF grid)."""
    rule = FinalApproach.for_env(env)
    return {
        "constants": {"grid_size": rule.size, "position_indices": [0, 1], "goal_indices": [4, 5],
                      "centre_index": CENTRE_INDEX, "window_size": WINDOW, "radius": RADIUS,
                      "free_cell": FREE_CELL, "stay": STAY,
                      "action_deltas (dx, dy)": {str(a): [int(v) for v in d]
                                                 for a, d in enumerate(ACTION_DELTAS)}},
        "state": "none: each step is decided from that step's observation and stall breaking's "
                 "sample flag",
        "update": [
            "(dx, dy) = round((obs[4:6] - obs[0:2]) * (grid_size - 1)), the difference in "
            "float32, rounded to the nearest integer: the goal's offset in cells",
            "capture: if |dx| + |dy| == 1 and obs[centre_index + dx + dy * window_size] == "
            "free_cell: action = the action whose delta is (dx, dy) (also on a step stall "
            "breaking samples)",
            "hold: else if dx == 0 and dy == 0 and stall breaking does not sample this step: "
            "action = stay",
            "path: else if |dx| + |dy| >= 2 and max(|dx|, |dy|) <= radius and stall breaking "
            "does not sample this step: D = the breadth-first distance from the goal cell "
            "(window cell (dx, dy), only if free) over the window's free cells, 4-connected, "
            "the robot's own cell counting as free; if the robot's cell has a distance D, "
            "action = the first of up, down, left, right whose neighbour cell has distance D - 1",
            "else: the action chosen (argmax, or drawn where stall breaking samples)",
        ],
        "order": "after stall breaking's update and the action choice, on every observation",
    }


def action_selection() -> dict[str, Any]:
    """:func:`sdhn_policy.actor_runtime.choose_actions` and the actor's generator, as data."""
    return {
        "log_softmax": "float32: z = logits - max(logits); logp = z - log(sum(exp(z)))",
        "greedy": "argmax(logp), the first index on ties",
        "sampled": [
            "lp = float64(logp)",
            "if temperature != 1: lp = lp / temperature; lp = lp - max(lp)",
            "cdf = cumsum(exp(lp)); u = U * cdf[-1] with U uniform in [0, 1)",
            "action = min(count(cdf < u), num_actions - 1)",
        ],
        "random_stream": "one generator per robot: numpy.random.default_rng([seed, robot_id]) "
                         "(PCG64); one .random() draw per sampled step, none on argmax steps",
        "recurrent_state": "hidden = zeros at an episode's first step; then hidden_out",
    }


def card_dead_reckoning(card: dict[str, Any] | None) -> bool:
    """Whether the card's deployment mode includes dead reckoning (``heldout_large.deploy``'s
    ``dead_reckoning`` on a MAIF card, ``deploy``'s on a card without that set: RWARE; False
    where the card says nothing). The launcher deploys it from here."""
    c = card or {}
    chosen = (c.get("heldout_large") or {}).get("deploy") or c.get("deploy") or {}
    return bool(chosen.get("dead_reckoning", False))


def dead_reckoning() -> dict[str, Any]:
    """:class:`sdhn_policy.dead_reckoning.DeadReckoner` for one robot, as data."""
    return {
        "input": "RobotObservation.obs_age: the robot's actions for steps step - obs_age .. "
                 "step - 1 are not yet reflected in the observation (0 = current)",
        "state": "the (step, action) of every action sent this episode, at most horizon kept; "
                 "cleared at an episode's first observation",
        "constants": {"horizon": HORIZON, "obstacle": OBSTACLE, "action_deltas (dx, dy)":
                      {str(a): [int(v) for v in d] for a, d in enumerate(ACTION_DELTAS)}},
        "update": [
            "unseen = the sent actions whose step is >= step - obs_age, oldest first",
            "cell = round(obs[0:2] * (grid_size - 1)); offset = (0, 0)",
            "for each unseen action: target = offset + delta; it is taken unless the window cell "
            "at target (relative to the observed centre) is an obstacle or cell + target is off "
            "the grid",
            "if offset != (0, 0): obs[0:2] = (cell + offset) / (grid_size - 1); the window "
            "shifts by offset (cells coming into view: 0 on the grid, 1 beyond its edge; the "
            "centre cell 0); goals and centroids stay as observed",
            "after acting: append (step, action sent; 0 when no action was sent)",
        ],
        "order": "runs before stall breaking and the policy, on every observation",
    }


def card_mode(card: dict[str, Any] | None) -> dict[str, Any]:
    """The deployment mode the card chose (``heldout_large.deploy``), with the measured success
    of that mode where the card has it; greedy where the card chose none."""
    large = (card or {}).get("heldout_large") or {}
    chosen = large.get("deploy")
    if not chosen:
        return {"kind": "greedy", "greedy": True, "temperature": 1.0, "break_stalls": False,
                "dead_reckoning": False,
                "source": "default (the card measures greedy play and chooses no other mode)"}
    greedy = bool(chosen.get("greedy", True))
    breaks = bool(chosen.get("break_stalls", False)) and greedy
    temperature = float(chosen.get("temperature", 1.0))
    mode: dict[str, Any] = {"greedy": greedy, "temperature": temperature, "break_stalls": breaks,
                            "dead_reckoning": card_dead_reckoning(card),
                            "source": "card.json heldout_large.deploy"}
    if breaks:
        rule = StallRule.parse(chosen["stall_rule"]) if chosen.get("stall_rule") else StallRule()
        mode.update(kind="greedy_with_stall_breaking", stall_rule=rule.text())
        approach = bool(chosen.get("final_approach", False))
        if approach:  # the key only where it is on: earlier contracts stay as they were
            mode["final_approach"] = True
        measured_name = stall_mode_name(rule, approach)
    elif greedy:
        mode["kind"] = "greedy"
        measured_name = "greedy"
    else:
        mode["kind"] = "sampled"
        measured_name = f"sampled at T={temperature:g}"
    measured = (large.get("modes") or {}).get(measured_name)
    if measured:
        mode["measured"] = {"set": large.get("set"), "instances": large.get("instances"),
                            "success_rate": measured["success_rate"],
                            "success_ci95_maps": measured["success_ci95_maps"]}
    return mode


def deploy_contract(spec: ActorSpec, family: str, card: dict[str, Any] | None,
                    env: str | None = None) -> dict[str, Any]:
    mode = card_mode(card)
    contract: dict[str, Any] = {
        "deploy_contract_version": DEPLOY_CONTRACT_VERSION,
        "model": "actor.onnx",
        "io_contract": "actor.onnx.json",
        "env": env or (card or {}).get("env"),
        "observation": maif_observation() if family == "maif" else rware_observation(spec),
        "mode": mode,
        "action_selection": action_selection(),
    }
    if mode["break_stalls"]:
        contract["stall_breaking"] = stall_breaking(StallRule.parse(mode["stall_rule"]))
    if mode.get("final_approach"):
        contract["final_approach"] = final_approach(str(contract["env"]))
    if mode["dead_reckoning"]:
        contract["dead_reckoning"] = dead_reckoning()
    return contract


def write_deploy_json(model_dir: Path, spec: ActorSpec, family: str) -> Path:
    """``deploy.json`` into a model folder, from its ``card.json`` (atomically)."""
    card_path = model_dir / "card.json"
    card = json.loads(card_path.read_text()) if card_path.exists() else None
    out = model_dir / FILE_NAME
    text = json.dumps(deploy_contract(spec, family, card), indent=2) + "\n"
    atomic_write_bytes(out, text.encode())
    os.chmod(out, 0o644)
    return out
