#!/usr/bin/env python3
"""Train MAIF with TorchRL: MAPPO (parameter-shared actor on each robot's own observation, a
centralised critic) built from TorchRL parts on the project's PettingZoo environment, with no
other code of the project, as a TorchRL or BenchMARL user would.

    .venv/bin/python scripts/example_torchrl_mappo.py --env maif-tiny --iterations 50
    .venv/bin/python scripts/example_torchrl_mappo.py --env maif-solo --iterations 3 --frames 256

The environment is ``parallel_env(name, flat_infos=True)`` behind TorchRL's
``PettingZooWrapper``: flat numeric episode metrics in every step's infos, which TorchRL keeps
(``("next", "robot", "info", "episode_completed")``...). Parts: ``MultiAgentMLP`` for the actor
(decentralised, shared) and critic (centralised, shared), ``ProbabilisticActor`` with a
categorical distribution, ``Collector``, ``ClipPPOLoss`` with GAE. One line per
iteration: frames, finished episodes, their success rate and mean makespan (completed ones),
and the losses. Exit code 0; a test runs it for a few iterations (test/envs/test_torchrl.py).
"""

from __future__ import annotations

import argparse
import sys

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torch.distributions import Categorical
from torchrl.collectors import Collector
from torchrl.envs.libs.pettingzoo import PettingZooWrapper
from torchrl.modules import MultiAgentMLP, ProbabilisticActor
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from sdhn_sim.envs.pettingzoo_env import parallel_env

GROUP = "robot"  # TorchRL groups the agents robot_0 .. robot_{N-1} under their common prefix


def build(args: argparse.Namespace) -> tuple[PettingZooWrapper, ProbabilisticActor,
                                             TensorDictModule]:
    env = PettingZooWrapper(
        parallel_env(args.env, seed=args.seed, flat_infos=True, max_steps=args.max_steps),
        categorical_actions=True, use_mask=False, return_state=True, seed=args.seed)
    n = len(env.group_map[GROUP])
    obs_dim = env.observation_spec[GROUP, "observation"].shape[-1]
    n_actions = env.full_action_spec[GROUP, "action"].space.n
    actor_net = MultiAgentMLP(n_agent_inputs=obs_dim, n_agent_outputs=n_actions, n_agents=n,
                              centralised=False, share_params=True, depth=2, num_cells=64,
                              activation_class=nn.Tanh)
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, in_keys=[(GROUP, "observation")],
                         out_keys=[(GROUP, "logits")]),
        in_keys=[(GROUP, "logits")], out_keys=[(GROUP, "action")],
        distribution_class=Categorical, return_log_prob=True,
        log_prob_key=(GROUP, "sample_log_prob"))
    critic_net = MultiAgentMLP(n_agent_inputs=obs_dim, n_agent_outputs=1, n_agents=n,
                               centralised=True, share_params=True, depth=2, num_cells=64,
                               activation_class=nn.Tanh)
    critic = TensorDictModule(critic_net, in_keys=[(GROUP, "observation")],
                              out_keys=[(GROUP, "state_value")])
    return env, actor, critic


def episode_line(batch: object) -> str:
    """Success and makespan of the episodes that ended in this batch (from the flat infos)."""
    info = batch["next", GROUP, "info"]  # type: ignore[index]

    def robot_0(key: str) -> torch.Tensor:  # [frames, robots] -> [frames]: every robot agrees
        x = info[key]
        return x.reshape(-1, x.shape[-1])[:, 0]

    ended = robot_0("episode_done") > 0.5
    if not bool(ended.any()):
        return "0 episodes"
    completed = robot_0("episode_completed")[ended]
    makespan = robot_0("episode_makespan")[ended][completed > 0.5]
    mean = f"{makespan.float().mean():.1f}" if len(makespan) else "NC"
    return (f"{int(ended.sum())} episodes, success {completed.float().mean():.2f}, "
            f"makespan {mean}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="maif-tiny")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=50)
    ap.add_argument("--frames", type=int, default=1024, help="team steps per iteration")
    ap.add_argument("--max-steps", type=int, default=100, help="episode step limit")
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--minibatch", type=int, default=256)
    ap.add_argument("--lr", type=float, default=3e-4)
    args = ap.parse_args(argv)
    torch.manual_seed(args.seed)
    env, actor, critic = build(args)
    loss = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=0.2,
                       entropy_coeff=0.01, normalize_advantage=True)
    loss.set_keys(reward=(GROUP, "reward"), action=(GROUP, "action"),
                  sample_log_prob=(GROUP, "sample_log_prob"), value=(GROUP, "state_value"),
                  done=(GROUP, "done"), terminated=(GROUP, "terminated"))
    loss.make_value_estimator(ValueEstimators.GAE, gamma=0.99, lmbda=0.95)
    optimiser = torch.optim.Adam(loss.parameters(), lr=args.lr)
    collector = Collector(env, actor, frames_per_batch=args.frames,
                          total_frames=args.frames * args.iterations, device="cpu",
                          auto_register_policy_transforms=False)  # the actor keeps no state
    for it, batch in enumerate(collector):
        with torch.no_grad():
            loss.value_estimator(batch, params=loss.critic_network_params,
                                 target_params=loss.target_critic_network_params)
        flat = batch.reshape(-1)
        for _ in range(args.epochs):
            for idx in torch.randperm(flat.shape[0]).split(args.minibatch):
                parts = loss(flat[idx])
                total = parts["loss_objective"] + parts["loss_critic"] + parts["loss_entropy"]
                optimiser.zero_grad()
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
                optimiser.step()
        collector.update_policy_weights_()
        print(f"iteration {it}: {flat.shape[0]} frames, {episode_line(batch)}, "
              f"loss_objective {parts['loss_objective'].item():.4f}, "
              f"loss_critic {parts['loss_critic'].item():.4f}", flush=True)
    collector.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
