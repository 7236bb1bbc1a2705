"""A real HTTP server on 127.0.0.1 whose misbehaviour is chosen by the first path segment.

``http://127.0.0.1:PORT/<mode>`` is a policy base URL: ``/<mode>/info``, ``/<mode>/reset`` ... behave
well except where the mode says otherwise (mostly on ``/act``). It is written on raw sockets so that it
can do what a framework would refuse to: drip bytes, drop the connection, lie about lengths.

With ``secret`` it signs its 200 answers like the SDK does (bound to each request), so that the modes
``replay`` (step 0's signed answer sent again at every later step), ``wrong_episode`` (signed for another
episode id), ``resign_old`` (signed with a timestamp outside the replay window) and ``unsigned`` test the
caller's answer check and nothing else.
"""

from __future__ import annotations

import json
import socket
import socketserver
import threading
import time

from robobpp import protocol as P

GOOD_ACT = {"x": 0.0, "y": 0.0, "orientation": 0}

#: mode → raw JSON body of the /act answer (a 200 with Content-Type application/json).
ACT_BODIES: dict[str, bytes] = {
    "good": json.dumps(GOOD_ACT).encode(),
    "nan": b'{"x": NaN, "y": 0, "orientation": 0}',
    "inf": b'{"x": 0, "y": Infinity, "orientation": 0}',
    "negative": b'{"x": -5, "y": 0, "orientation": 0}',
    "huge": b'{"x": 1e300, "y": 0, "orientation": 0}',
    "wrong_type": b'{"x": "0", "y": 0, "orientation": 0}',
    "bool_orientation": b'{"x": 0, "y": 0, "orientation": true}',
    "bad_orientation": b'{"x": 0, "y": 0, "orientation": 2}',
    "extra": b'{"x": 0, "y": 0, "orientation": 0, "z": 3}',
    "missing": b'{"x": 0, "y": 0}',
    "partial_null": b'{"x": null, "y": 0, "orientation": 0}',
    "no_placement": b'{"x": null, "y": null, "orientation": null, "compute_time": 0.25}',
    "not_object": b"[0, 0, 0]",
    "invalid_json": b'{"x": 0, "y": ',
    "negative_compute": b'{"x": 0, "y": 0, "orientation": 0, "compute_time": -1}',
    "compute_time": b'{"x": 0, "y": 0, "orientation": 0, "compute_time": 0.125}',
}


class _Handler(socketserver.BaseRequestHandler):
    server: HostileServer
    current: tuple[dict[str, str], bytes] = ({}, b"")
    mode = ""
    replayed: tuple[bytes, str] | None = None

    def handle(self) -> None:
        self.server.opened()
        sock: socket.socket = self.request
        sock.settimeout(30)
        buffer = b""
        try:
            while True:
                while b"\r\n\r\n" not in buffer:
                    chunk = sock.recv(65536)
                    if not chunk:
                        return
                    buffer += chunk
                head, _, buffer = buffer.partition(b"\r\n\r\n")
                lines = head.decode("latin-1").split("\r\n")
                method, target, _ = lines[0].split(" ", 2)
                headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
                length = int(headers.get("content-length", "0"))
                while len(buffer) < length:
                    chunk = sock.recv(65536)
                    if not chunk:
                        return
                    buffer += chunk
                body, buffer = buffer[:length], buffer[length:]
                self.server.requests.append((method, target, headers, body))
                self.current = (headers, body)
                if not self.respond(sock, target):
                    return
        except OSError:
            return
        finally:
            self.server.closed()

    def send(
        self, sock: socket.socket, status: str, body: bytes, ctype: str = "application/json", extra: str = ""
    ) -> bool:
        if status.startswith("200") and self.server.secret is not None and "X-Robobpp-" not in extra:
            extra += self.signature(body)
        head = f"HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {len(body)}\r\n{extra}\r\n"
        sock.sendall(head.encode() + body)
        return True

    def signature(self, body: bytes) -> str:
        """Answer-signature header lines for ``body`` as the SDK would sign it (bent by the mode)."""
        headers, request_body = self.current
        mode = self.mode
        if mode == "unsigned":
            return ""
        try:
            request = json.loads(request_body) if request_body else {}
        except ValueError:
            request = {}
        episode_id = str(request.get("episode_id", "")) if isinstance(request, dict) else ""
        step = request.get("step") if isinstance(request, dict) else None
        if mode == "wrong_episode" and step is not None:
            episode_id += "-other"
        now = (
            time.time() - 10 * P.DEFAULT_REPLAY_WINDOW_S
            if mode == "resign_old" and step is not None
            else None
        )
        assert self.server.secret is not None
        signed = P.sign_answer(
            self.server.secret,
            episode_id=episode_id,
            step=step,
            body=body,
            now=now,
            request_signature=headers.get(P.SIGNATURE_HEADER.lower(), ""),
        )
        return "".join(f"{k}: {v}\r\n" for k, v in signed.items())

    def respond(self, sock: socket.socket, target: str) -> bool:
        """Answer one request; False closes the connection."""
        _, mode, endpoint = target.split("/", 2)
        self.mode = mode
        if endpoint == "info":
            if mode == "empty_info":
                return self.send(sock, "200 OK", b"{}")
            protocol = "robobpp/2" if mode == "wrong_protocol" else "robobpp/1"
            return self.send(sock, "200 OK", json.dumps({"protocol": protocol, "name": mode}).encode())
        if endpoint == "reset" and mode == "reset_500":
            return self.send(sock, "500 Internal Server Error", b"boom at reset", "text/plain")
        if endpoint in ("reset", "close"):
            return self.send(sock, "200 OK", b"{}")
        # endpoint == "act"
        if mode == "replay":  # the first signed answer of the connection, byte for byte, every time
            if self.replayed is None:
                body = json.dumps(GOOD_ACT).encode()
                self.replayed = (body, self.signature(body))
            return self.send(sock, "200 OK", self.replayed[0], extra=self.replayed[1])
        if mode in ACT_BODIES:
            return self.send(sock, "200 OK", ACT_BODIES[mode])
        if mode in ("unsigned", "wrong_episode", "resign_old"):
            return self.send(sock, "200 OK", ACT_BODIES["good"])
        if mode == "error500":
            return self.send(sock, "500 Internal Server Error", b'{"error": "kaput"}')
        if mode == "html":
            return self.send(sock, "200 OK", b"<html>hello</html>", "text/html")
        if mode == "gzip":
            return self.send(sock, "200 OK", b"\x1f\x8b\x08\x00", extra="Content-Encoding: gzip\r\n")
        if mode == "redirect":
            return self.send(sock, "302 Found", b"", extra="Location: http://169.254.169.254/act\r\n")
        if mode == "big":  # 10 MB, honestly declared
            return self.send(sock, "200 OK", b'{"x": "' + b"a" * 10_000_000 + b'"}')
        if mode == "big_chunked":  # 10 MB with no length: only counting the bytes can stop it
            sock.sendall(
                b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
            )
            piece = b"a" * 65536
            for _ in range(160):
                sock.sendall(b"%x\r\n%s\r\n" % (len(piece), piece))
            sock.sendall(b"0\r\n\r\n")
            return False
        if mode == "slow":
            time.sleep(self.server.slow_s)
            return self.send(sock, "200 OK", ACT_BODIES["good"])
        if mode == "drip":  # a header byte at a time, forever: per-read timeouts never fire
            sock.sendall(b"HTTP/1.1 200 OK\r\nX-Drip: ")
            for _ in range(int(self.server.slow_s / 0.05)):
                sock.sendall(b"a")
                time.sleep(0.05)
            return False
        if mode == "drop":
            sock.shutdown(socket.SHUT_RDWR)
            return False
        if mode == "garbage":
            sock.sendall(b"this is not http\r\n\r\n")
            return False
        raise AssertionError(f"unknown mode {mode!r}")


class HostileServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, slow_s: float = 3.0, secret: str | None = None) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.slow_s = slow_s
        self.secret = secret
        self.requests: list[tuple[str, str, dict[str, str], bytes]] = []
        self._lock = threading.Lock()
        self.open_connections = 0
        self.total_connections = 0
        self._thread = threading.Thread(
            target=self.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        assert isinstance(host, str)  # bound to "127.0.0.1" above (the stub's address also admits bytes)
        return f"http://{host}:{port}"

    def opened(self) -> None:
        with self._lock:
            self.open_connections += 1
            self.total_connections += 1

    def closed(self) -> None:
        with self._lock:
            self.open_connections -= 1

    def wait_all_closed(self, within_s: float = 15.0) -> bool:
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            if self.open_connections == 0:
                return True
            time.sleep(0.02)
        return self.open_connections == 0

    def __enter__(self) -> HostileServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()
        self.server_close()
