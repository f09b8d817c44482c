"""One enumeration of drop kinds: what the simulator's lock-step core, an actor's core, a weights
check and the trainer's assembler drop is a ``DropKind``, written to status files by value."""

from __future__ import annotations

import json

import pytest

from sdhn_base.drops import DESCRIPTIONS, DropKind, describe
from sdhn_policy.weights import (
    BadTensorsError,
    IncompatibleWeightsError,
    OversizedPayloadError,
    Sha256MismatchError,
    UnknownFormatError,
    WeightsError,
)
from sdhn_sim.lockstep import LockstepSim, SimConfig

from .test_transitions import assembler, feed, script


def test_every_kind_is_described_and_logged_by_its_value() -> None:
    assert set(DESCRIPTIONS) == set(DropKind), set(DropKind) ^ set(DESCRIPTIONS)
    assert describe(DropKind.STALE_STEP).startswith("stale_step (")
    assert describe("not_a_kind") == "not_a_kind"


def test_status_files_and_log_lines_name_drops_by_value() -> None:
    counts = {DropKind.STALE_STEP: 2, DropKind.LEARNER_BUSY: 1}
    assert json.loads(json.dumps({"dropped": counts})) == {
        "dropped": {"stale_step": 2, "learner_busy": 1}}
    assert str(counts) == "{'stale_step': 2, 'learner_busy': 1}"


@pytest.mark.parametrize("error", [WeightsError, UnknownFormatError, Sha256MismatchError,
                                   BadTensorsError, OversizedPayloadError,
                                   IncompatibleWeightsError])
def test_weights_rejections_are_drop_kinds(error: type[WeightsError]) -> None:
    assert isinstance(error.kind, DropKind)


def test_the_simulator_and_the_trainer_name_a_stale_action_alike() -> None:
    sim = LockstepSim(SimConfig(env="maif-tiny", seed=0))
    f = sim.reset()
    for i in range(sim.num_robots):
        assert sim.submit(i, f.episode, f.step, 0, 1) is None
    sim.advance()
    sim_kind = sim.submit(0, f.episode, f.step, 0, 1)  # the step just played
    lengths = [3, 3]
    asm = assembler(rollout_steps=100)
    feed(asm, script(lengths), lengths)
    trainer_kind = asm.add_action(0, 1, 0, 0, log_prob=-1.0, version=1)  # assembled
    assert sim_kind is DropKind.STALE_STEP and trainer_kind is DropKind.STALE_STEP, (
        sim_kind, trainer_kind)
