"""One episode result, four encodings: the conversions of ``sdhn_sim.episode.EpisodeResult`` to
and from the EpisodeSummary message (CDR bytes included), the simulator's events JSON, the
launcher's episodes.csv row and the environments' EpisodeStats keep every field they carry."""

from __future__ import annotations

import csv
import dataclasses
import io
import json

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message

from sdhn_msgs.msg import EpisodeSummary
from sdhn_sim.envs.api import EpisodeStats
from sdhn_sim.episode import CSV_FIELDS, EpisodeResult

u32 = st.integers(0, 2**32 - 1)
f32 = st.floats(-1e6, 1e6, width=32)


@st.composite
def results(draw: st.DrawFn) -> EpisodeResult:
    completed = draw(st.booleans())
    length = draw(st.integers(1, 10_000))
    failed = draw(st.integers(0, 3))
    survivors = draw(st.booleans()) if failed else None
    return EpisodeResult(
        env_name=draw(st.sampled_from(["maif-tiny", "maif-10", "rware-3"])),
        episode=draw(u32), length=length, completed=completed,
        makespan=draw(st.integers(1, length)) if completed else None,
        episode_return=draw(f32), collisions=draw(u32), formation_error=draw(f32.map(abs)),
        missed_actions=draw(u32), policy_version=draw(u32),
        instance_id=draw(st.integers(-1, 2**31 - 1)), failed_robots=failed,
        survivors_completed=survivors,
        survivors_makespan=draw(st.integers(1, length)) if survivors else None)


@given(results())
def test_message_round_trip_through_cdr(r: EpisodeResult) -> None:
    msg = r.to_message(EpisodeSummary())
    assert msg.makespan == (r.makespan if r.completed else 0), "NC is makespan 0 on the wire"
    back = EpisodeResult.from_message(deserialize_message(serialize_message(msg), EpisodeSummary))
    # the message has no field for robot failure: the events file and episodes.csv carry it
    assert back == dataclasses.replace(r, failed_robots=0, survivors_completed=None,
                                       survivors_makespan=None)


@given(results())
def test_events_json_round_trip(r: EpisodeResult) -> None:
    line = json.dumps({"event": "episode", "t": 1.5, **r.to_event()})
    event = json.loads(line)
    assert event["makespan"] == r.makespan, "NC is null in the events file"
    assert EpisodeResult.from_event(event) == r


@given(results(), st.floats(0, 1e5))
def test_csv_row_round_trip(r: EpisodeResult, wall_s: float) -> None:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=CSV_FIELDS)
    writer.writeheader()
    writer.writerow(r.to_csv_row(wall_s))
    (row,) = csv.DictReader(io.StringIO(out.getvalue()))
    assert list(row) == CSV_FIELDS
    assert (row["makespan"] == "NC") == (not r.completed)
    back = EpisodeResult.from_csv_row(row, env_name=r.env_name)
    # The row holds the return with 3 decimals and no formation error.
    assert back == EpisodeResult(**{**r.to_event(), "formation_error": None,
                                    "episode_return": round(r.episode_return, 3)})


def test_the_csv_row_and_event_of_a_simulator_episode_are_unchanged() -> None:
    """The on-disk formats as the launcher wrote them before the type existed (the failure
    columns added after, empty when no robot failed)."""
    ep = EpisodeStats(env_index=3, episode_return=-7.25, length=500, makespan=None,
                      completed=False, collisions=4, formation_error=0.5)
    r = EpisodeResult.from_stats(ep, env_name="maif-10", episode=2, missed_actions=1,
                                 policy_version=7, instance_id=12)
    assert r.to_event() == {
        "env_name": "maif-10", "episode": 2, "length": 500, "completed": False,
        "makespan": None, "episode_return": -7.25, "collisions": 4, "formation_error": 0.5,
        "missed_actions": 1, "policy_version": 7, "instance_id": 12,
        "failed_robots": 0, "survivors_completed": None, "survivors_makespan": None}
    assert r.to_csv_row(3.14159) == {
        "episode": 2, "completed": False, "makespan": "NC", "return": "-7.250", "length": 500,
        "collisions": 4, "missed_actions": 1, "policy_version": 7, "instance_id": 12,
        "wall_s": "3.14", "failed_robots": 0, "survivors_completed": "",
        "survivors_makespan": ""}
    assert r.to_stats(env_index=3) == ep


@given(results())
def test_stats_round_trip_keeps_what_the_environment_knows(r: EpisodeResult) -> None:
    back = EpisodeResult.from_stats(r.to_stats(), env_name=r.env_name, episode=r.episode,
                                    missed_actions=r.missed_actions,
                                    policy_version=r.policy_version, instance_id=r.instance_id)
    # robot failure is the condition model's, not the environment's statistics
    assert back == dataclasses.replace(r, failed_robots=0, survivors_completed=None,
                                       survivors_makespan=None)


def test_makespan_and_completed_must_agree() -> None:
    fields = {**EpisodeResult(env_name="maif-tiny", episode=0, length=9, completed=True,
                              makespan=9, episode_return=1.0, collisions=0,
                              formation_error=0.0, missed_actions=0,
                              policy_version=0).to_event()}
    with pytest.raises(ValueError, match="makespan"):
        EpisodeResult(**{**fields, "completed": False})
    with pytest.raises(ValueError, match="makespan"):
        EpisodeResult(**{**fields, "makespan": None})


def test_an_unknown_collision_count_is_not_published() -> None:
    r = EpisodeResult(env_name="maif-tiny", episode=0, length=9, completed=False, makespan=None,
                      episode_return=1.0, collisions=None, formation_error=None,
                      missed_actions=0, policy_version=0)
    with pytest.raises(ValueError, match="unknown"):
        r.to_message(EpisodeSummary())
    assert r.to_csv_row(0.0)["collisions"] == ""
