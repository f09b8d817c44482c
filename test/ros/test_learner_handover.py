"""The trainer node's hand-over to its learner offload process and its accounting, without ROS:
raw NumPy frames over a pipe (no pickle) survive the trip bit for bit; every step of a stream with
lost messages is a transition or a counted step drop once flushed; the status file the launcher
reads.
"""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path

import numpy as np
import pytest

from sdhn_base.drops import DropKind
from sdhn_base.ros.status import read_statuses, write_status
from sdhn_bringup.supervisor import node_status_parts
from sdhn_train import transitions as tr
from sdhn_train.learner_offload import (
    assembled_from,
    recv_message,
    rollout_arrays,
    send_message,
)
from sdhn_train.transitions import TransitionAssembler

from .test_transitions import Msg, N, feed, script


def test_frames_carry_arrays_of_every_dtype_and_no_pickle() -> None:
    r, w = mp.get_context("spawn").Pipe(duplex=False)
    rng = np.random.default_rng(0)
    arrays = {"f": rng.standard_normal((3, 1, 4, 5)).astype(np.float32),
              "i": rng.integers(0, 9, (7, 2)), "b": rng.random(6) > 0.5,
              "u": np.frombuffer(b"\x00\x01weights", np.uint8), "empty": np.zeros((0, 4, 5),
                                                                                  np.float32),
              "strided": np.arange(20, dtype=np.float64).reshape(4, 5)[:, ::2]}
    send_message(w, "rollout", {"episodes": [{"length": 3}]}, arrays)
    header, got = recv_message(r)
    assert header == {"kind": "rollout", "episodes": [{"length": 3}]}
    for k, v in arrays.items():
        assert got[k].dtype == v.dtype and got[k].shape == v.shape
        np.testing.assert_array_equal(got[k], v)
        assert got[k].flags.writeable
    # the frames on the wire: a JSON header, then raw bytes (a pickle would start with 0x80)
    send_message(w, "update", {"version": 2}, {"payload": arrays["u"]})
    assert r.recv_bytes().startswith(b"{")
    assert r.recv_bytes() == b"\x00\x01weights"


def test_an_assembled_rollout_round_trips() -> None:
    lengths = [6, 5]
    asm = TransitionAssembler(N, 5, N * 5, 5, rollout_steps=4, max_steps=10)
    feed(asm, script(lengths), lengths)
    a = asm.pop_rollout()
    b = asm.pop_rollout()
    assert a is not None and b is not None
    r, w = mp.get_context("spawn").Pipe(duplex=False)
    send_message(w, "rollout", {}, rollout_arrays(b))
    _, arrays = recv_message(r)
    back = assembled_from(arrays)
    assert back.keys == b.keys
    np.testing.assert_array_equal(back.versions, b.versions)
    np.testing.assert_array_equal(back.prefix_obs, b.prefix_obs)
    for name in tr.Rollout.__dataclass_fields__:
        if name in ("actor_h0", "critic_h0"):
            continue
        np.testing.assert_array_equal(getattr(back.rollout, name), getattr(b.rollout, name))


@pytest.mark.parametrize("lose", ["one action", "whole step"])
def test_every_step_is_a_transition_or_a_counted_drop(lose: str) -> None:
    lengths = [30, 30]
    msgs = script(lengths)
    if lose == "one action":
        msgs = [m for m in msgs if not (m.kind == "action" and m.episode == 0 and m.step == 7
                                        and m.robot == 1)]
    else:
        msgs = [m for m in msgs if not (m.episode == 0 and m.step == 7)]
    asm = TransitionAssembler(N, 5, N * 5, 5, rollout_steps=8, max_steps=40)
    feed(asm, msgs, lengths)
    # the stream stops mid-episode 2 (the trainer is stopped): flush settles the rest
    cut = [Msg("obs", 2, 0, i) for i in range(N)] + [Msg("state", 2, 0)]
    feed(asm, cut, [*lengths, 30])
    asm.flush()
    d = asm.stats.dropped
    steps = sum(lengths) + 1  # episode 2's step 0 was made too
    lost = d.get(DropKind.INCOMPLETE_STEP, 0) + d.get(DropKind.STEP_NEVER_SEEN, 0)
    assert asm.pending_records == 0
    assert asm.stats.transitions + lost == steps, (asm.stats, d)
    # one action lost costs transition 7; the whole step 7 costs transition 6 too (its next step
    # never came); episode 2's unanswered step 0 is flushed as incomplete
    assert lost == (2 if lose == "one action" else 3)
    assert (d.get(DropKind.STEP_NEVER_SEEN, 0) == 1) == (lose == "whole step")


def test_status_files_feed_the_launchers_status_line(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("SDHN_READY_FILE", raising=False)
    assert write_status("trainer", {"x": 1}) is None  # no supervisor: no file
    monkeypatch.setenv("SDHN_READY_FILE", str(tmp_path / "trainer.ready"))
    write_status("trainer", {"version": 3, "transitions": 120, "transitions_learned": 96,
                             "dropped": {DropKind.INCOMPLETE_STEP: 2}})
    (tmp_path / "junk.status.json").write_text("{half")
    statuses = read_statuses(tmp_path)
    assert list(statuses) == ["trainer"]
    parts = node_status_parts(statuses)
    assert parts == ["trainer v3 120 transitions (96 learned)",
                     f"trainer dropped {DropKind.INCOMPLETE_STEP}: 2"]


def test_a_step_the_sim_took_with_a_stay_is_dropped_at_once_even_if_the_action_comes_late() -> None:
    lengths = [12]
    msgs = script(lengths)
    late = next(m for m in msgs if m.kind == "action" and m.step == 7 and m.robot == 1)
    msgs.remove(late)
    asm = TransitionAssembler(N, 5, N * 5, 5, rollout_steps=4, max_steps=40, settle_lag=1000)
    cut = next(i for i, m in enumerate(msgs) if m.kind == "state" and m.step == 8)
    feed(asm, msgs[:cut], lengths)
    # the state of step 8 says one robot took 'stay' in step 7
    assert asm.add_state(0, 8, np.full(N * 5, 8, np.float32), num_robots=N, team_reward=8.0,
                         terminated=False, truncated=False, missed=1) is None
    assert asm.stats.dropped == {DropKind.MISSED_ACTION: 1}, "dropped without waiting to settle"
    # the late answer is not what the world executed, and its step is already counted as a
    # drop: taken quietly, neither learned from nor counted again (topics race: a peer's
    # on-time answer can reach the trainer after the state that dropped the step)
    pending = asm.pending_records
    assert feed(asm, [late], lengths) == [None]
    assert asm.pending_records == pending, "the dropped step is not opened again"
    feed(asm, msgs[cut + 1:], lengths)
    assert asm.stats.transitions == 11 and asm.pending_records == 0
    assert asm.stats.dropped == {DropKind.MISSED_ACTION: 1}
