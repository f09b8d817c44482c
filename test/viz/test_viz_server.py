"""The viz WebSocket server without ROS: the Foxglove protocol flow, hostile client input, the
handshake deadline, and a slow client's bounded queue."""

from __future__ import annotations

import json
import socket
import struct
import time
from collections.abc import Iterator

import pytest
from websockets.sync.client import connect

from sdhn_sim.ros.topics import VIZ_METRICS, VIZ_SCENE
from sdhn_sim.viz import server as viz_server
from sdhn_sim.viz.server import VizServer

SUBPROTOCOLS = ["foxglove.websocket.v1"]


@pytest.fixture
def served() -> Iterator[tuple[VizServer, list[str]]]:
    lines: list[str] = []
    server = VizServer("127.0.0.1", 0, 2, "test", lines.append)
    try:
        yield server, lines
    finally:
        server.close()


def wait_for(predicate: object, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return True
        time.sleep(0.01)
    return False


def test_advertises_subscribes_sends_and_unsubscribes(served: tuple[VizServer, list[str]]
                                                      ) -> None:
    server, lines = served
    with connect(f"ws://127.0.0.1:{server.port}", subprotocols=SUBPROTOCOLS,
                 proxy=None) as ws:
        info = json.loads(ws.recv(timeout=5))
        assert info["op"] == "serverInfo" and info["name"] == "test", info
        channels = {c["topic"]: c for c in json.loads(ws.recv(timeout=5))["channels"]}
        assert channels[VIZ_SCENE]["schemaName"] == "foxglove.SceneUpdate"
        assert channels[VIZ_METRICS]["schemaEncoding"] == "jsonschema"
        assert not server.has_sinks(VIZ_METRICS)
        # hostile ops first: each ignored, the connection stays usable
        for junk in ("not json", "[" * 10_000 + "]" * 10_000, '{"op": "subscribe"}',
                     '{"op": "subscribe", "subscriptions": [{"id": "x"}]}', "1e999", "{}"):
            ws.send(junk)
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 7, "channelId": channels[VIZ_METRICS]["id"]}]}))
        assert wait_for(lambda: server.has_sinks(VIZ_METRICS)), lines
        assert not server.has_sinks(VIZ_SCENE)
        assert server.new_subscriber.is_set()
        server.log(VIZ_METRICS, b'{"step": 3}', 42)
        raw = ws.recv(timeout=5)
        assert isinstance(raw, bytes) and raw[0] == 1
        assert struct.unpack_from("<IQ", raw, 1) == (7, 42) and raw[13:] == b'{"step": 3}'
        ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds": [7]}))
        assert wait_for(lambda: not server.has_sinks(VIZ_METRICS))
    assert wait_for(lambda: any("disconnected" in ln for ln in lines)), lines
    assert server.active == 0, lines


def test_a_silent_connection_is_closed_after_the_handshake_deadline(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A connection that never upgrades holds a slot only until the deadline."""
    monkeypatch.setattr(viz_server, "HANDSHAKE_TIMEOUT_S", 0.5)
    lines: list[str] = []
    server = VizServer("127.0.0.1", 0, 1, "test", lines.append)
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=10) as silent:
            assert silent.recv(16) == b"", "a silent connection was never closed"
        assert wait_for(lambda: server.active == 0), lines
        with socket.create_connection(("127.0.0.1", server.port), timeout=5):
            assert wait_for(lambda: server.active == 1), "the freed slot is not usable"
    finally:
        server.close()


def test_a_slow_client_loses_old_messages_and_never_blocks_the_caller(
        served: tuple[VizServer, list[str]]) -> None:
    server, lines = served
    with connect(f"ws://127.0.0.1:{server.port}", subprotocols=SUBPROTOCOLS,
                 proxy=None, close_timeout=0.5) as ws:
        ws.recv(timeout=5)
        cid = {c["topic"]: c["id"] for c in json.loads(ws.recv(timeout=5))["channels"]}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": 1, "channelId": cid[VIZ_SCENE]}]}))
        assert wait_for(lambda: server.has_sinks(VIZ_SCENE))
        blob = bytes(16 * 1024)  # the client reads nothing: socket buffers fill, queue fills
        calls = 4 * viz_server.OUTGOING_QUEUE
        for k in range(calls):
            server.log(VIZ_SCENE, blob, k)  # returns at once however full things are
    assert wait_for(lambda: any("messages dropped: slow client" in ln for ln in lines), 15), (
        lines)


def test_close_stops_listening() -> None:
    server = VizServer("127.0.0.1", 0, 2, "test", lambda line: None)
    port = server.port
    server.close()
    assert wait_for(lambda: not server._thread.is_alive()), "the accept loop outlived close()"
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
