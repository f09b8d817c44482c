"""Cost of the Foxglove viz: encoding per message, and per-state overhead with and without a client.

    .venv/bin/python scripts/bench_viz.py [--env maif-10] [--states 300]

1. Build + encode time of each viz message (scene with and without the static map, hypergraph
   scene, P_H image, metrics JSON) for one team state of ``--env``.
2. The viz node's per-state path (validate, trail, and -- only if the channel has a subscriber --
   build, encode and send the scene + metrics) on the viz node's own WebSocket server
   (sdhn_sim.viz.server: the Foxglove SDK's), first with no client,
   then with one ``websockets`` client (a separate process) subscribed to every channel.
No ROS here: the ROS callback adds the same small constant in both cases.
"""

from __future__ import annotations

import argparse
import array
import asyncio
import json
import subprocess
import sys
import time
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from sdhn_base.ros.topics import VIZ_METRICS, VIZ_SCENE
from sdhn_sim.envs import make_single_env
from sdhn_sim.viz.renderer import VizRenderer
from sdhn_sim.viz.server import VizServer


def team_messages(env_name: str, count: int) -> list[Any]:
    env = make_single_env(env_name, seed=0)
    obs, state = env.reset()
    rng = np.random.default_rng(0)
    out = []
    for step in range(count):
        pos = env.positions if env_name.startswith("maif") else obs[:, :2].astype(np.int64)
        out.append(SimpleNamespace(
            header=SimpleNamespace(stamp=SimpleNamespace(sec=step, nanosec=0)),
            env_name=env_name, episode=0, step=step, num_robots=env.num_robots,
            state=array.array("f", state.astype(np.float32).tobytes()),
            positions=pos.reshape(-1).tolist(), team_reward=0.0, terminated=False,
            truncated=False, makespan_so_far=step, missed_actions=0, instance_id=-1,
        ))
        res = env.step(rng.integers(0, env.num_actions, env.num_robots))
        if res.terminated or res.truncated:
            obs, state = env.reset()
        else:
            obs, state = res.obs, res.state
    return out


def hypergraph_message(n: int, m: int) -> Any:
    p_h = np.random.default_rng(1).random((n, m)).astype(np.float32)
    return SimpleNamespace(
        header=None, episode=0, step=0, num_robots=n, num_hyperedges=m,
        p_h=array.array("f", p_h.tobytes()), incidence=(p_h > 0.5).astype(np.uint8).tobytes(),
        skewness=0.1, policy_version=1,
    )


def per_call_ms(fn: Any, repeat: int = 50) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t0) / repeat * 1e3


def encoding_costs(env_name: str) -> None:
    (msg,) = team_messages(env_name, 1)
    r = VizRenderer()
    r.on_state(msg)
    n = msg.num_robots
    r.on_hypergraph(hypergraph_message(n, max(2, n // 2)))
    rows: list[tuple[str, Callable[[], Any]]] = [
        ("scene, with static map", lambda: r.scene(with_static=True).encode()),
        ("scene, robots only", lambda: r.scene(with_static=False).encode()),
        ("hypergraph scene", lambda: r.hypergraph_scene().encode()),  # type: ignore[union-attr]
        ("P_H image", lambda: r.p_h_image().encode()),  # type: ignore[union-attr]
        ("metrics JSON", lambda: json.dumps(r.metrics()).encode()),
        ("validate + trail (every state)", lambda: r.on_state(msg)),
    ]
    print(f"encoding cost per message, {env_name} ({n} robots):")
    for name, fn in rows:
        size = len(fn()) if name != "validate + trail (every state)" else 0
        print(f"  {name:32s} {per_call_ms(fn):7.3f} ms" + (f"  {size:7d} B" if size else ""))


def run_states(msgs: list[Any], server: VizServer) -> tuple[float, int]:
    """The node's on_state path; returns (mean ms per state, scenes sent)."""
    r = VizRenderer()
    sent = 0
    t0 = time.perf_counter()
    for i, msg in enumerate(msgs):
        r.on_state(msg)
        if server.has_sinks(VIZ_SCENE):
            server.log(VIZ_SCENE, r.scene(with_static=i % 50 == 0).encode(), time.time_ns())
            sent += 1
        if server.has_sinks(VIZ_METRICS):
            server.log(VIZ_METRICS, json.dumps(r.metrics()).encode(), time.time_ns())
    return (time.perf_counter() - t0) / len(msgs) * 1e3, sent


async def client(port: int, seconds: float) -> None:
    import websockets
    from websockets.typing import Subprotocol

    async with websockets.connect(
        f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol("foxglove.sdk.v1")], proxy=None,
        max_size=None,
    ) as ws:
        subscribed = False
        received = 0
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                raw = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            if isinstance(raw, str):
                op = json.loads(raw)
                if op["op"] == "advertise" and not subscribed:
                    subs = [{"id": c["id"], "channelId": c["id"]} for c in op["channels"]]
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    subscribed = True
                    print("subscribed", flush=True)
            else:
                received += len(raw)
        print(f"client received {received} B", flush=True)


def overhead(env_name: str, states: int) -> None:
    msgs = team_messages(env_name, states)
    server = VizServer("127.0.0.1", 0, "bench", lambda line: None)
    idle_ms, sent = run_states(msgs, server)
    print(f"per-state cost, {env_name}, {states} states:")
    print(f"  no client:  {idle_ms:7.3f} ms/state  (scenes encoded: {sent})")
    proc = subprocess.Popen(
        [sys.executable, "-m", "sdhn_experiments.bench.viz", "--client", str(server.port)],
        stdout=subprocess.PIPE, text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert "subscribed" in line, line
    deadline = time.monotonic() + 5
    while (not (server.has_sinks(VIZ_SCENE) and server.has_sinks(VIZ_METRICS))
           and time.monotonic() < deadline):
        time.sleep(0.01)
    busy_ms, sent = run_states(msgs, server)
    print(f"  one client: {busy_ms:7.3f} ms/state  (scenes encoded: {sent}; node's max_rate "
          f"caps this at 30/s live)")
    proc.terminate()
    proc.wait()
    server.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="maif-10")
    parser.add_argument("--states", type=int, default=300)
    parser.add_argument("--client", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.client:
        asyncio.run(client(args.client, 60.0))
        return 0
    encoding_costs(args.env)
    overhead(args.env, args.states)
    return 0


if __name__ == "__main__":
    sys.exit(main())
