"""Team-transition assembly from per-robot messages (ROS-free): order, gaps, duplicates, drops,
episode boundaries, hidden-state prefixes, and that the result trains the shared PPO learner."""

from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np
import pytest

from sdhn_base.drops import DropKind
from sdhn_train import transitions as tr
from sdhn_train.transitions import TransitionAssembler

N, D, A = 3, 5, 5
S = N * D


@dataclass
class Msg:
    kind: str  # obs | action | state
    episode: int
    step: int
    robot: int = 0


def obs_of(e: int, t: int, i: int) -> np.ndarray:
    return np.full(D, 100 * e + t + 0.1 * i, np.float32)


def state_of(e: int, t: int) -> np.ndarray:
    return np.full(S, 100 * e + t, np.float32)


def reward_into(e: int, t: int) -> float:
    return 0.0 if t == 0 else float(10 * e + t)


def script(lengths: list[int]) -> list[Msg]:
    """Messages of episodes with the given lengths, in lock-step publish order: per step the N obs
    and the state, then the N actions; the terminal step (t == length) has obs and state only."""
    out: list[Msg] = []
    for e, length in enumerate(lengths):
        for t in range(length + 1):
            out += [Msg("obs", e, t, i) for i in range(N)] + [Msg("state", e, t)]
            if t < length:
                out += [Msg("action", e, t, i) for i in range(N)]
    return out


def feed(asm: TransitionAssembler, msgs: list[Msg], lengths: list[int]) -> list[str | None]:
    results = []
    for m in msgs:
        done = m.step == lengths[m.episode]
        if m.kind == "obs":
            values = obs_of(m.episode, m.step, m.robot)
            results.append(asm.add_obs(m.episode, m.step, m.robot, values, num_robots=N,
                                       terminated=done, truncated=False))
        elif m.kind == "action":
            results.append(asm.add_action(m.episode, m.step, m.robot, (m.step + m.robot) % A,
                                          log_prob=-0.5 - m.robot, version=1 + m.step // 4))
        else:
            results.append(asm.add_state(m.episode, m.step, state_of(m.episode, m.step),
                                         num_robots=N, team_reward=reward_into(m.episode, m.step),
                                         terminated=done, truncated=False))
    return results


def assembler(rollout_steps: int = 4, lag: int = 6) -> TransitionAssembler:
    return TransitionAssembler(N, D, S, A, rollout_steps=rollout_steps, max_steps=50,
                               settle_lag=lag)


def drain(asm: TransitionAssembler) -> list[tr.AssembledRollout]:
    out = []
    while (r := asm.pop_rollout()) is not None:
        out.append(r)
    return out


def test_in_order_stream_gives_exact_rollouts() -> None:
    lengths = [5, 3]
    asm = assembler(rollout_steps=4)
    assert all(r is None for r in feed(asm, script(lengths), lengths))
    (r1, r2) = drain(asm)  # 8 transitions = 2 rollouts of 4
    r = r1.rollout
    r.validate()
    assert r.shape == (4, 1, N)
    assert r1.keys == [(0, 0), (0, 1), (0, 2), (0, 3)]
    np.testing.assert_array_equal(r.obs[2, 0, 1], obs_of(0, 2, 1))
    np.testing.assert_array_equal(r.state[3, 0], state_of(0, 3))
    np.testing.assert_array_equal(r.final_obs[3, 0, 2], obs_of(0, 4, 2))
    np.testing.assert_array_equal(r.actions[1, 0], [(1 + i) % A for i in range(N)])
    np.testing.assert_allclose(r.log_probs[0, 0], [-0.5 - i for i in range(N)])
    np.testing.assert_allclose(r.rewards[:, 0], [reward_into(0, t + 1) for t in range(4)])
    assert not r.terminated.any() and not r.truncated.any()
    assert r1.versions[:, 0].tolist() == [1, 1, 1, 1]
    assert r1.prefix_obs.shape == (0, N, D)

    # second rollout: (0,4) ends episode 0 (terminal record (0,5)), then episode 1 steps 0..2
    q = r2.rollout
    assert r2.keys == [(0, 4), (1, 0), (1, 1), (1, 2)]
    assert q.terminated[:, 0].tolist() == [True, False, False, True]
    np.testing.assert_array_equal(q.final_obs[0, 0, 0], obs_of(0, 5, 0))
    np.testing.assert_array_equal(q.final_state[3, 0], state_of(1, 3))
    # it starts mid-episode 0: the prefix holds steps 0..3 of episode 0
    assert r2.prefix_obs.shape == (4, N, D)
    np.testing.assert_array_equal(r2.prefix_obs[3, 1], obs_of(0, 3, 1))
    assert q.resets()[:, 0].tolist() == [False, True, False, False]


@pytest.mark.parametrize("seed", range(5))
def test_out_of_order_arrival_gives_the_same_rollouts(seed: int) -> None:
    lengths = [6, 4, 5]
    msgs = script(lengths)
    reference = drain(assembler_fed(msgs, lengths, lag=10**6))
    shuffled = list(msgs)
    # shuffle within windows of a few steps (DDS orders per topic, not across topics)
    rng = random.Random(seed)
    window = 3 * (2 * N + 1)
    for start in range(0, len(shuffled), window):
        chunk = shuffled[start : start + window]
        rng.shuffle(chunk)
        shuffled[start : start + window] = chunk
    asm = assembler(lag=10**6)
    assert all(r is None for r in feed(asm, shuffled, lengths))
    got = drain(asm)
    assert len(got) == len(reference) == 3
    for a, b in zip(got, reference, strict=True):
        assert a.keys == b.keys
        for name in ("obs", "state", "actions", "log_probs", "rewards", "terminated",
                     "truncated", "final_obs", "final_state"):
            np.testing.assert_array_equal(getattr(a.rollout, name), getattr(b.rollout, name), name)


def assembler_fed(msgs: list[Msg], lengths: list[int], lag: int) -> TransitionAssembler:
    asm = assembler(lag=lag)
    feed(asm, msgs, lengths)
    return asm


def test_missing_robot_action_drops_the_step_and_cuts_the_stream() -> None:
    lengths = [12]
    msgs = [m for m in script(lengths) if not (m.kind == "action" and m.step == 2 and m.robot == 1)]
    asm = assembler(rollout_steps=4, lag=4)
    feed(asm, msgs, lengths)
    assert asm.stats.dropped == {DropKind.INCOMPLETE_STEP: 1}
    assert asm.stats.gaps == 1
    first, second = drain(asm)
    # (0,2) is gone; the transition before it is truncated (bootstraps from obs of step 2)
    assert first.keys == [(0, 0), (0, 1), (0, 3), (0, 4)]
    assert first.rollout.truncated[:, 0].tolist() == [False, True, False, False]
    np.testing.assert_array_equal(first.rollout.final_obs[1, 0, 0], obs_of(0, 2, 0))
    assert first.rollout.resets()[:, 0].tolist() == [False, False, True, False]
    # the next rollout continues the segment that restarted at step 3
    assert second.keys[0] == (0, 5)
    np.testing.assert_array_equal(second.prefix_obs[:, 0, 0], [obs_of(0, t, 0)[0] for t in (3, 4)])


def test_incomplete_steps_name_what_they_lacked_and_count_the_run_without_transitions() -> None:
    """A stream that stops arriving (robot 2's actions from step 3 to 10, the state of steps 9
    and 10) names itself; the run of incomplete steps grows until the next transition."""
    lengths = [30]

    def withheld(m: Msg) -> bool:
        return (((m.kind, m.robot) == ("action", 2) and 3 <= m.step <= 10)
                or (m.kind == "state" and m.step in (9, 10)))
    msgs = [m for m in script(lengths) if not withheld(m)]
    asm = assembler(rollout_steps=4, lag=4)
    feed(asm, [m for m in msgs if m.step <= 10], lengths)
    asm.flush()
    st = asm.stats
    assert st.missing == {"action 2": 8, "state": 2}
    assert st.incomplete_run == st.dropped[DropKind.INCOMPLETE_STEP] == 8
    assert st.transitions == 3  # steps 0-2
    feed(asm, [m for m in msgs if m.step > 10], lengths)
    assert st.transitions > 3 and st.incomplete_run == 0  # steps 11+ are whole again


def test_a_late_message_to_a_dropped_step_is_taken_quietly_not_counted_again() -> None:
    """The step is already one counted drop; its straggler is not a second one (a stale step is
    a message to a step that was assembled, e.g. a replay)."""
    lengths = [12]
    late = Msg("action", 0, 2, 1)
    msgs = [m for m in script(lengths) if m != late]
    asm = assembler(rollout_steps=4, lag=4)
    feed(asm, msgs, lengths)
    assert feed(asm, [late, Msg("obs", 0, 2, 0)], lengths) == [None, None]
    assert asm.stats.dropped == {DropKind.INCOMPLETE_STEP: 1}
    assert asm.pending_records == 0
    assert feed(asm, [Msg("action", 0, 3, 1)], lengths) == [DropKind.STALE_STEP]


def test_gap_at_a_rollout_boundary_starts_the_next_rollout_afresh() -> None:
    lengths = [12]
    msgs = [m for m in script(lengths) if not (m.kind == "action" and m.step == 4 and m.robot == 0)]
    asm = assembler(rollout_steps=4, lag=4)
    feed(asm, msgs, lengths)
    first, second = drain(asm)
    assert first.keys == [(0, 0), (0, 1), (0, 2), (0, 3)]
    assert second.keys[0] == (0, 5)
    assert second.prefix_obs.shape[0] == 0, "after a gap the hidden state starts from zero"


def test_duplicates_and_malformed_messages_are_dropped_with_a_reason() -> None:
    asm = assembler()

    def obs(robot: int, values: np.ndarray, team: int = N) -> str | None:
        return asm.add_obs(0, 0, robot, values, num_robots=team, terminated=False,
                           truncated=False)

    def act(robot: int, action: int, log_prob: float = -1.0, step: int = 0) -> str | None:
        return asm.add_action(0, step, robot, action, log_prob=log_prob, version=1)

    def state(values: np.ndarray, step: int = 0) -> str | None:
        return asm.add_state(0, step, values, num_robots=N, team_reward=0.0, terminated=False,
                             truncated=False)

    assert obs(0, obs_of(0, 0, 0)) is None
    assert obs(0, obs_of(0, 0, 0)) == DropKind.DUPLICATE_OBS
    assert act(1, 2) is None
    assert act(1, 3) == DropKind.DUPLICATE_ACTION
    assert state(state_of(0, 0)) is None
    assert state(state_of(0, 0)) == DropKind.DUPLICATE_STATE
    assert obs(1, np.zeros(D + 1, np.float32)) == DropKind.WRONG_OBS_LENGTH
    bad = obs_of(0, 0, 1)
    bad[2] = np.nan
    assert obs(1, bad) == DropKind.NON_FINITE_OBS
    assert obs(N, obs_of(0, 0, 1)) == DropKind.UNKNOWN_ROBOT
    assert obs(1, obs_of(0, 0, 1), team=N + 1) == DropKind.WRONG_TEAM_SIZE
    assert act(2, A) == DropKind.ACTION_OUT_OF_RANGE
    assert act(2, 0, log_prob=float("inf")) == DropKind.BAD_LOG_PROB
    assert act(2, 0, log_prob=0.5) == DropKind.BAD_LOG_PROB
    assert act(2, 0, step=99) == DropKind.FUTURE_STEP
    assert state(np.zeros(S - 1, np.float32), step=1) == DropKind.WRONG_STATE_LENGTH
    # the first (valid) duplicate won
    assert asm._records[(0, 0)].actions[1] == 2


def test_stale_messages_after_assembly_are_dropped_but_answers_to_terminal_steps_are_not() -> None:
    lengths = [3, 3]
    asm = assembler(rollout_steps=100)
    feed(asm, script(lengths), lengths)
    assert asm.stats.transitions == 6
    assert asm.add_action(0, 1, 0, 0, log_prob=-1.0, version=1) == DropKind.STALE_STEP
    # an actor answering the terminal obs is not an error
    assert asm.add_action(0, 3, 0, 0, log_prob=-1.0, version=1) is None


def test_simulator_restart_resets_the_stream() -> None:
    lengths = [3, 3, 3, 3]
    asm = assembler(rollout_steps=100)
    feed(asm, script(lengths), lengths)
    before = asm.stats.transitions
    feed(asm, script([3]), [3])  # a new simulator run: episode counter back at 0
    assert asm.stats.transitions == before + 3


def test_assembled_rollout_trains_the_shared_learner(tmp_path: object) -> None:
    """The node's learner (same PPOLearner as in-process) takes an assembled rollout from MAIF."""
    from pathlib import Path

    from sdhn_policy.weights import decode_weights
    from sdhn_sim.envs import make_env
    from sdhn_train.checkpoint import latest_checkpoint
    from sdhn_train.config import Config
    from sdhn_train.envinfo import EnvInfo
    from sdhn_train.stream_learner import StreamLearner

    env = make_env("maif-tiny", num_envs=1, seed=3)
    info = EnvInfo.of(env)
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.ppo.num_minibatches, cfg.ppo.epochs = "maif-tiny", 1, 1, 1
    cfg.log.tensorboard = False
    run_dir = Path(str(tmp_path))
    learner = StreamLearner(cfg, info, run_dir)
    asm = TransitionAssembler(info.num_robots, info.obs_size, info.state_size, info.num_actions,
                              rollout_steps=8, max_steps=env.max_steps)
    obs, state = env.reset()
    rng = np.random.default_rng(0)
    reward, term, trunc = 0.0, False, False
    for t in range(12):
        for i in range(info.num_robots):
            asm.add_obs(0, t, i, obs[0, i], num_robots=info.num_robots, terminated=term,
                        truncated=trunc)
        asm.add_state(0, t, state[0], num_robots=info.num_robots, team_reward=reward,
                      terminated=term, truncated=trunc)
        actions = rng.integers(0, info.num_actions, info.num_robots)
        for i in range(info.num_robots):
            asm.add_action(0, t, i, int(actions[i]), log_prob=float(np.log(0.2)), version=1)
        res = env.step(actions[None])
        obs, state, reward = res.final_obs, res.final_state, float(res.reward[0])
        term, trunc = bool(res.terminated[0]), bool(res.truncated[0])
    assembled = asm.pop_rollout()
    assert assembled is not None
    result = learner.train(assembled, max_hypergraphs=3)
    assert result.version == 2 and np.isfinite(result.metrics["losses/value_loss"])
    assert len(result.hypergraphs) == 3
    g = result.hypergraphs[0]
    assert g.p_h.shape == (info.num_robots, cfg.sdhn.num_hyperedges)
    assert set(np.unique(g.incidence)) <= {0, 1} and -1 < g.skewness < 1
    assert latest_checkpoint(run_dir) == run_dir / "checkpoints" / "step_000000000008"
    # resume: a fresh learner picks up version 2 and the same actor weights (compared as
    # tensors: safetensors writes its metadata map in no fixed order, so bytes may differ)
    again = StreamLearner(cfg, info, run_dir)
    again.resume_latest()
    assert again.version == 2
    _, want = decode_weights(result.weights)
    _, got = decode_weights(again.weights())
    for name, tensor in want.items():
        np.testing.assert_array_equal(got[name], tensor, name)


def test_stream_learner_warm_starts_from_an_exported_actor(tmp_path: object) -> None:
    """actor.init_from (the trainer node's init_from): version 1 is the file's actor, as the
    in-process trainer's start; an actor of another shape is a ConfigError naming the field."""
    from pathlib import Path

    from sdhn_policy.weights import decode_weights, load_actor_file
    from sdhn_sim.envs import make_env
    from sdhn_train.config import Config, ConfigError
    from sdhn_train.env_features import resolve_features, wrap_features
    from sdhn_train.envinfo import EnvInfo
    from sdhn_train.stream_learner import StreamLearner

    shipped = Path(__file__).resolve().parents[2] / "models/maif-solo-mappo/actor.safetensors"
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.ppo.num_minibatches = "maif-tiny", 1, 1
    cfg.log.tensorboard = False
    cfg.actor.init_from = str(shipped)
    info = EnvInfo.of(wrap_features(make_env("maif-tiny", num_envs=1, seed=0),
                                    resolve_features(cfg)))
    learner = StreamLearner(cfg, info, Path(str(tmp_path)) / "a")
    assert learner.version == 1
    _, want = decode_weights(load_actor_file(shipped))
    _, got = decode_weights(learner.weights())
    assert want.keys() == got.keys()
    for name, tensor in want.items():
        np.testing.assert_array_equal(got[name], tensor, name)
    cfg.actor.gru_hidden = 32
    with pytest.raises(ConfigError, match=r"actor\.init_from"):
        StreamLearner(cfg, info, Path(str(tmp_path)) / "b")
