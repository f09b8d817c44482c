"""The viz WebSocket server: the Foxglove SDK's server (``foxglove.start_server``, written in Rust
and maintained by Foxglove) with our channels, a connection log and a bounded shutdown.

The SDK speaks the Foxglove WebSocket protocol (subprotocol ``foxglove.sdk.v1``, which the
Foxglove app offers); it parses every client message itself, keeps one subscription per channel
and client, and gives each client a bounded outgoing queue (``message_backlog_size``: the oldest
data message goes when full), so a viewer that never reads costs the others nothing. What this
module adds around it:

- the five viz channels with the schemas of :func:`sdhn_sim.viz.channels.channel_specs` (the same
  ones recordings carry), in a ``foxglove.Context`` of its own;
- the SDK's own log lines about clients (``Registered client ADDR``, ``Unregistered client``,
  invalid messages, full queues) passed to ``log`` one whole line at a time, cut to
  ``MAX_LOG_LINE`` characters and at most ``LOG_BURST`` lines per ``LOG_WINDOW_S`` (a client that
  sends garbage in a loop cannot flood the node's log);
- :meth:`VizServer.close` that returns within ``CLOSE_TIMEOUT_S``: the SDK's ``stop()`` waits for
  every client to take its close frame, forever for one that never reads (measured: still
  waiting after 200 s), so it runs on a thread of its own and the process may exit past it.

What the SDK does not offer, and this module therefore does not either: a limit on connected
clients, the Origin of an upgrade request, a deadline for a connection that never upgrades. The
default host is loopback; viewers on other machines come through an SSH tunnel (docs/foxglove.md).

    server = VizServer("127.0.0.1", 8765, name="sdhn viz", log=print)
    if server.has_sinks("/viz/scene"):
        server.log("/viz/scene", scene.encode(), time.time_ns())
    server.close()
"""

from __future__ import annotations

import ipaddress
import logging
import re
import threading
import time
from collections.abc import Callable

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener

from sdhn_sim.viz.channels import VIZ_TOPICS, channel_specs

SUBPROTOCOL = "foxglove.sdk.v1"  # the one the SDK's server accepts (the app offers it)
MESSAGE_BACKLOG = 1024  # outgoing messages per client; the oldest data message goes when full
CLOSE_TIMEOUT_S = 2.0  # close() waits this long for the SDK's stop(), then lets it go
MAX_LOG_LINE = 300  # characters of one SDK log line passed on (a client's junk is echoed in it)
LOG_BURST = 20  # SDK lines passed on per window; more are counted and reported with the next
LOG_WINDOW_S = 10.0
_SDK_LOGGER = "foxglove.websocket"
_QUIET_PREFIXES = ("Started server", "Shutting down", "Shutdown complete")  # said by us instead


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


def bind_error(host: str, port: int, error: Exception) -> BindError:
    """The SDK's bind failure as a :class:`BindError`: ``host`` for an address that is unknown or
    not this machine's, ``port`` for a port taken or not allowed."""
    reason = str(error).removeprefix("FoxgloveError: ").removeprefix("Failed to bind port: ")
    host_fault = ("lookup address" in reason or "os error 99)" in reason
                  or "os error 97)" in reason or "invalid socket address" in reason.lower())
    where = ws_url(host, port).removeprefix("ws://")
    return BindError("host" if host_fault else "port", f"cannot serve on {where} ({reason})")


class _SubscribeEvents(ServerListener):
    """Sets ``new_subscriber`` when a client subscribes (the node then sends the static map)."""

    def __init__(self, event: threading.Event) -> None:
        self.event = event

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.event.set()

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        return None


class _LineLog(logging.Handler):
    """Passes the SDK's records to ``log``: whole lines, bounded in length and in rate."""

    def __init__(self, log: Callable[[str], None]) -> None:
        super().__init__(logging.INFO)
        self.out = log
        self.window_start = time.monotonic()
        self.in_window = 0
        self.suppressed = 0
        self._lines = threading.Lock()  # one line at a time from the SDK's threads

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # a record that cannot be formatted is not worth a traceback
            return
        if text.startswith(_QUIET_PREFIXES):
            return
        text = re.sub(r"\s+", " ", text)
        if len(text) > MAX_LOG_LINE:
            text = text[:MAX_LOG_LINE] + f"... ({len(text)} characters)"
        with self._lines:
            now = time.monotonic()
            if now - self.window_start >= LOG_WINDOW_S:
                self.window_start, self.in_window = now, 0
            if self.in_window >= LOG_BURST:
                self.suppressed += 1
                return
            self.in_window += 1
            if self.suppressed:
                self.out(f"server: {self.suppressed} more log lines suppressed "
                         f"(at most {LOG_BURST} per {LOG_WINDOW_S:.0f} s)")
                self.suppressed = 0
            self.out(f"server: {text}")

    def flush_suppressed(self) -> None:
        with self._lines:
            if self.suppressed:
                self.out(f"server: {self.suppressed} more log lines suppressed")
                self.suppressed = 0


class VizServer:
    """The viz channels served by the Foxglove SDK on ``host:port`` (``port`` 0: any free one,
    then in ``self.port``). :class:`BindError` when it cannot listen."""

    def __init__(self, host: str, port: int, name: str, log: Callable[[str], None],
                 backlog: int = MESSAGE_BACKLOG) -> None:
        self.name = name
        self.log_line = log
        self.new_subscriber = threading.Event()
        self.context = foxglove.Context()
        specs = channel_specs()
        self.channels = {
            topic: foxglove.Channel(
                topic, context=self.context, message_encoding=specs[topic].message_encoding,
                schema=foxglove.Schema(name=specs[topic].schema_name,
                                       encoding=specs[topic].schema_encoding,
                                       data=specs[topic].schema_data))
            for topic in VIZ_TOPICS}
        self._handler = _LineLog(log)
        sdk_log = logging.getLogger(_SDK_LOGGER)
        sdk_log.setLevel(logging.INFO)
        sdk_log.propagate = False  # its lines go through the handler only, not twice via root
        sdk_log.addHandler(self._handler)
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=port, context=self.context,
                server_listener=_SubscribeEvents(self.new_subscriber),
                message_backlog_size=backlog)
        except RuntimeError as error:
            sdk_log.removeHandler(self._handler)
            raise bind_error(host, port, error) from None
        self.port = int(self._server.port)
        self._closed = False

    def has_sinks(self, topic: str) -> bool:
        """True when a connected client subscribes to ``topic`` (else nothing need be built)."""
        return bool(self.channels[topic].has_sinks())

    def log(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Queue ``data`` for every client subscribed to ``topic`` (never blocks on a client)."""
        self.channels[topic].log(data, log_time=log_time_ns)

    def close(self) -> bool:
        """Stop serving. True when the SDK's stop() returned within ``CLOSE_TIMEOUT_S``; False
        when a client that does not read still holds it (logged; the process may exit anyway)."""
        if self._closed:
            return True
        self._closed = True
        stopper = threading.Thread(target=self._server.stop, name="viz-server-stop", daemon=True)
        stopper.start()
        stopper.join(CLOSE_TIMEOUT_S)
        self._handler.flush_suppressed()
        logging.getLogger(_SDK_LOGGER).removeHandler(self._handler)
        if stopper.is_alive():
            self.log_line(f"server: a client did not take its close frame within "
                          f"{CLOSE_TIMEOUT_S:.0f} s; stopped without it")
            return False
        return True
