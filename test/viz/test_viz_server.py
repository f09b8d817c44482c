"""The viz WebSocket server (the Foxglove SDK's, behind ``sdhn_sim.viz.server``) without ROS: the
protocol flow with a real client, and the three attacks that broke the project's own server
(issue 54, items 1-3): an out-of-range subscription id, clients that never read, thousands of
subscriptions on one channel. Plus a seeded fuzz of client messages."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import random
import socket
import struct
import threading
import time
from collections.abc import Iterator

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from sdhn_base.ros.topics import VIZ_METRICS, VIZ_SCENE
from sdhn_sim.viz.channels import VIZ_TOPICS, channel_specs
from sdhn_sim.viz.server import SUBPROTOCOL, VizServer

# What the Foxglove app offers; the SDK picks foxglove.sdk.v1.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


@pytest.fixture
def served() -> Iterator[tuple[VizServer, list[str]]]:
    lines: list[str] = []
    server = VizServer("127.0.0.1", 0, "test", lines.append)
    try:
        yield server, lines
    finally:
        server.close()


def wait_for(predicate: object, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(0.01)
    return False


def viewer(port: int) -> ClientConnection:
    return connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS,  # type: ignore[arg-type]
                   proxy=None, close_timeout=1, max_size=None)


def hello(ws: ClientConnection) -> dict[str, int]:
    """Read serverInfo and advertise; topic -> channel id."""
    info = json.loads(ws.recv(timeout=5))
    assert info["op"] == "serverInfo", info
    channels: dict[str, int] = {}
    while set(channels) != set(VIZ_TOPICS):
        op = json.loads(ws.recv(timeout=5))
        if op["op"] == "advertise":
            channels.update({c["topic"]: c["id"] for c in op["channels"]})
    return channels


def data_messages(ws: ClientConnection, settle: float = 0.5) -> list[tuple[int, int, bytes]]:
    """Every message-data frame until none comes for ``settle`` s: (sub id, log time, payload)."""
    out = []
    while True:
        try:
            raw = ws.recv(timeout=settle)
        except TimeoutError:
            return out
        if isinstance(raw, bytes) and raw[0] == 1:
            sub, log_time = struct.unpack_from("<IQ", raw, 1)
            out.append((sub, log_time, raw[13:]))


def test_advertises_the_project_schemas_subscribes_sends_and_unsubscribes(
        served: tuple[VizServer, list[str]]) -> None:
    server, lines = served
    with viewer(server.port) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        info = json.loads(ws.recv(timeout=5))
        assert info["op"] == "serverInfo" and info["name"] == "test", info
        advertised = {c["topic"]: c for c in json.loads(ws.recv(timeout=5))["channels"]}
        for topic, spec in channel_specs().items():  # the recordings' schemas, byte for byte
            c = advertised[topic]
            assert (c["schemaName"], c["schemaEncoding"], c["encoding"]) == (
                spec.schema_name, spec.schema_encoding, spec.message_encoding), c
            schema = (base64.b64decode(c["schema"]) if spec.schema_encoding == "protobuf"
                      else c["schema"].encode())
            assert schema == spec.schema_data, topic
        assert not server.has_sinks(VIZ_METRICS)
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 7, "channelId": advertised[VIZ_METRICS]["id"]}]}))
        assert wait_for(lambda: server.has_sinks(VIZ_METRICS)), lines
        assert not server.has_sinks(VIZ_SCENE)
        assert server.new_subscriber.is_set()
        server.log(VIZ_METRICS, b'{"step": 3}', 42)
        assert data_messages(ws) == [(7, 42, b'{"step": 3}')]
        ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [7]}))
        assert wait_for(lambda: not server.has_sinks(VIZ_METRICS))
    assert wait_for(lambda: any("Unregistered client 127.0.0.1" in ln for ln in lines)), lines
    assert any("Registered client 127.0.0.1" in ln for ln in lines), lines


def test_an_out_of_range_subscription_id_is_refused_and_the_server_goes_on(
        served: tuple[VizServer, list[str]]) -> None:
    """Item 1: id 2**32 passed the old server's parser, then struct.pack raised in log(): the
    viz node died in its ROS callback."""
    server, lines = served
    with viewer(server.port) as ws:
        cid = hello(ws)
        for bad in (2**32, -1, 2**64, 1.5, "7", None):
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": bad, "channelId": cid[VIZ_SCENE]}]}))
        time.sleep(0.3)
        server.log(VIZ_SCENE, b"scene", 1)  # raised struct.error with the old server
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 3, "channelId": cid[VIZ_SCENE]}]}))
        assert wait_for(lambda: server.has_sinks(VIZ_SCENE))
        data_messages(ws, 0.2)
        server.log(VIZ_SCENE, b"scene", 2)
        assert data_messages(ws) == [(3, 2, b"scene")]
    assert any("4294967296" in ln for ln in lines), lines  # the refusal is in the log


def test_thousands_of_subscriptions_on_one_channel_are_one_subscription(
        served: tuple[VizServer, list[str]]) -> None:
    """Item 3: 44,000 ids on one channel made the old server send every message 44,000 times
    and starved the other viewers. The SDK keeps one subscription per channel and client (a
    repeat is answered with a status message; a client that piles up unread replies is
    disconnected)."""
    server, lines = served
    hostile = viewer(server.port)
    with viewer(server.port) as ws:
        cid = hello(hostile)
        with contextlib.suppress(ConnectionClosed, OSError):  # it may be cut off on the way
            for first in range(0, 5000, 1000):  # 1,000 per message (~40 kB), 5,000 in all
                hostile.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": k, "channelId": cid[VIZ_METRICS]} for k in range(first, first + 1000)]}))
            for k in range(5000, 6000):  # one at a time, too
                hostile.send(json.dumps({"op": "subscribe", "subscriptions": [
                    {"id": k, "channelId": cid[VIZ_METRICS]}]}))
        hello(ws)
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 1, "channelId": cid[VIZ_METRICS]}]}))
        assert wait_for(lambda: server.has_sinks(VIZ_METRICS))
        time.sleep(0.5)
        data_messages(ws, 0.2)
        for k in range(10):
            server.log(VIZ_METRICS, b"{}", k)
        assert [m[:2] for m in data_messages(ws)] == [(1, k) for k in range(10)]
        try:
            hostile_got = len(data_messages(hostile))
        except (ConnectionClosed, OSError):  # disconnected for its unread replies: fine too
            hostile_got = 0
    with contextlib.suppress(ConnectionClosed, OSError):
        hostile.close()
    assert hostile_got <= 10, f"10 log() calls reached the hostile client {hostile_got} times"
    assert len(lines) < 100, f"{len(lines)} log lines for one hostile client"


def raw_upgrade(port: int, subscribe_to: int) -> socket.socket:
    """A client that completes the handshake, subscribes, and then never reads a byte."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall(f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
              f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
              f"Sec-WebSocket-Protocol: {SUBPROTOCOL}\r\n\r\n".encode())
    assert b" 101 " in s.recv(200)
    op = json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": subscribe_to}]})
    payload = op.encode()
    s.sendall(bytes([0x81, 0x80 | len(payload)]) + b"\0\0\0\0" + payload)  # zero mask
    return s


def test_clients_that_never_read_neither_lock_out_nor_slow_a_viewer_nor_hold_shutdown() -> None:
    """Item 2: the old server blocked in sendall() for a client that never read; 8 of them
    locked every real viewer out, and stopping waited on them."""
    lines: list[str] = []
    server = VizServer("127.0.0.1", 0, "test", lines.append, backlog=64)
    hogs: list[socket.socket] = []
    try:
        with viewer(server.port) as probe:
            scene = hello(probe)[VIZ_SCENE]
        hogs = [raw_upgrade(server.port, scene) for _ in range(10)]
        assert wait_for(lambda: server.has_sinks(VIZ_SCENE))
        with viewer(server.port) as ws:  # the 11th client: still let in
            assert hello(ws)[VIZ_SCENE] == scene
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": 9, "channelId": scene}]}))
            time.sleep(0.5)
            blob = bytes(64 * 1024)
            received = []
            for k in range(300):  # 20 MB to each hog: their queues overflow
                server.log(VIZ_SCENE, blob, k)
                while True:  # the reader keeps up (one message at a time), whatever the load
                    raw = ws.recv(timeout=30)
                    if isinstance(raw, bytes):
                        received.append(struct.unpack_from("<IQ", raw, 1)[1])
                        break
        assert received == list(range(300)), "the reading viewer lost messages to the hogs"
        assert any("full" in ln for ln in lines), lines  # the SDK says a queue overflowed
        stopper = threading.Thread(target=server.close)
        stopper.start()
        stopper.join(30)
        assert not stopper.is_alive(), "close() hangs while clients that never read are connected"
    finally:
        for s in hogs:
            s.close()
        server.close()


def fuzz_op(rng: random.Random, cid: list[int]) -> str | bytes:
    """One hostile client message: a mutated protocol op, random JSON, or random bytes."""
    values: list[object] = [0, 1, -1, 2**31, 2**32, 2**63, 2**64, 1e308, float("nan"), "1", None,
                            True, [], {}, "x" * 1000, rng.choice(cid)]
    kind = rng.randrange(6)
    if kind == 0:
        return json.dumps({"op": "subscribe", "subscriptions": [
            {"id": rng.choice(values), "channelId": rng.choice(values)}
            for _ in range(rng.randrange(4))]})
    if kind == 1:
        return json.dumps({"op": "unsubscribe", "subscriptionIds": [
            rng.choice(values) for _ in range(rng.randrange(4))]})
    if kind == 2:
        return json.dumps({"op": rng.choice(["advertise", "getParameters", "subscribeConnection"
                                              "Graph", "callService", "fetchAsset", "", "x"]),
                           rng.choice(["id", "channels", "parameterNames", "x"]):
                           rng.choice(values)})
    if kind == 3:
        return bytes([rng.randrange(256) for _ in range(rng.randrange(1, 40))])
    if kind == 4:
        text = json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": cid[0]}]})
        k = rng.randrange(len(text))
        return text[:k] + chr(rng.randrange(32, 127)) + text[k + 1:]
    return "[" * rng.randrange(1, 3000) + "]" * rng.randrange(0, 3000)


def test_fuzzed_client_messages_leave_the_server_serving(
        served: tuple[VizServer, list[str]]) -> None:
    """Item 9: 3,000 seeded hostile messages (mutated ops, out-of-range values, binary junk, deep
    nesting) on one connection; then a fresh viewer subscribes and receives, and the log stays
    bounded."""
    server, lines = served
    rng = random.Random(54)
    with viewer(server.port) as ws:
        cid = list(hello(ws).values())
        for _ in range(3000):
            try:
                ws.send(fuzz_op(rng, cid))
            except Exception:  # the server may close a connection that speaks garbage
                break
    with viewer(server.port) as ws:
        channels = hello(ws)
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 1, "channelId": channels[VIZ_METRICS]}]}))
        assert wait_for(lambda: server.has_sinks(VIZ_METRICS))
        data_messages(ws, 0.2)
        server.log(VIZ_METRICS, b"{}", 1)
        assert [m[0] for m in data_messages(ws)] == [1]
    assert len(lines) < 100, f"{len(lines)} log lines from one hostile client"
    assert all(len(ln) < 400 for ln in lines), max(lines, key=len)
