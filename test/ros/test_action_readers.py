"""An actor creates its obs subscription only once its action publisher has matched every reader
of its actions (``action_readers``): the simulator starts step 0 only when every obs topic has
all its subscribers, so no reader of the actions (recorder, trainer, an observer) misses a
robot's first ones, however late that reader's discovery comes. The wait is bounded: past
``action_readers_timeout`` the actor warns, names the readers it knows of, and acts anyway. The
launcher tells every actor how many readers its graph has. Real actor and simulator processes
(maif-tiny, the shipped policy), an rclpy observer in the test process."""

from __future__ import annotations

import dataclasses
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from sdhn_base.ros import topics
from sdhn_bringup.launch_graph import actor_node, node_parameters
from sdhn_bringup.launch_load import load_config, resolve

from .deploy_helpers import EXACT_DEADLINE_S, actor_cmd, sim_cmd, stop_all
from .own_node import own_node_and_executor
from .processes import node_processes

pytestmark = pytest.mark.ros

N, STEPS = 4, 20
MODEL = Path(__file__).resolve().parents[2] / "models" / "maif-tiny-sdhn"
WEIGHTS = MODEL / "actor.safetensors"
LATE_S = 1.0  # the observer's action subscriptions come this long after every actor is seen


@dataclasses.dataclass
class LateObserver:
    """An rclpy node that subscribes to every obs, state and episode topic at once (the
    simulator counts it with ``extra_subscribers=1``) and to the robots' actions only when told:
    a reader of the actions whose discovery comes late."""

    node: Any
    executor: Any
    ns: str = ""  # the test's own team namespace (a node of an earlier test lingers until its
    # lease ends and must not count here)
    actions: dict[int, set[tuple[int, int]]] = dataclasses.field(default_factory=dict)
    episodes: list[Any] = dataclasses.field(default_factory=list)
    subs: list[Any] = dataclasses.field(default_factory=list)

    def qos(self) -> Any:
        from rclpy.qos import QoSProfile

        from sdhn_base.ros.qos import STEP
        # a history as deep as the run: a starved test process never loses an action it was sent
        return QoSProfile(history=STEP.history, depth=4096, reliability=STEP.reliability,
                          durability=STEP.durability)

    def subscribe_team(self) -> None:
        from sdhn_msgs.msg import EpisodeSummary, RobotObservation, TeamState
        for i in range(N):
            self.subs.append(self.node.create_subscription(
                RobotObservation, topics.absolute(self.ns, topics.robot_obs(i)),
                lambda _m: None, self.qos()))
        self.subs.append(self.node.create_subscription(
            TeamState, topics.absolute(self.ns, topics.STATE), lambda _m: None, self.qos()))
        self.subs.append(self.node.create_subscription(
            EpisodeSummary, topics.absolute(self.ns, topics.EPISODE), self.episodes.append,
            self.qos()))

    def subscribe_actions(self) -> None:
        from sdhn_msgs.msg import RobotAction

        def on_action(m: Any) -> None:
            self.actions.setdefault(int(m.robot_id), set()).add((int(m.episode), int(m.step)))
        for i in range(N):
            self.subs.append(self.node.create_subscription(
                RobotAction, topics.absolute(self.ns, topics.robot_action(i)), on_action,
                self.qos()))

    def spin(self, seconds: float, until: Any = None) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
            if until is not None and until():
                return True
        return until is None


@pytest.fixture
def late_observer() -> Iterator[LateObserver]:
    from rclpy.experimental import EventsExecutor

    with own_node_and_executor("late_observer", EventsExecutor) as (node, executor):
        yield LateObserver(node, executor)


def test_a_reader_discovered_late_gets_every_action_from_step_0(
        late_observer: LateObserver) -> None:
    obs = late_observer
    obs.ns = ns = "/readers_late"
    obs.subscribe_team()
    # The old actor (obs subscribed with its action publisher) let the simulator start as soon
    # as the observer's obs subscriptions matched: the whole episode ran before the observer's
    # action subscriptions existed, and it saw none of the first actions.
    actors = [actor_cmd(i, N, ns, weights_file=WEIGHTS, greedy=True, action_readers=2)
              for i in range(N)]
    sim = sim_cmd(ns=ns, episodes=1, max_steps=STEPS, seed=4, extra_subscribers=1,
                  step_deadline=EXACT_DEADLINE_S)
    action_topics = [topics.absolute(ns, topics.robot_action(i)) for i in range(N)]
    with node_processes(sim, *actors) as procs:
        assert obs.spin(60, lambda: all(obs.node.count_publishers(t) >= 1
                                        for t in action_topics)), [p.output for p in procs]
        obs.spin(LATE_S)
        obs.subscribe_actions()
        assert obs.spin(60, lambda: len(obs.episodes) == 1), procs[0].output
        length = int(obs.episodes[0].length)
        # an action can reach this reader after the summary the simulator sent once it had it
        obs.spin(10, lambda: all(len(obs.actions.get(i, ())) >= length for i in range(N)))
        assert procs[0].proc.wait(timeout=20) == 0, procs[0].output
        stop_all(procs[1:])
    assert obs.episodes[0].missed_actions == 0, procs[0].output
    for i in range(N):
        missing = sorted({(0, t) for t in range(length)} - obs.actions.get(i, set()))
        assert not missing, (f"robot {i}: the late reader lacks actions {missing[:5]} "
                             f"({len(missing)} of {length})\n{procs[1 + i].output}")
        waited = [line for line in procs[1 + i].lines if "of 2 action readers after" in line]
        assert len(waited) == 1, procs[1 + i].output


def test_past_the_timeout_an_actor_names_what_it_knows_and_acts(
        late_observer: LateObserver) -> None:
    ns = "/readers_timeout"
    # Told of 3 readers where only the simulator reads its actions (a reader gone for good, as
    # for an actor restarted after the recorder died): it must not wait for ever.
    actor = actor_cmd(0, N, ns, weights_file=WEIGHTS, greedy=True, action_readers=3,
                      action_readers_timeout=1.0)
    others = [actor_cmd(i, N, ns, weights_file=WEIGHTS, greedy=True) for i in range(1, N)]
    sim = sim_cmd(ns=ns, episodes=1, max_steps=STEPS, seed=4, step_deadline=EXACT_DEADLINE_S)
    with node_processes(sim, actor, *others) as procs:
        assert procs[0].proc.wait(timeout=90) == 0, procs[0].output
        stop_all(procs[1:])
    # The simulator ran its episode (exit 0): robot 0 subscribed to its observations after all.
    # Its one warning says how many of the 3 it has and which subscribers it knows of (the
    # simulator, unless discovery was slower than the timeout).
    warned = [line for line in procs[1].lines if "of 3 action readers in" in line]
    assert len(warned) == 1, procs[1].output
    known = re.search(r"matched (\d) of 3 .*this process knows of: (.*); subscribing", warned[0])
    assert known and int(known[1]) <= 1, warned[0]
    assert known[2] in (f"{ns}/sim", "none"), warned[0]


def params(tmp_path: Path, *sets: str) -> dict[str, dict[str, Any]]:
    config = tmp_path / "launch.yaml"
    config.write_text(f"env: maif-tiny\nweights: {MODEL}\nrecorder: true\n")
    cfg = load_config(config, [f"run_dir={tmp_path / 'run'}", *sets])
    return node_parameters(resolve(cfg))


@pytest.mark.parametrize(("sets", "readers"), [
    ((), 2),  # the simulator and the recorder node
    (("recorder.where=sim",), 1),  # the simulator records: no recorder node
    (("recorder.enabled=false",), 1),
    (("mode=train",), 3),  # the simulator, the recorder, the trainer
    (("mode=train", "wait_for_observers=false"), 1),  # nobody waits for the observers
    (("actor_hosts=2",), 2),  # an actor host's nodes read the same parameters file
])
def test_the_launcher_tells_each_actor_its_graphs_readers(
        tmp_path: Path, sets: tuple[str, ...], readers: int) -> None:
    nodes = params(tmp_path, *sets)
    extra = nodes["/sdhn/sim"]["extra_subscribers"]
    for i in range(4):
        assert nodes[actor_node("/sdhn", i)]["action_readers"] == readers == 1 + extra, sets
