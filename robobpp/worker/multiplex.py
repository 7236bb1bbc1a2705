"""Several episodes in flight in one worker process: while one waits on its participant's policy, another
computes.

A worker that runs one episode at a time does nothing while a participant's policy thinks: two workers and a
policy that takes a second a box held the whole pool, however idle its CPUs. So a worker process keeps up to
``episodes_per_worker`` episodes in flight, one thread each, under two rules:

- **One computes at a time.** The process's :class:`Cpu` is a lock: an episode holds it while it simulates,
  scores and records, and lets go of it only while it waits on a participant's policy (each exchange with the
  policy's server in push mode, or with the relay in pull mode, and the wait for a pull client:
  robobpp/worker/run.py). The simulation is never time-sliced between episodes (the interpreter would slice
  threads every few milliseconds, slowing each); the network waits release the interpreter's lock too.
- **A further episode is claimed only while the CPU is free**: the claim loop takes the lock before it claims
  and hands it to the episode it starts, so it claims only while every episode in flight waits on its policy.
  A built-in's episode (served on loopback in this very process: its think time is this machine's CPU) and a
  paper-protocol replay keep the lock from start to end: they run alone, as before, and open no slot.

The Celery worker follows the same rule with the same :class:`Cpu` (robobpp/worker/tasks.py): its node runs the
episode task on a pool of ``episodes_per_worker`` threads, and each task takes its process's CPU
(:func:`process_cpu`) before it claims, hands it to the episode, and lets go of it when the episode ends. There
the threads are Celery's and the claim loop is the broker's delivery; the rule and the bounds are these.

Bounded per process (``episodes_per_worker``; 1 is one episode at a time, exactly as before) and per participant
(``participant_max_running``, checked by the claim over all workers). Each episode keeps its own policy
connection, simulator world and lease thread (:func:`robobpp.worker.run.run_claimed`, as before): claims,
heartbeats and completions are the same SQL calls under the same lease tokens, so leases, retries and
exactly-once completion hold as before. A worker process that dies takes its episodes with it; they share the
process's worker id, so the supervisor hands all of them back at once (robobpp/worker/local.py).
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from sqlalchemy.orm import Session, sessionmaker

from robobpp.db import work
from robobpp.db.work import Claim
from robobpp.worker.options import WorkerOptions
from robobpp.worker.run import Gate, run_claimed

log = logging.getLogger("robobpp.worker")

Runner = Callable[[sessionmaker[Session], Claim, WorkerOptions, Gate], bool]


class Cpu:
    """The worker process's one computing slot: held by the episode that computes (or by the claim loop)."""

    def __init__(self) -> None:
        self._lock = (
            threading.Lock()
        )  # not an RLock: the claim loop takes it, the episode it starts lets it go

    def acquire(self, timeout_s: float) -> bool:
        return self._lock.acquire(timeout=max(0.0, timeout_s))

    def release(self) -> None:
        self._lock.release()

    @contextmanager
    def waiting(self) -> Iterator[None]:
        """Around a wait on a participant's policy: others may compute meanwhile; held again after it."""
        self._lock.release()
        try:
            yield
        finally:
            self._lock.acquire()


_process_cpu: tuple[int, Cpu] | None = None
_process_cpu_lock = threading.Lock()


def process_cpu() -> Cpu:
    """This process's CPU, shared by every episode task of a Celery worker node (robobpp/worker/tasks.py).

    Keyed by process id: a child forked by Celery's prefork pool gets its own, never a copy of its parent's
    (which the parent never takes, but a copied lock's state is whatever it was at the fork)."""
    global _process_cpu
    with _process_cpu_lock:
        if _process_cpu is None or _process_cpu[0] != os.getpid():
            _process_cpu = (os.getpid(), Cpu())
        return _process_cpu[1]


class Multiplexer:
    """The episodes in flight in one worker process, and the claim loop's step (:meth:`claim_next`)."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        options: WorkerOptions,
        worker: str,
        *,
        runner: Runner = run_claimed,
    ) -> None:
        self.factory, self.options, self.worker, self.runner = factory, options, worker, runner
        self.limit = max(1, options.episodes_per_worker)
        self.cpu = Cpu()
        self._threads: set[threading.Thread] = set()
        self._changed = threading.Condition()

    def in_flight(self) -> int:
        with self._changed:
            return len(self._threads)

    def claim_next(self, wait_s: float) -> bool | None:
        """Claim one episode and start it when there is room and the CPU is free (every episode in flight waits
        on its policy). ``True``: one started; ``None``: nothing to claim; ``False``: no room, or the CPU stayed
        busy, for ``wait_s``. A database error propagates (the claim loop waits and tries again)."""
        with self._changed:
            if len(self._threads) >= self.limit:
                self._changed.wait(wait_s)  # an episode ends
                return False
        if not self.cpu.acquire(wait_s):
            return False
        handed = False
        try:
            with self.factory() as s, s.begin():
                claim = work.claim_episode(
                    s,
                    self.worker,
                    lease_s=self.options.lease_s,
                    max_attempts=self.options.max_attempts,
                    max_running_per_participant=self.options.participant_max_running,
                )
            if claim is None:
                return None
            thread = threading.Thread(
                target=self._run, args=(claim,), name=f"episode-{claim.episode_id}", daemon=True
            )
            with self._changed:
                self._threads.add(thread)
            thread.start()  # the CPU goes with it
            handed = True
            return True
        finally:
            if not handed:
                self.cpu.release()

    def _run(self, claim: Claim) -> None:
        """One episode's thread: it starts holding the CPU and lets it go when it ends."""
        try:
            self.runner(self.factory, claim, self.options, self.cpu)
        except Exception:
            log.exception(
                "episode %s could not be recorded; it runs again when its lease expires", claim.episode_id
            )
        finally:
            self.cpu.release()
            with self._changed:
                self._threads.discard(threading.current_thread())
                self._changed.notify_all()

    def drain(self, timeout_s: float | None = None) -> bool:
        """Wait for the episodes in flight to end (claim none meanwhile). ``False``: some still run at the timeout."""
        with self._changed:
            return self._changed.wait_for(lambda: not self._threads, timeout_s)
