"""A TCP gate in front of the Foxglove WebSocket server: a connection limit and a log of who
connects (the foxglove SDK has neither).

The SDK server binds 127.0.0.1 on a free port; the gate listens on the address and port the user
asked for, accepts at most ``max_clients`` connections at a time (more are logged and closed at
once), logs each client's address when it connects and when it leaves, and copies bytes both
ways; the Origin header of each client's upgrade request is logged too. Stdlib only, no ROS;
one thread per direction per client.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable

BUFFER = 64 * 1024


def origin_of(request: bytes) -> str:
    """The Origin header of an HTTP request's first bytes ('none' when there is none)."""
    for line in request.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"origin":
            return value.strip().decode("ascii", "replace")[:200] or "none"
        if not line:
            break
    return "none"


class Gate:
    def __init__(self, host: str, port: int, backend_port: int, max_clients: int,
                 log: Callable[[str], None]) -> None:
        self.backend = ("127.0.0.1", backend_port)
        self.max_clients = max_clients
        self.log = log
        self.active = 0
        self.refused = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.sock = socket.create_server((host, port), reuse_port=False)
        self.port = int(self.sock.getsockname()[1])
        self._thread = threading.Thread(target=self._accept, name="viz-gate", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, addr = self.sock.accept()
            except OSError:
                return  # closed
            who = f"{addr[0]}:{addr[1]}"
            with self._lock:
                full = self.active >= self.max_clients
                if not full:
                    self.active += 1
                else:
                    self.refused += 1
                n = self.active
            if full:
                self.log(f"refused {who}: {self.max_clients} clients connected (max_clients)")
                client.close()
                continue
            try:
                upstream = socket.create_connection(self.backend, timeout=5)
                upstream.settimeout(None)
            except OSError as e:
                self.log(f"client {who}: viz server unreachable ({e}); closed")
                client.close()
                self._left()
                continue
            self.log(f"client connected from {who} ({n}/{self.max_clients})")
            done = threading.Event()
            for a, b, first in ((client, upstream, True), (upstream, client, False)):
                threading.Thread(target=self._pump, args=(a, b, done, who, first),
                                 daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, done: threading.Event,
              who: str, request: bool = False) -> None:
        try:
            while True:
                data = src.recv(BUFFER)
                if not data:
                    break
                if request:  # the client's HTTP upgrade request: say where it comes from
                    request = False
                    self.log(f"client {who}: Origin {origin_of(data)}")
                dst.sendall(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
            with self._lock:  # the first direction to end reports and counts
                first = not done.is_set()
                done.set()
            if first:
                self._left()
                self.log(f"client {who} disconnected")
            src.close()

    def _left(self) -> None:
        with self._lock:
            self.active -= 1

    def close(self) -> None:
        self._stop.set()
        self.sock.close()
