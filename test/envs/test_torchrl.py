"""TorchRL on the project's PettingZoo environment, through TorchRL's own PettingZooWrapper and
spec check, and the docs' MAPPO example (scripts/example_torchrl_mappo.py) for a few iterations:
the episode metrics reach TorchRL as numbers (flat_infos)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_wrapper_keeps_the_episode_metrics() -> None:
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    from sdhn_sim.envs.pettingzoo_env import NOT_COMPLETED, parallel_env

    env = PettingZooWrapper(parallel_env("maif-tiny", seed=0, flat_infos=True, max_steps=5),
                            categorical_actions=True, use_mask=False, return_state=True)
    check_env_specs(env)
    td = env.rollout(10, break_when_any_done=False)
    info = td["next", "robot", "info"]
    done = info["episode_done"][:, 0]
    assert done.tolist() == [0, 0, 0, 0, 1] * 2, done.tolist()
    assert info["episode_length"][:, 0][done > 0].tolist() == [5, 5]
    assert info["episode_makespan"][:, 0][done > 0].tolist() == [NOT_COMPLETED] * 2


def test_mappo_example_trains_a_few_iterations() -> None:
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "example_torchrl_mappo.py"),
                           "--env", "maif-tiny", "--iterations", "2", "--frames", "64",
                           "--max-steps", "16", "--epochs", "1", "--minibatch", "32"],
                          capture_output=True, text=True, timeout=600, check=False, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [x for x in done.stdout.splitlines() if x.startswith("iteration ")]
    assert len(lines) == 2, done.stdout
    for line in lines:  # 64 frames of 16-step episodes that random play never completes
        assert "64 frames, 4 episodes, success 0.00, makespan NC" in line, line
        losses = [float(v) for v in re.findall(r"loss_\w+ (-?[\d.]+)", line)]
        assert len(losses) == 2 and all(abs(v) < 1e3 for v in losses), line
