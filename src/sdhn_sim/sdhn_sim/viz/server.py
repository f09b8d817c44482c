"""The viz WebSocket server: the Foxglove WebSocket protocol (``foxglove.websocket.v1``) on one
listening socket that we own, with a connection limit and a log of who connects.

It replaces the Foxglove SDK's server, which binds a port of its own: behind a gate in front
of it, any local process could still connect to that loopback port directly, past the limit and
unlogged. Here the only listening socket is this server's, so every connection is counted
(``max_clients``; more are logged and closed at once), logged with its address and the Origin
of its upgrade request, and given ``HANDSHAKE_TIMEOUT_S`` to complete the WebSocket handshake.

What it speaks (enough for the Foxglove app and for ``test/ros/test_viz.py``'s client): on
connect ``serverInfo`` and ``advertise`` (every channel, schema from
:func:`sdhn_sim.viz.channels.channel_specs`); from the client ``subscribe`` / ``unsubscribe``;
to the client binary message data (opcode 1, subscription id, log time, payload). Anything
else a client sends is ignored. Each client has a bounded outgoing queue drained by its own
thread: a slow viewer loses its oldest data messages (counted), it never blocks the caller of
:meth:`VizServer.log` (a ROS callback). Stdlib + ``websockets``; no ROS.

    server = VizServer("127.0.0.1", 8765, max_clients=8, name="sdhn viz", log=print)
    if server.has_sinks("/viz/scene"):
        server.log("/viz/scene", scene.encode(), time.time_ns())
    server.close()
"""

from __future__ import annotations

import base64
import contextlib
import errno
import ipaddress
import json
import logging
import queue
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request
from websockets.protocol import State
from websockets.server import ServerProtocol
from websockets.sync.server import Server, ServerConnection
from websockets.typing import Subprotocol

from sdhn_sim.viz.channels import VIZ_TOPICS, channel_specs

SUBPROTOCOLS = [Subprotocol("foxglove.websocket.v1"), Subprotocol("foxglove.sdk.v1")]
HANDSHAKE_TIMEOUT_S = 10.0
CLOSE_TIMEOUT_S = 2.0  # a refused upgrade or a closing client: the slot is free after this
MAX_INCOMING = 64 * 1024  # bytes per client message (a client only sends small JSON ops)
OUTGOING_QUEUE = 1024  # messages per client; the oldest data message goes when full
MESSAGE_DATA = 1  # binary opcode of the Foxglove WebSocket protocol

# websockets logs a failed handshake or a client that drops with a traceback; this server says
# what matters in its own lines (connected, Origin, disconnected), so the library stays quiet.
_QUIET = logging.getLogger("sdhn_sim.viz.server.websockets")
_QUIET.addHandler(logging.NullHandler())
_QUIET.propagate = False


class BindError(OSError):
    """The server cannot listen; ``field`` names the setting at fault ('host' or 'port')."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field
        self.message = message


def ws_url(host: str, port: int) -> str:
    """``ws://host:port``, with an IPv6 address in brackets as URLs need."""
    try:
        if ipaddress.ip_address(host).version == 6:
            return f"ws://[{host}]:{port}"
    except ValueError:
        pass
    return f"ws://{host}:{port}"


def listen(host: str, port: int) -> socket.socket:
    """A listening TCP socket on (host, port); :class:`BindError` naming ``host`` when the
    address is unknown or not one of this machine's, ``port`` when the port is taken or not
    allowed."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as e:
        raise BindError("host", f"cannot resolve {host!r} ({e})") from None
    family, _, _, _, address = infos[0]
    try:
        return socket.create_server(address, family=family, reuse_port=False)
    except OSError as e:
        where = ws_url(host, port).removeprefix("ws://")
        field = "host" if e.errno in (errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT) else "port"
        raise BindError(field, f"cannot serve on {where} ({e.strerror or e})") from None


class _Client:
    """One connected viewer: its subscriptions and its outgoing queue."""

    def __init__(self, who: str, conn: ServerConnection) -> None:
        self.who = who
        self.conn = conn
        self.subscriptions: dict[int, int] = {}  # subscription id -> channel id
        self.outgoing: queue.Queue[str | bytes | None] = queue.Queue(OUTGOING_QUEUE)
        self.dropped = 0

    def put_final(self) -> None:
        """Tell the sender thread to end (after what is queued, or at once when full)."""
        with contextlib.suppress(queue.Full):
            self.outgoing.put_nowait(None)
            return
        with contextlib.suppress(queue.Empty):
            self.outgoing.get_nowait()
        with contextlib.suppress(queue.Full):
            self.outgoing.put_nowait(None)

    def put(self, item: str | bytes) -> None:
        while True:
            try:
                self.outgoing.put_nowait(item)
                return
            except queue.Full:
                with contextlib.suppress(queue.Empty):
                    self.outgoing.get_nowait()
                    self.dropped += 1


class VizServer:
    def __init__(self, host: str, port: int, max_clients: int, name: str,
                 log: Callable[[str], None]) -> None:
        self.name = name
        self.max_clients = max_clients
        self.log_line = log
        self.refused = 0
        self.new_subscriber = threading.Event()
        self.channels = {topic: k + 1 for k, topic in enumerate(VIZ_TOPICS)}
        self._advertise = json.dumps({"op": "advertise", "channels": [
            self._channel_json(topic, cid) for topic, cid in self.channels.items()]})
        self._clients: set[_Client] = set()
        self._pending = 0  # accepted, not yet handshaken (they count against max_clients)
        self._lock = threading.Lock()
        self._session = str(time.time_ns())
        self.sock = listen(host, port)
        self.port = int(self.sock.getsockname()[1])
        # websockets' connections want their server (for its shutdown flag); its own accept
        # loop (serve_forever) never runs: ours above counts and logs every connection first.
        self._ws = Server(self.sock, lambda _sock, _addr: None, logger=_QUIET)
        self._thread = threading.Thread(target=self._accept, name="viz-server", daemon=True)
        self._thread.start()

    @staticmethod
    def _channel_json(topic: str, cid: int) -> dict[str, Any]:
        spec = channel_specs()[topic]
        schema = (base64.b64encode(spec.schema_data).decode() if spec.schema_encoding ==
                  "protobuf" else spec.schema_data.decode())
        return {"id": cid, "topic": topic, "encoding": spec.message_encoding,
                "schemaName": spec.schema_name, "schema": schema,
                "schemaEncoding": spec.schema_encoding}

    # -- the caller's side
    def has_sinks(self, topic: str) -> bool:
        """True when a connected client subscribes to ``topic`` (else nothing need be built)."""
        cid = self.channels[topic]
        with self._lock:
            return any(cid in c.subscriptions.values() for c in self._clients)

    def log(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Queue ``data`` for every client subscribed to ``topic`` (never blocks)."""
        cid = self.channels[topic]
        with self._lock:
            targets = [(c, sub) for c in self._clients
                       for sub, ch in c.subscriptions.items() if ch == cid]
        for client, sub in targets:
            client.put(struct.pack("<BIQ", MESSAGE_DATA, sub, log_time_ns) + data)

    @property
    def active(self) -> int:
        with self._lock:
            return len(self._clients) + self._pending

    def close(self) -> None:
        self._ws.socket_closed.set()  # a handshake still under way is refused
        with contextlib.suppress(OSError):  # wakes the accept loop (close alone does not)
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            with contextlib.suppress(Exception):
                c.conn.close()

    # -- connections
    def _accept(self) -> None:
        while True:
            try:
                sock, addr = self.sock.accept()
            except OSError:
                return  # closed
            who = f"{addr[0]}:{addr[1]}"
            with self._lock:
                full = len(self._clients) + self._pending >= self.max_clients
                if full:
                    self.refused += 1
                else:
                    self._pending += 1
                n = len(self._clients) + self._pending
            if full:
                self.log_line(f"refused {who}: {self.max_clients} clients connected "
                              "(max_clients)")
                sock.close()
                continue
            self.log_line(f"client connected from {who} ({n}/{self.max_clients})")
            threading.Thread(target=self._serve, args=(sock, who), name=f"viz {who}",
                             daemon=True).start()

    def _serve(self, sock: socket.socket, who: str) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, True)
        conn = ServerConnection(
            sock, ServerProtocol(subprotocols=SUBPROTOCOLS, max_size=MAX_INCOMING, logger=_QUIET),
            self._ws,
            close_timeout=CLOSE_TIMEOUT_S)
        client = _Client(who, conn)
        def origin(_conn: ServerConnection, request: Request) -> None:
            """Log where the upgrade request comes from as soon as it is read."""
            self.log_line(f"client {who}: Origin {request.headers.get('Origin', 'none')[:200]}")

        try:
            conn.handshake(process_request=origin, timeout=HANDSHAKE_TIMEOUT_S)
            if conn.protocol.state is not State.OPEN:
                return  # not a WebSocket upgrade: answered with an HTTP error
            conn.start_keepalive()
            with self._lock:
                self._pending -= 1
                self._clients.add(client)
            sender = threading.Thread(target=self._send, args=(conn, client), daemon=True)
            sender.start()
            client.put(json.dumps({"op": "serverInfo", "name": self.name, "capabilities": [],
                                   "supportedEncodings": [], "metadata": {},
                                   "sessionId": self._session}))
            client.put(self._advertise)
            for raw in conn:
                if isinstance(raw, str):
                    self._on_text(client, raw)
        except (ConnectionClosed, OSError, TimeoutError, ValueError):
            pass  # a client that leaves, times out or speaks something else: just gone
        except Exception as e:
            self.log_line(f"client {who}: closed ({type(e).__name__})")
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.discard(client)
                else:
                    self._pending -= 1
            client.put_final()
            with contextlib.suppress(Exception):
                conn.close()
            with contextlib.suppress(OSError):
                sock.close()
            lost = f" ({client.dropped} messages dropped: slow client)" if client.dropped else ""
            self.log_line(f"client {who} disconnected{lost}")

    def _send(self, conn: ServerConnection, client: _Client) -> None:
        with contextlib.suppress(ConnectionClosed, OSError):
            while (item := client.outgoing.get()) is not None:
                conn.send(item)

    def _on_text(self, client: _Client, raw: str) -> None:
        """``subscribe`` / ``unsubscribe``; anything else (or malformed) is ignored."""
        try:
            op = json.loads(raw)
            if not isinstance(op, dict):
                return
            if op.get("op") == "subscribe":
                known = set(self.channels.values())
                subs = {int(s["id"]): int(s["channelId"]) for s in op.get("subscriptions", [])
                        if int(s["channelId"]) in known}
                with self._lock:
                    client.subscriptions.update(subs)
                if subs:
                    self.new_subscriber.set()
            elif op.get("op") == "unsubscribe":
                with self._lock:
                    for sub in op.get("subscriptionIds", []):
                        client.subscriptions.pop(int(sub), None)
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError,
                OverflowError):
            return
