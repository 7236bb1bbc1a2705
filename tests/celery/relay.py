"""A TCP relay in front of a real broker that a test can switch off and on.

Switched off, every open connection is cut and every new one is reset as soon as it is accepted: what a
broker restart looks like to its clients, without touching the broker itself (it is shared with other tests
and other runs).

The listening socket stays bound from the relay's creation to ``close``. An earlier relay closed it while down,
which freed its port for anyone: another test's relay (to the same Redis) or server could be handed that
port by the kernel, and the "unreachable" broker then answered through it — the outage this relay was meant
to cause never happened (a CI run saw no failed round at all).
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading


class Relay:
    """127.0.0.1:<port> → the target, switchable."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self.listener = socket.socket()
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(64)
        self.port: int = self.listener.getsockname()[1]
        self.is_up = False
        self.closed = False
        self.conns: list[socket.socket] = []
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def up(self) -> None:
        self.is_up = True

    def down(self) -> None:
        """Cut every open connection; refuse new ones until :meth:`up` (the port stays this relay's)."""
        self.is_up = False
        with self.lock:
            conns, self.conns = self.conns, []
        for c in conns:
            _cut(c)

    def close(self) -> None:
        """Down for good: the port is released."""
        self.down()
        self.closed = True
        with contextlib.suppress(OSError):
            self.listener.shutdown(socket.SHUT_RDWR)
        self.listener.close()

    def _accept(self) -> None:
        while not self.closed:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            if not self.is_up:
                _cut(client)
                continue
            try:
                upstream = socket.create_connection(self.target, timeout=5)
                upstream.settimeout(None)
            except OSError:
                _cut(client)
                continue
            with self.lock:
                self.conns += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while data := src.recv(65536):
                dst.sendall(data)
        with contextlib.suppress(OSError):
            dst.shutdown(socket.SHUT_RDWR)


def _cut(conn: socket.socket) -> None:
    """Close with a reset (linger 0), as a restarted broker's kernel answers an old or a new connection."""
    with contextlib.suppress(OSError):
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    with contextlib.suppress(OSError):
        conn.shutdown(socket.SHUT_RDWR)
    conn.close()
