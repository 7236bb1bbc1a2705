"""``robobpp worker --concurrency N`` with episodes multiplexed: N Celery worker nodes, one process each.

Celery's prefork pool gives each of its processes one task at a time, so a process there cannot keep several
episodes in flight while they wait on participants' policies. A node with Celery's thread pool can (its threads
share the process's CPU under the rule of robobpp/worker/multiplex.py), but it is one process: the simulation of
all its episodes runs on one core. So each of the N processes is a node of its own, started here as
``robobpp worker --concurrency 1`` (the same command a deployment may run once per core), and this process only
supervises them:

- a node that dies (a simulator crash, the OOM killer) is started again, at most once every
  :data:`RESTART_EVERY_S` per slot; its episodes' leases expire and the sweep sends them again, as for any dead
  worker;
- SIGTERM or SIGINT (``docker stop``, systemd, Ctrl-C) is passed on as SIGTERM: each node finishes its episodes in
  flight (Celery's warm shutdown), then this process leaves with them; a second signal ends them at once (SIGQUIT,
  Celery's cold shutdown: their episodes run again elsewhere);
- the nodes end with this process however it ends (robobpp/worker/lifeline.py, ``--parent-pid``): a supervisor
  killed outright leaves no node behind that would go on claiming unsupervised.
"""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from robobpp import logs

log = logging.getLogger("robobpp.worker")

#: A slot whose node died is started again no sooner than this after its previous start: a node that cannot
#: start (a broker refusing it) is retried, not restarted in a tight loop.
RESTART_EVERY_S = 5.0


def node_hostname(hostname: str | None, index: int) -> str | None:
    """The Celery node name of slot ``index``: ``NAME-i@HOST`` for a given ``NAME@HOST`` (node names must differ);
    ``None`` lets each node take its default (``robobpp-PID@HOST``, unique per process)."""
    if hostname is None:
        return None
    name, at, host = hostname.partition("@")
    return f"{name}-{index}{at}{host}"


def node_command(*, loglevel: str, hostname: str | None, parent_pid: int) -> list[str]:
    """One node: the worker command itself, one process, multiplexed."""
    cmd = [sys.executable, "-c", "from robobpp.cli import main; main()", "worker", "--concurrency", "1"]
    cmd += ["--pool", "multiplex", "--loglevel", loglevel.lower(), "--parent-pid", str(parent_pid)]
    if hostname is not None:
        cmd += ["--hostname", hostname]
    return cmd


class NodeSupervisor:
    """Runs ``nodes`` node processes until a signal asks it to stop; returns an exit status."""

    def __init__(self, nodes: int, command: Callable[[int], list[str]]) -> None:
        self.nodes, self.command = nodes, command
        self.slots: list[subprocess.Popen[bytes] | None] = [None] * nodes
        self.started = [0.0] * nodes
        self.signals = 0
        self.stopping = threading.Event()

    def _start(self, index: int) -> None:
        self.started[index] = time.monotonic()
        try:
            # Same process group: ``kill -9`` of the group (a container's end) takes every node with it.
            self.slots[index] = subprocess.Popen(self.command(index))
        except OSError as exc:  # out of processes or memory: the slot is tried again later
            log.warning("could not start worker node %d (%s); trying again", index, exc)
            self.slots[index] = None

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.signals += 1
        self.stopping.set()
        if self.signals > 1:  # asked again: end the nodes now (their episodes run again elsewhere)
            self._signal_nodes(signal.SIGQUIT)

    def _signal_nodes(self, how: int) -> None:
        for proc in self.slots:
            if proc is not None and proc.poll() is None:
                proc.send_signal(how)

    def run(self) -> int:
        logs.configure()  # its lines (a node restarted) look like the nodes' and the server's, time stamp included
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)
        for i in range(self.nodes):
            self._start(i)
        # Started and restarted from this (the main) thread: the nodes' kernel lifeline follows it.
        while not self.stopping.wait(0.5):
            for i, proc in enumerate(self.slots):
                if proc is not None and proc.poll() is None:
                    continue
                if time.monotonic() - self.started[i] < RESTART_EVERY_S or self.stopping.is_set():
                    continue
                if proc is not None:
                    log.warning(
                        "worker node %d (process %s) exited with %s; starting it again",
                        i,
                        proc.pid,
                        proc.returncode,
                    )
                self._start(i)
        # Here, not in the handler: a node started while the signal arrived gets it too. A node that already
        # had it (a group's Ctrl-C) ignores a second SIGTERM.
        self._signal_nodes(signal.SIGTERM)
        codes = [proc.wait() for proc in self.slots if proc is not None]
        return 0 if self.signals else max(codes, default=0)
