"""Several API processes on one port: ``robobpp serve --server-workers N``.

One Python process serves the API on one core. With ``N`` > 1 the process ``robobpp serve`` starts becomes a
supervisor that serves nothing itself:

1. it applies the migrations and seeds the database once (:func:`robobpp.server.bootstrap.bootstrap`), so
   ``N`` processes never race to create the same rows;
2. it starts what runs the episodes once (:func:`robobpp.server.app.start_executor`: the local worker pool,
   or the Celery dispatcher), and the board worker once (:func:`robobpp.server.app.start_board_worker`), not
   once per API process;
3. it binds the port and starts ``N`` API processes (spawned: fresh interpreters) that all accept on that
   one socket (the kernel spreads the connections), each an app built with ``start_workers=False`` and
   ``first_start=False`` under the same connection limits as a single process;
4. it restarts an API process that exits, and on SIGTERM or Ctrl-C stops them, then the workers;
5. ``/metrics`` of any API process sums the request metrics of all of them (server/prometheus.py);
6. killed outright (SIGKILL, the OOM killer), it takes everything it started with it: each API process, worker
   and board worker ends at once with the supervisor (worker/lifeline.py), so nothing keeps accepting
   submissions that nobody dispatches or holds the port, and ``/healthz`` of an API process whose supervisor
   is gone answers 503 until it has ended. The next start hands the episodes they held back to the queue.

What is process-local stays correct with several processes: boards are published in SQL and read from there, login
sessions and everything else a route reads are in SQL, the pull relay's sockets meet through the broker, Redis or
RabbitMQ (:mod:`robobpp.server.relay_bus`). Without a broker it refuses to start (:func:`refusal`). Limits on connections
and on pull clients are per process (docs/deploy.md, "Several API processes").
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from multiprocessing.process import BaseProcess
from typing import Any

from robobpp import logs
from robobpp.server.state import state_of
from robobpp.worker.lifeline import Lifeline

log = logging.getLogger("robobpp.server")


class StartFailed(RuntimeError):
    """The API processes did not come up."""


#: How long the supervisor waits for the first API process to answer ``/healthz``.
READY_TIMEOUT_S = 120.0


def refusal(settings: Any, processes: int) -> str | None:
    """Why these settings cannot run ``processes`` API processes, or ``None`` when they can."""
    if processes > 1 and not settings.pull_bus_url:
        return (
            f"--server-workers {processes} needs a broker, where the API processes' pull relays meet (a worker's "
            "socket and the participant's may land on different processes): set ROBOBPP_BROKER_URL (Celery "
            "workers) or ROBOBPP_PULL_BROKER_URL (local workers) to redis://… or amqp://…"
        )
    return None


class SupervisorsWorkers:
    """The workers as an API process sees them: their count, which the supervisor publishes every half second
    (``/healthz`` reports it as from a single process's own pool), while the supervisor is there. Without it
    nothing dispatches, whatever the last count said: none alive, and ``/healthz`` says the supervisor is gone."""

    def __init__(self, alive: Any, lifeline: Lifeline) -> None:
        self._alive = alive
        self._lifeline = lifeline

    def supervisor_alive(self) -> bool:
        return self._lifeline.intact()

    def alive(self) -> int:
        return int(self._alive.value) if self.supervisor_alive() else 0


def api_process(
    overrides: dict[str, Any], sock: socket.socket, workers_alive: Any, lifeline: Lifeline
) -> None:
    """One API process: the app without bootstrap or workers, served by uvicorn on the inherited socket; it ends
    with the supervisor however that ends (``lifeline``)."""
    lifeline.hold("API process")
    import uvicorn

    from robobpp.server.app import create_app
    from robobpp.server.config import Settings
    from robobpp.server.connections import server_config

    logs.configure()
    settings = Settings(**overrides)
    app = create_app(settings, start_workers=False, first_start=False)
    state_of(app).runtime.executor = SupervisorsWorkers(workers_alive, lifeline)
    config = uvicorn.Config(
        app,
        log_level="info",
        log_config=logs.uvicorn_log_config(),
        access_log=False,
        **server_config(settings),
    )
    uvicorn.Server(config).run(sockets=[sock])


class Supervisor:
    """The N API processes on one listening socket, restarted when one exits."""

    def __init__(
        self,
        overrides: dict[str, Any],
        sock: socket.socket,
        processes: int,
        executor: Any,
        stopping: threading.Event,
    ) -> None:
        self.overrides, self.sock, self.processes, self.executor = overrides, sock, processes, executor
        self._ctx = mp.get_context("spawn")
        self._procs: list[BaseProcess] = []
        self.stopping = stopping
        #: How many workers are alive, as the executor says; shared with the API processes (/healthz).
        self.workers_alive = self._ctx.RawValue("i", self._count_workers())

    def _count_workers(self) -> int:
        return self.executor.alive() if self.executor is not None else 0

    def _spawn(self) -> BaseProcess:
        # from the main thread (start, watch), which lasts as long as this process: the kernel's guard applies
        proc = self._ctx.Process(
            target=api_process,
            args=(self.overrides, self.sock, self.workers_alive, Lifeline.to_here()),
            name="robobpp-api",
            daemon=True,
        )
        proc.start()
        return proc

    def start(self) -> None:
        self._procs = [self._spawn() for _ in range(self.processes)]

    def watch(self) -> None:
        """Until :attr:`stopping` is set: restart any API process that exited; publish the workers' count."""
        while not self.stopping.wait(0.5):
            self.workers_alive.value = self._count_workers()
            for i, proc in enumerate(self._procs):
                if not proc.is_alive() and not self.stopping.is_set():
                    log.warning("API process %s exited (code %s); restarting", proc.pid, proc.exitcode)
                    self._procs[i] = self._spawn()

    def exited(self) -> list[BaseProcess]:
        return [p for p in self._procs if p.exitcode is not None]

    def pids(self) -> list[int]:
        return [p.pid for p in self._procs if p.pid is not None and p.is_alive()]

    def stop(self, timeout_s: float = 15.0) -> None:
        self.stopping.set()
        for proc in self._procs:
            if proc.is_alive():
                proc.terminate()  # SIGTERM: uvicorn closes its connections and runs the app's shutdown
        deadline = time.monotonic() + timeout_s
        for proc in self._procs:
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(2)


def serve_processes(
    settings: Any,
    overrides: dict[str, Any],
    host: str,
    port: int,
    processes: int,
    on_ready: Callable[[str], None],
) -> None:
    """Bootstrap once, start the workers once, serve the API from ``processes`` processes until stopped."""
    import httpx

    logging.getLogger("httpx").setLevel(logging.WARNING)  # the readiness polls below are not news
    from robobpp.boards.worker import await_first_publication
    from robobpp.server.app import FIRST_PUBLICATION_S, start_board_worker, start_executor
    from robobpp.server.bootstrap import bootstrap
    from robobpp.server.runtime import Runtime
    from robobpp.server.services.progress import ProgressLog

    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))  # first: a port in use fails the start before anything is written
    except OSError:
        sock.close()
        raise
    sock.listen(2048)  # connections wait in the backlog until the first API process accepts them
    runtime = Runtime(settings)
    bootstrap(runtime)
    # the API processes' request metrics, summed at each scrape (server/prometheus.py); fresh at each start
    metrics_dir = tempfile.TemporaryDirectory(prefix="robobpp-metrics-")
    os.environ["PROMETHEUS_MULTIPROC_DIR"] = metrics_dir.name  # inherited by the spawned API processes
    executor = board_worker = progress = None
    previous = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    stopping = threading.Event()

    def stop(_signum: int, _frame: Any) -> None:
        stopping.set()

    for s in previous:
        signal.signal(s, stop)
    supervisor: Supervisor | None = None
    try:
        executor = start_executor(settings)
        progress = ProgressLog(
            runtime.read_session, settings.workers, per_worker=settings.episodes_per_worker
        ).start()
        board_worker = start_board_worker(runtime)
        if board_worker is not None:
            await_first_publication(runtime.read_session, FIRST_PUBLICATION_S)
        # the API processes read the boards the supervisor's board worker publishes
        supervisor = Supervisor({**overrides, "board_worker": "off"}, sock, processes, executor, stopping)
        supervisor.start()
        bound = sock.getsockname()[1]
        local = "127.0.0.1" if host in ("0.0.0.0", "") else ("[::1]" if host == "::" else host)
        url = f"http://{f'[{local}]' if ':' in local and not local.startswith('[') else local}:{bound}"
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not stopping.is_set():
            try:
                if httpx.get(url + "/healthz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            exited = supervisor.exited()
            if exited:  # a broken configuration would only restart it in a loop
                raise StartFailed(
                    f"an API process exited during start-up (exit code {exited[0].exitcode}; its log is above)"
                )
            if time.monotonic() > deadline:
                raise StartFailed(f"no API process answered on {url} within {READY_TIMEOUT_S:g} s")
            time.sleep(0.2)
        else:
            return
        on_ready(f"http://{f'[{host}]' if ':' in host else host}:{bound}")
        supervisor.watch()
    finally:
        if supervisor is not None:
            supervisor.stop()
        if executor is not None:
            executor.stop()
        if progress is not None:
            progress.stop()
        if board_worker is not None:
            board_worker.stop()
        sock.close()
        runtime.dispose()
        os.environ.pop("PROMETHEUS_MULTIPROC_DIR", None)
        metrics_dir.cleanup()
        for s, handler in previous.items():
            signal.signal(s, handler)
