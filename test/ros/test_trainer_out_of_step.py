"""A trainer out of step with the team re-creates its step subscriptions and learns again.

Once, after a restart under load, a trainer node assembled nothing for minutes: every step it
received lacked something (status `incomplete_step` growing at the loop's rate). Here the test
process plays the team (the real message stream of maif-tiny, ``team_stream``) to a real trainer
process, first without robot 3's actions: the trainer must say it is out of step, name what the
steps lacked, re-create its subscriptions, and assemble transitions from the whole steps that
follow on the new ones."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from sdhn_base.ros import topics
from sdhn_base.ros.qos import STEP
from sdhn_train.trainer_node import OUT_OF_STEP_STEPS

from .deploy_helpers import status_watched_trainer
from .own_node import own_node
from .processes import node_processes
from .team_stream import Out, team_stream

pytestmark = pytest.mark.ros
NS = "/out_of_step"
N = 4
SILENT = 3  # the robot whose actions are withheld at first


def steps(stream: Iterator[Out]) -> Iterator[list[Out]]:
    """The stream cut into lock-steps (a step ends with its actions, or its summary)."""
    batch: list[Out] = []
    for out in stream:
        batch.append(out)
        if out.topic in (topics.robot_action(N - 1), topics.EPISODE):
            yield batch
            batch = []


def test_out_of_step_trainer_resubscribes_and_assembles_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from sdhn_msgs.msg import EpisodeSummary, RobotAction, RobotObservation, TeamState

    trainer_args, status_dir = status_watched_trainer(tmp_path, monkeypatch, NS)
    types = {topics.STATE: TeamState, topics.EPISODE: EpisodeSummary}
    for i in range(N):
        types[topics.robot_obs(i)] = RobotObservation
        types[topics.robot_action(i)] = RobotAction
    with own_node("team") as node:
        pubs = {t: node.create_publisher(m, topics.absolute(NS, t), STEP) for t, m in types.items()}
        step_topics = [t for t in pubs if t != topics.EPISODE]

        def status() -> dict:
            try:
                return json.loads((status_dir / "trainer.status.json").read_text())
            except (OSError, ValueError):
                return {}

        def matched() -> bool:
            return all(pubs[t].get_subscription_count() >= 1 for t in step_topics)

        def play(batches: Iterator[list[Out]], count: int, silent: bool) -> None:
            for _, batch in zip(range(count), batches, strict=False):
                for out in batch:
                    if silent and out.topic == topics.robot_action(SILENT):
                        continue
                    pubs[out.topic].publish(out.message)
                time.sleep(0.003)  # ~300 steps/s: the trainer keeps up, the queues never overflow

        with node_processes(trainer_args) as (trainer,):
            assert trainer.wait_for_line("ready", timeout=90), trainer.output
            deadline = time.monotonic() + 30
            while not matched():
                assert time.monotonic() < deadline, "the trainer's subscriptions never matched"
                time.sleep(0.05)
            batches = steps(team_stream(episodes=10_000, max_steps=25, seed=2))
            play(batches, OUT_OF_STEP_STEPS + 300, silent=True)
            assert trainer.wait_for_line("out of step", timeout=30), trainer.output
            assert status().get("transitions", -1) == 0, status()
            # the new subscriptions are new endpoints: wait until they have matched again
            deadline = time.monotonic() + 30
            while not (matched() and status().get("resubscribed", 0) >= 1):
                assert time.monotonic() < deadline, f"no new subscriptions: {status()}"
                time.sleep(0.05)
            time.sleep(0.5)
            deadline = time.monotonic() + 60
            while status().get("transitions", 0) < 32:
                assert time.monotonic() < deadline, f"nothing assembled after it: {status()}"
                play(batches, 100, silent=False)
            st = status()
            assert trainer.stop(timeout=20) == 0, trainer.output
    print(f"\nstatus after resubscribing: transitions={st['transitions']} "
          f"resubscribed={st['resubscribed']} missing={st['missing']}")
    assert max(st["missing"], key=st["missing"].get) == f"action {SILENT}", st["missing"]
    assert "Traceback" not in trainer.output, trainer.output
