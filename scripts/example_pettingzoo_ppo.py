#!/usr/bin/env python3
"""Train on an sdhn environment through PettingZoo only: parameter-shared independent PPO.

A MARL user's view of the project: nothing of sdhn is imported but the environment
(``sdhn_sim.envs.pettingzoo_env.parallel_env``); the learner below is a plain, self-contained PPO
with one network shared by every robot (feed-forward, each robot's own observation in), the kind
of loop any PettingZoo code has. It is an example of the API, not the project's trainer
(``python -m sdhn_train.cli`` trains SDHN and the baselines, much faster).

    .venv/bin/python scripts/example_pettingzoo_ppo.py --env maif-solo --iterations 50

Prints one line per iteration and writes them to ``--csv``: the mean episode return per robot,
the episodes finished and the size of the parameter update.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

from sdhn_sim.envs.pettingzoo_env import parallel_env


class Policy(nn.Module):
    def __init__(self, obs_size: int, num_actions: int, hidden: int = 64) -> None:
        super().__init__()
        self.body = nn.Sequential(nn.Linear(obs_size, hidden), nn.Tanh(),
                                  nn.Linear(hidden, hidden), nn.Tanh())
        self.pi = nn.Linear(hidden, num_actions)
        self.v = nn.Linear(hidden, 1)

    def forward(self, obs: torch.Tensor) -> tuple[torch.distributions.Categorical, torch.Tensor]:
        z = self.body(obs)
        return torch.distributions.Categorical(logits=self.pi(z)), self.v(z).squeeze(-1)


def collect(env, policy: Policy, steps: int, obs: dict) -> tuple[dict, dict, list[float]]:
    """``steps`` parallel steps; arrays are [T, N] (robots as a second axis)."""
    agents = env.possible_agents
    buf: dict[str, list] = {k: [] for k in ("obs", "act", "logp", "val", "rew", "done")}
    returns, running = [], np.zeros(len(agents))
    for _ in range(steps):
        x = torch.as_tensor(np.stack([obs[a] for a in agents]))
        with torch.no_grad():
            dist, value = policy(x)
            act = dist.sample()
        obs, rew, term, trunc, _ = env.step({a: int(act[i]) for i, a in enumerate(agents)})
        r = np.array([rew[a] for a in agents], dtype=np.float32)
        done = bool(term[agents[0]] or trunc[agents[0]])
        running += r
        for k, v in (("obs", x), ("act", act), ("logp", dist.log_prob(act)), ("val", value),
                     ("rew", torch.as_tensor(r)), ("done", torch.full((len(agents),), done))):
            buf[k].append(v)
        if done:
            returns.append(float(running.mean()))
            running[:] = 0
            obs, _ = env.reset()
    batch = {k: torch.stack(v) for k, v in buf.items()}
    with torch.no_grad():
        _, last = policy(torch.as_tensor(np.stack([obs[a] for a in agents])))
    batch["last_val"] = last
    return batch, obs, returns


def advantages(b: dict, gamma: float = 0.99, lam: float = 0.95) -> tuple[torch.Tensor, ...]:
    adv = torch.zeros_like(b["rew"])
    gae = torch.zeros_like(b["last_val"])
    for t in reversed(range(len(adv))):
        nxt = b["last_val"] if t == len(adv) - 1 else b["val"][t + 1]
        alive = 1.0 - b["done"][t].float()
        delta = b["rew"][t] + gamma * nxt * alive - b["val"][t]
        gae = delta + gamma * lam * alive * gae
        adv[t] = gae
    return adv, adv + b["val"]


def update(policy: Policy, opt: torch.optim.Optimizer, b: dict, epochs: int = 4) -> float:
    before = torch.cat([p.detach().flatten() for p in policy.parameters()]).clone()
    adv, ret = advantages(b)
    flat = {k: b[k].flatten(0, 1) for k in ("obs", "act", "logp")}
    adv, ret = adv.flatten(), ret.flatten()
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    for _ in range(epochs):
        dist, value = policy(flat["obs"])
        ratio = torch.exp(dist.log_prob(flat["act"]) - flat["logp"])
        pg = -torch.min(ratio * adv, ratio.clamp(0.8, 1.2) * adv).mean()
        loss = pg + 0.5 * ((value - ret) ** 2).mean() - 0.01 * dist.entropy().mean()
        opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
        opt.step()
    after = torch.cat([p.detach().flatten() for p in policy.parameters()])
    return float((after - before).norm())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--env", default="maif-solo", help="any sdhn environment name")
    ap.add_argument("--iterations", type=int, default=50)
    ap.add_argument("--steps", type=int, default=1024, help="parallel steps per iteration")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--csv", type=Path, default=None, help="write the per-iteration log here")
    args = ap.parse_args(argv)
    if args.iterations < 1 or args.steps < 1:
        print("--iterations and --steps must be >= 1", file=sys.stderr)
        return 2
    torch.manual_seed(args.seed)
    env = parallel_env(args.env, seed=args.seed)
    agent = env.possible_agents[0]
    policy = Policy(env.observation_space(agent).shape[0], int(env.action_space(agent).n))
    opt = torch.optim.Adam(policy.parameters(), lr=3e-4)
    obs, _ = env.reset(seed=args.seed)
    rows = []
    for it in range(1, args.iterations + 1):
        batch, obs, returns = collect(env, policy, args.steps, obs)
        change = update(policy, opt, batch)
        mean_ret = float(np.mean(returns)) if returns else float("nan")
        rows.append((it, mean_ret, len(returns), change))
        print(f"iteration {it}: return per robot {mean_ret:.3f} over {len(returns)} episodes, "
              f"update size {change:.4f}", flush=True)
    if args.csv is not None:
        with args.csv.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["iteration", "mean_return_per_robot", "episodes", "update_norm"])
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
