"""One robot's decision loop, without ROS: validate an observation, keep the GRU state, act.

The actor node feeds every observation message to :meth:`ActorCore.on_obs` and every weights
message to :meth:`ActorCore.offer_weights`. Weights are validated when offered, but only swapped
in at the next observation, so one step always runs on one set of weights, and the action carries
the version that produced it. The GRU state goes back to zeros when a new episode starts
(step 0 or a different episode counter). NumPy only: importing this never imports torch.

Final approach (``approach``: ``sdhn_policy.final_approach.FinalApproach.for_env(env)``, MAIF,
with stall breaking): after the action is chosen, a robot one cell from its free goal steps onto
it, one whose free goal is farther but inside its window (and not sampling) takes the first step of
a shortest free path in the window, and one on its goal stays unless stall breaking samples this
step.

Dead reckoning (``reckoner``: ``sdhn_policy.dead_reckoning.reckoner_for(env)``, MAIF or RWARE,
for one row): the core keeps the step each recorded action
answered, so an observation ``obs_age`` steps behind this robot's own actions
(``RobotObservation.obs_age``) is moved forward by exactly the actions it sent for steps
``step - obs_age .. step - 1``: steps it skipped or never answered (realtime clock, a restart
mid-episode) sent nothing and move nothing.

    core = ActorCore(robot_id=2, num_robots=4, greedy=True, seed=0)
    core.offer_weights(fmt, version, payload, sha256)    # WeightsError (.kind) if rejected
    out = core.on_obs(episode, step, robot_id, num_robots, obs)
    if isinstance(out, Decision): publish(out.action, out.log_prob, out.version)
    else: count(out.kind, out.reason)                    # a Drop
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sdhn_base.drops import DropKind
from sdhn_policy.actor_runtime import (
    ActorRuntime,
    NonFiniteLogitsError,
    PolicyOutputError,
    check_temperature,
)
from sdhn_policy.dead_reckoning import Reckoner
from sdhn_policy.final_approach import FinalApproach
from sdhn_policy.stall_breaker import StallBreaker, StallRule
from sdhn_policy.weights import IncompatibleWeightsError, OversizedPayloadError, WeightsError
from sdhn_sim.envs.maif import OBS_SIZE as MAIF_OBS_SIZE

MAX_WEIGHTS_BYTES = 64 * 1024 * 1024
"""Largest weights payload an actor accepts (the actor itself is ~100 kB)."""

BACKENDS = ("numpy", "onnx")


def runtime_class(backend: str) -> type[ActorRuntime]:
    """The runtime that computes the policy: ``numpy`` (default) or ``onnx`` (onnxruntime, imported
    only when chosen, so a NumPy actor never loads it). Both give the same actions (tested)."""
    if backend == "numpy":
        return ActorRuntime
    if backend == "onnx":
        from sdhn_policy.onnx_runtime import OnnxActorRuntime
        return OnnxActorRuntime
    raise ValueError(f"backend: got {backend!r}; allowed: {', '.join(BACKENDS)}")


def runtime_from_file(backend: str, path: str) -> ActorRuntime:
    """The runtime of a weights file: ``actor.safetensors`` on either backend, or an exported
    ``actor.onnx`` as it is (backend ``onnx`` only). WeightsError if the file is unusable."""
    cls = runtime_class(backend)
    if path.endswith(".onnx"):
        if backend != "onnx":
            raise WeightsError(f"an .onnx file runs on backend 'onnx', not {backend!r}")
        from sdhn_policy.onnx_runtime import OnnxActorRuntime
        return OnnxActorRuntime.from_onnx_file(path)
    return cls.from_file(path)


@dataclass(frozen=True)
class Decision:
    action: int
    log_prob: float
    version: int  # version of the weights that produced this action


@dataclass(frozen=True)
class Drop:
    kind: DropKind  # counted per kind
    reason: str  # human-readable detail for the log


class ActorCore:
    """The per-robot policy state machine (weights, GRU hidden state, RNG)."""

    def __init__(self, robot_id: int, num_robots: int, greedy: bool, seed: int,
                 runtime: ActorRuntime | None = None, *,
                 runtime_cls: type[ActorRuntime] = ActorRuntime,
                 temperature: float = 1.0, stall_rule: StallRule | None = None,
                 approach: FinalApproach | None = None,
                 skip_ahead: bool = False, reckoner: Reckoner | None = None) -> None:
        self.robot_id = robot_id
        # Realtime clock: the world steps on without this robot, so a later step of the episode
        # is taken (the GRU goes on from the last observation it saw); counted in ``skipped``.
        self.skip_ahead = skip_ahead
        self.skipped = 0  # steps of an episode never seen between two answered ones
        # under observation latency: move a stale observation forward by the actions sent
        # since (sdhn_policy.dead_reckoning); a rule for one row
        if reckoner is not None and reckoner.rows != 1:
            raise ValueError(f"dead reckoning: one rule for one robot (rows 1), got rows "
                             f"{reckoner.rows}")
        self.reckoner = reckoner
        # the step each action recorded in the reckoner answered, newest last (this episode)
        self._sent_steps: deque[int] = deque(
            maxlen=self.reckoner.horizon if self.reckoner is not None else 1)
        self.reckoned = 0  # observations dead reckoning moved (a robot's own actions unseen)
        self.temperature = check_temperature(temperature)  # sampled play only
        if stall_rule is not None and not greedy:
            raise ValueError("stall breaking is a greedy mode (greedy must be true)")
        # greedy play that samples a few actions when this robot's play has stalled
        self.stalls = StallBreaker(stall_rule, 1) if stall_rule is not None else None
        if approach is not None and self.stalls is None:
            raise ValueError("final approach requires stall breaking (stall_rule): its hold "
                             "would deadlock corridors without it")
        # the last step onto the goal and staying there (sdhn_policy.final_approach)
        self.approach = approach
        self.runtime_cls = runtime_cls  # builds the runtime of every weights message
        self.num_robots = num_robots
        self.greedy = greedy
        self.rng = np.random.default_rng([seed, robot_id])
        self.runtime: ActorRuntime | None = None
        self._pending: ActorRuntime | None = None
        self.hidden: npt.NDArray[np.float32] | None = None
        self.episode: int | None = None
        self.last_step: int | None = None
        if runtime is not None:
            self._check(runtime)
            self.runtime = runtime
            self.hidden = runtime.initial_state(1)

    @property
    def version(self) -> int:
        """Version of the weights in use (0 = none yet)."""
        return self.runtime.version if self.runtime is not None else 0

    def forget_position(self) -> None:
        """After a pause (a deactivated actor): forget the last answered step, so the next
        observation is taken whatever step it is (as by a restarted actor), with a fresh GRU
        state; the steps in between were not this actor's."""
        self.episode = self.last_step = None
        if self.runtime is not None:
            self.hidden = self.runtime.initial_state(1)
        if self.stalls is not None:
            self.stalls.reset()
        self._reset_reckoner()

    def _reset_reckoner(self) -> None:
        if self.reckoner is not None:
            self.reckoner.reset()
            self._sent_steps.clear()

    def _record(self, step: int, action: int) -> None:
        if self.reckoner is not None:
            self.reckoner.record([action])
            self._sent_steps.append(step)

    def unseen_actions(self, step: int, obs_age: int) -> int:
        """How many of the actions this robot sent this episode an observation of ``step``,
        ``obs_age`` steps behind its actions, does not reflect (those answering steps
        ``step - obs_age`` and later; at most the reckoner's horizon)."""
        first = step - obs_age
        return sum(1 for s in self._sent_steps if first <= s < step)

    def _check(self, rt: ActorRuntime) -> None:
        spec = rt.spec
        if spec.use_robot_id and spec.num_robots != self.num_robots:
            raise IncompatibleWeightsError(
                f"incompatible weights: trained for {spec.num_robots} robots (one-hot id), this "
                f"team has {self.num_robots}")
        if self.stalls is not None and spec.obs_size != MAIF_OBS_SIZE:  # also final approach
            raise IncompatibleWeightsError(
                f"incompatible weights: stall breaking reads MAIF observations "
                f"({MAIF_OBS_SIZE} floats), this actor takes {spec.obs_size}")
        if self.reckoner is not None and spec.obs_size != self.reckoner.obs_size:
            raise IncompatibleWeightsError(
                f"incompatible weights: dead reckoning for this env reads observations of "
                f"{self.reckoner.obs_size} floats, this actor takes {spec.obs_size}")

    def offer_weights(self, fmt: str, version: int, payload: bytes, sha256: str) -> bool:
        """Validate new weights and queue them for the next step; False when that version is
        already queued or in use (a no-op). WeightsError if rejected: the old weights stay."""
        newest = self._pending or self.runtime
        if newest is not None and newest.version == version and version > 0:
            return False
        if len(payload) > MAX_WEIGHTS_BYTES:
            raise OversizedPayloadError(
                f"oversized payload: {len(payload)} bytes > {MAX_WEIGHTS_BYTES}")
        try:
            rt = self.runtime_cls.from_bytes(fmt, version, payload, sha256)
        except WeightsError:
            raise
        except Exception as e:  # whatever a crafted payload provokes: a rejection, not a crash
            raise WeightsError(f"weights rejected ({type(e).__name__}): {str(e)[:300]}") from e
        self._check(rt)
        self._pending = rt
        return True

    def _swap(self) -> None:
        if self._pending is None:
            return
        old, self.runtime, self._pending = self.runtime, self._pending, None
        if self.hidden is None or old is None or old.hidden_size != self.runtime.hidden_size:
            self.hidden = self.runtime.initial_state(1)

    def on_obs(self, episode: int, step: int, robot_id: int, num_robots: int,
               obs: npt.NDArray[np.float32], *, done: bool = False,
               obs_age: int | None = 0) -> Decision | Drop | None:
        """Answer one observation; None when no answer is due (``done``: the episode's final
        observation, which the simulator does not wait on). ``obs_age``: how many steps the
        observation lags behind this robot's actions (dead reckoning moves it forward by the
        actions sent for steps ``step - obs_age`` on); None = the message lacks it, a drop
        (``bad_obs_age``) only where dead reckoning needs it, as is an age before step 0."""
        if done:
            return None
        if robot_id != self.robot_id or num_robots != self.num_robots:
            return Drop(DropKind.WRONG_ROBOT, f"observation for robot {robot_id} of {num_robots}, "
                        f"this is robot {self.robot_id} of {self.num_robots}")
        self._swap()  # between steps: the previous step is answered, this one not yet started
        if self.runtime is None or self.hidden is None:
            return Drop(DropKind.NO_WEIGHTS, "no policy weights yet (weights_file empty and "
                        "nothing received on the weights topic)")
        if obs.shape != (self.runtime.spec.obs_size,):
            return Drop(DropKind.WRONG_OBS_LENGTH, f"observation has length {obs.size}, the policy "
                        f"expects {self.runtime.spec.obs_size}")
        if not np.isfinite(obs).all():
            return Drop(DropKind.NON_FINITE_OBS, "observation contains NaN or Inf")
        if self.reckoner is not None and (obs_age is None or not 0 <= obs_age <= step):
            return Drop(DropKind.BAD_OBS_AGE, "observation without obs_age (a publisher of the "
                        "older message definition)" if obs_age is None else
                        f"obs_age {obs_age} at step {step}: before the episode's start")
        order = self._order(episode, step)
        if order is not None:
            return order
        if step == 0 or episode != self.episode:
            self.hidden = self.runtime.initial_state(1)
            self.episode, self.last_step = episode, None
            if self.stalls is not None:
                self.stalls.reset()
            self._reset_reckoner()
        if self.reckoner is not None:  # on every observation: the RWARE rule remembers shelves
            unseen = self.unseen_actions(step, obs_age) if obs_age else 0
            self.reckoned += int(unseen > 0)
            obs = self.reckoner.correct(obs[None], [unseen])[0]
        greedy, temperature = self.greedy, self.temperature
        sampling = self.stalls is not None and bool(self.stalls.update(obs[None])[0])
        if sampling:
            assert self.stalls is not None
            greedy, temperature = False, self.stalls.rule.temperature
        try:
            action, logp, h_next = self.runtime.act(obs[None], self.hidden, greedy, self.rng,
                                                    robot_id=self.robot_id,
                                                    temperature=temperature)
        except NonFiniteLogitsError as e:  # counted and logged by the node; never an action
            return self._unanswered(step, e.h_next, Drop(DropKind.NON_FINITE_LOGITS, str(e)))
        except PolicyOutputError as e:
            return self._unanswered(step, None, Drop(DropKind.BAD_POLICY_OUTPUT, str(e)))
        if self.approach is not None:
            # The log-prob stays the policy's for the action it chose (the argmax, or the draw),
            # not for the rule's: only greedy deploy actors run the rule, and no trainer learns
            # from them (the launcher starts a trainer only in train mode, where actors sample
            # without stall breaking or the final approach: launch_load refuses them there).
            action = self.approach.apply(obs[None], action, np.array([sampling]))
        self.hidden = h_next
        self.last_step = step
        self._record(step, int(action[0]))
        return Decision(int(action[0]), float(logp[0]), self.runtime.version)

    def _unanswered(self, step: int, h_next: npt.NDArray[np.float32] | None, drop: Drop) -> Drop:
        """A step the policy could not answer: taken (the next step is in order, not 'future'),
        the GRU state carried on when it is finite, else back to zeros."""
        assert self.runtime is not None
        self._record(step, 0)  # nothing sent: the simulator takes 'stay'
        if h_next is not None and np.isfinite(h_next).all():
            self.hidden = h_next
        else:
            self.hidden = self.runtime.initial_state(1)
        self.last_step = step
        return drop

    def _order(self, episode: int, step: int) -> Drop | None:
        """Drop an observation from the past or the future of the episode being answered.

        The simulator sends every step of an episode in order (reliable, in-order topic), so an
        actor that already answered (e, s) only ever sees (e, s + 1) next, or step 0 of a new
        episode (also after a simulator restart, whose counter starts again at 0). Anything else
        is dropped *without* touching the GRU state: one stray message must not reset it or make
        the real next steps look stale. An actor that has answered nothing yet (just started or
        restarted mid-episode) takes whatever comes. Step 0 is always taken: a simulator
        restarted in episode 0 sends (0, 0) again, which a replayed step 0 cannot be told from.
        With ``skip_ahead`` (the realtime clock) a later step of the same episode is taken too,
        and any step of a later episode (its step 0 may have been skipped; the GRU state is reset
        as at step 0)."""
        if self.episode is None or self.last_step is None or step == 0:
            return None
        if (episode, step) <= (self.episode, self.last_step):
            return Drop(DropKind.STALE_STEP, f"episode {episode} step {step} is not after the last "
                        f"answered episode {self.episode} step {self.last_step}")
        if self.skip_ahead:  # a later step of this episode, or any step of a later one
            self.skipped += step - self.last_step - 1 if episode == self.episode else step
            return None
        if episode != self.episode or step > self.last_step + 1:
            return Drop(DropKind.FUTURE_STEP, f"episode {episode} step {step} skips ahead of the "
                        f"last answered episode {self.episode} step {self.last_step}")
        return None
