"""The local executor: a pool of worker processes on the server's machine (the embedded default).

Processes, not threads: episodes are CPU-bound (geometry, PyBullet) and a crashing simulator must not
take the server down. A supervisor thread restarts dead workers and hands their episodes back at once
(the lease would free them anyway, later). SQL stays the only channel between server and workers. A worker
ends with the server however the server ends (worker/lifeline.py): the episode it held runs again after the
next start.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import socket
import threading
import time
from multiprocessing.process import BaseProcess
from typing import Any

from robobpp import logs
from robobpp.db import work
from robobpp.db.session import make_engine, make_session_factory
from robobpp.worker.lifeline import Lifeline
from robobpp.worker.options import WorkerOptions
from robobpp.worker.outage import OutageLog

log = logging.getLogger("robobpp.worker")


def worker_main(options: WorkerOptions, stop: Any, lifeline: Lifeline) -> None:
    """Claim-run-record until ``stop.value`` is set (or SIGTERM), with up to ``options.episodes_per_worker``
    episodes in flight (robobpp/worker/multiplex.py); then finish those, and leave. Runs in a child process,
    which ends at once when its server process does (``lifeline``), even mid-episode.

    ``stop`` is a lock-free shared byte on purpose: a ``multiprocessing.Event`` deadlocks its ``set()`` when
    a process dies while waiting on it (e.g. SIGTERM sent to the whole process group by ``timeout`` or
    systemd), and the server would then never finish shutting down.
    """
    lifeline.hold("local worker")
    from robobpp.worker.multiplex import Multiplexer
    from robobpp.worker.run import worker_id

    leaving = threading.Event()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's; it stops us through ``stop``
    signal.signal(signal.SIGTERM, lambda *_: leaving.set())  # finish the episodes in flight, then leave
    logs.configure()  # its lines (an outage, a failed claim) look like the server's, time stamp included
    engine = make_engine(options.database_url)
    factory = make_session_factory(engine)
    me = worker_id("local")
    outages = OutageLog(log, f"worker {me}")
    episodes = Multiplexer(factory, options, me)
    try:
        while not stop.value and not leaving.is_set() and lifeline.intact():  # orphans stop claiming
            try:
                outcome = episodes.claim_next(options.poll_interval_s)
                outages.ok("database")
            except Exception as exc:  # noqa: BLE001 - the database blinked; wait and try again
                outages.failed(exc, "claim")
                outcome = None
            if outcome is None:
                leaving.wait(options.poll_interval_s)
        episodes.drain()
    finally:
        engine.dispose()


def host_prefix() -> str:
    return f"local:{socket.gethostname()}:"


class LocalExecutor:
    def __init__(self, options: WorkerOptions, workers: int) -> None:
        self.options = options
        self.workers = workers
        self._ctx = mp.get_context("spawn")
        self._stop = self._ctx.RawValue("b", 0)
        self._procs: list[BaseProcess] = []
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._stopped = threading.Event()  # every worker is out: the supervisor thread may end
        self._supervisor = threading.Thread(target=self._supervise, name="robobpp-supervisor", daemon=True)
        self._outages = OutageLog(log, "local worker supervisor")

    def _spawn(self, lifeline: Lifeline) -> BaseProcess:
        proc = self._ctx.Process(
            target=worker_main, args=(self.options, self._stop, lifeline), name="robobpp-worker", daemon=True
        )
        proc.start()
        return proc

    def _release_dead(self) -> None:
        alive = {p.pid for p in self._procs if p.pid is not None and p.is_alive()}
        engine = make_engine(self.options.database_url)
        try:
            with make_session_factory(engine)() as s, s.begin():
                n = work.release_dead_workers(s, host_prefix(), alive | {os.getpid()})
        finally:
            engine.dispose()
        if n:
            log.warning("handed back %d episode(s) of dead local workers", n)

    def start(self) -> None:
        self._release_dead()  # a previous server on this host died mid-evaluation
        with self._lock:
            self._procs = [self._spawn(Lifeline.to_here()) for _ in range(self.workers)]
        self._supervisor.start()

    def _supervise(self) -> None:
        # The kernel ends a child when the thread that started it ends (worker/lifeline.py): this thread, which
        # starts the replacements, lives until stop() has seen every worker out, and never dies of a failed start.
        lifeline = Lifeline.to_here(long_lived_thread=True)
        while not self._stopped.wait(1.0):
            if self._stopping.is_set():
                continue
            with self._lock:
                dead = [p for p in self._procs if not p.is_alive()]
                if not dead and len(self._procs) >= self.workers:
                    continue
                self._procs = [p for p in self._procs if p.is_alive()]
                for p in dead:
                    log.warning("worker process %s exited (code %s); restarting", p.pid, p.exitcode)
                while len(self._procs) < self.workers:
                    try:
                        self._procs.append(self._spawn(lifeline))
                    except OSError as exc:  # out of processes or memory: try again in a second
                        log.warning("could not start a worker process (%s); trying again", exc)
                        break
            try:
                self._release_dead()
                self._outages.ok("database")
            except Exception as exc:  # noqa: BLE001
                self._outages.failed(exc, "handing back dead workers' episodes")

    def alive(self) -> int:
        with self._lock:
            return sum(p.is_alive() for p in self._procs)

    def pids(self) -> list[int]:
        with self._lock:
            return [p.pid for p in self._procs if p.pid is not None and p.is_alive()]

    def stop(self, timeout_s: float = 10.0) -> None:
        """Ask workers to finish their episodes in flight; terminate those that do not within the timeout."""
        self._stopping.set()
        self._stop.value = 1
        deadline = time.monotonic() + timeout_s
        with self._lock:
            procs = list(self._procs)
        busy = sum(p.is_alive() for p in procs)
        if busy:  # the wait can last the timeout: say why the process has not exited yet
            log.info("stopping %d local worker(s): each finishes its episode within %.0f s", busy, timeout_s)
        for p in procs:
            p.join(max(0.0, deadline - time.monotonic()))
        cut = [p for p in procs if p.is_alive()]
        if cut:
            log.info(
                "%d worker(s) still in an episode after %.0f s: stopped; their episodes run again after the next start",
                len(cut),
                timeout_s,
            )
        for p in cut:
            p.terminate()
            p.join(2)
        self._stopped.set()
        if self._supervisor.is_alive():
            self._supervisor.join(2)
