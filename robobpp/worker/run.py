"""The episode execution unit shared by every executor (local pool, Celery).

:func:`run_claimed` runs one already-claimed episode and records it; :func:`claim_and_run` claims the next
one first. A background thread renews the lease while the episode runs, and the loop stops as soon as the
claim is lost (cancelled, or taken over after this worker was presumed dead): its result is then dropped,
never written twice. A worker that keeps several episodes in flight (robobpp/worker/multiplex.py) hands in a
``gate``: the episode holds it while it computes and lets go of it while it waits on the participant's policy.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import secrets
import socket
import threading
import traceback
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from typing import Any, Protocol

from sqlalchemy.orm import Session, sessionmaker

from robobpp.db import work
from robobpp.db.work import Claim
from robobpp.episode import StepRecord, run_episode
from robobpp.replay import math_result_of, replay_math_result
from robobpp.vocabulary import PAPER
from robobpp.worker.options import WorkerOptions
from robobpp.worker.outage import OutageLog
from robobpp.worker.specs import episode_spec

log = logging.getLogger("robobpp.worker")


class ClaimLost(Exception):
    """The episode is no longer ours (cancelled or re-leased): stop without recording anything."""


def worker_id(kind: str = "local") -> str:
    """``kind:host:pid`` — the host prefix lets a restarted server hand back its dead workers' episodes."""
    return f"{kind}:{socket.gethostname()}:{os.getpid()}"


def make_policy(claim: Claim, settings: WorkerOptions) -> Any:
    """A built-in policy served on loopback (``builtin:NAME``, :class:`~robobpp.worker.builtin.ServedBuiltin`),
    the participant's server over robobpp/1 (push), or the participant's client through the server's relay
    (pull). Every one is driven over robobpp/1 with the network probes on, so that the decision time ranked
    is the policy's, not the distance's, and a built-in pays the protocol as a participant does."""
    if claim.policy_url.startswith("builtin:"):
        from robobpp.worker.builtin import ServedBuiltin

        return ServedBuiltin(
            claim.policy_url.removeprefix("builtin:"),
            step_timeout_s=settings.step_timeout_s,
            episode_timeout_s=settings.episode_timeout_s,
        )
    from robobpp.client.remote import RemotePolicy

    transport = None
    url = claim.policy_url
    if claim.mode == "pull":
        from robobpp.client.frames import MAX_ENVELOPE
        from robobpp.worker.pull import PullTransport

        if not settings.pull_relay_url:
            raise RuntimeError("a pull episode needs ROBOBPP_PULL_RELAY_URL (the server's URL) on the worker")
        transport = PullTransport(
            settings.pull_relay_url,
            claim.episode_id,
            claim.token,
            wait_s=settings.pull_wait_s,
            reconnect_s=settings.pull_reconnect_s,
            max_frame_bytes=settings.response_cap_bytes + MAX_ENVELOPE,
        )
        url = settings.pull_relay_url  # names the policy only: every byte goes through the transport
    policy = RemotePolicy(
        url,
        claim.secret,
        step_timeout_s=settings.step_timeout_s,
        episode_timeout_s=settings.episode_timeout_s,
        max_response_bytes=settings.response_cap_bytes,
        resolved_ip=claim.pinned_ip,
        name=f"submission-{claim.submission_id}",
        probe_network=True,
        transport=transport,
    )
    if transport is not None:
        transport.headers_for = policy.request_headers
    return policy


class Gate(Protocol):
    """The worker process's CPU, as one episode among several in flight sees it (robobpp/worker/multiplex.py):
    held while the episode computes, let go of inside :meth:`waiting`."""

    def waiting(self) -> AbstractContextManager[None]: ...


class _NoGate:
    """One episode at a time: nothing to let go of."""

    @contextmanager
    def waiting(self) -> Iterator[None]:
        yield


class _WaitingTransport:
    """A participant's transport whose exchanges let go of the gate: while the worker waits for the policy's
    answer (push or pull), another episode of the process may compute. Everything else passes through."""

    def __init__(self, inner: Any, gate: Gate) -> None:
        self._inner, self._gate = inner, gate

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def request(self, *args: Any, **kwargs: Any) -> Any:
        with self._gate.waiting():
            return self._inner.request(*args, **kwargs)


def _wait_on_network(policy: Any, gate: Gate) -> None:
    """Let ``policy``'s exchanges with the participant go of the gate. A built-in is not wrapped: it is served
    in this very process, its think time is this machine's CPU, so it keeps the gate like the simulation."""
    policy._connection = _WaitingTransport(policy._connection, gate)


def _pair_pull_client(policy: Any, gate: Gate) -> None:
    """Pull mode: wait for the participant's client before the episode starts (raises ``NoClient``)."""
    transport = getattr(policy, "_connection", None)
    pair = getattr(transport, "pair", None)
    if transport is not None and pair is not None:
        with gate.waiting():
            pair(transport.wait_s)


class _Lease(threading.Thread):
    """The heartbeat: renews the lease every quarter of its length; flags the claim lost when refused."""

    def __init__(self, factory: sessionmaker[Session], claim: Claim, lease_s: float) -> None:
        super().__init__(name=f"lease-{claim.episode_id}", daemon=True)
        self.factory, self.claim, self.lease_s = factory, claim, lease_s
        self.step = 0
        #: The episode's boxes, once its spec is known (recorded with the progress).
        self.boxes_total: int | None = None
        self.lost = threading.Event()
        self.done = threading.Event()

    def run(self) -> None:
        interval = max(0.2, min(self.lease_s / 4, 10.0))
        outages = OutageLog(log, f"lease of episode {self.claim.episode_id}")
        while not self.done.wait(interval):
            try:
                with self.factory() as s, s.begin():
                    ok = work.heartbeat(
                        s,
                        self.claim.episode_id,
                        self.claim.token,
                        lease_s=self.lease_s,
                        step=self.step,
                        boxes_total=self.boxes_total,
                    )
            except Exception as exc:  # noqa: BLE001 - a blip of the database: try again next interval
                outages.failed(exc, "renewal")
                continue
            outages.ok("database")
            if not ok:
                self.lost.set()
                return


def _release_crashed(
    factory: sessionmaker[Session], claim: Claim, settings: WorkerOptions, exc: BaseException, what: str
) -> bool:
    """Record a simulator crash on the claimed episode (bounded retries); the caller returns what this returns."""
    detail = "".join(traceback.format_exception_only(exc)).strip()
    with factory() as s, s.begin():
        work.release_episode(s, claim.episode_id, claim.token, detail, max_attempts=settings.max_attempts)
    log.exception("%s %s crashed", what, claim.episode_id)
    return False


def run_claimed(
    factory: sessionmaker[Session], claim: Claim, settings: WorkerOptions, gate: Gate | None = None
) -> bool:
    """Run a claimed episode and record it. Returns whether this call recorded the result.

    ``gate``: held by the caller; let go of while the episode waits on a participant's policy (never on a
    built-in's, nor during a replay), held again before the episode computes on."""
    if claim.protocol == PAPER:
        return replay_claimed(factory, claim, settings)
    try:
        spec = episode_spec(
            claim.dataset,
            claim.split,
            claim.group,
            groups=settings.groups,
            private_dir=settings.private_dir,
            provider=settings.spec_provider,
            max_boxes=settings.max_boxes,
        )
        if not claim.policy_url.startswith("builtin:"):
            # The id a participant's policy sees names neither split nor group, and differs per episode and
            # attempt: it must not learn which test group it is playing (docs/server.md, threat model). The
            # built-in policies keep the readable id: they seed from it (Random, PCT), so their figures
            # stay the same on every run.
            spec = dataclasses.replace(spec, label=f"ep-{secrets.token_hex(8)}")
        policy = make_policy(claim, settings)
        if gate is not None and not claim.policy_url.startswith("builtin:"):
            _wait_on_network(policy, gate)
    except Exception as exc:  # noqa: BLE001 - an evaluation problem, not the policy's: retry, then fail
        with factory() as s, s.begin():
            work.release_episode(
                s,
                claim.episode_id,
                claim.token,
                f"{type(exc).__name__}: {exc}",
                max_attempts=settings.max_attempts,
            )
        log.error("episode %s could not start: %s", claim.episode_id, exc)
        return False
    lease = _Lease(factory, claim, settings.lease_s)
    lease.boxes_total = len(spec.boxes)
    lease.start()
    try:
        _pair_pull_client(policy, gate or _NoGate())  # under the lease: the wait may outlast it
    except Exception as exc:  # noqa: BLE001 - no client (yet): hand the episode back, bounded retries
        lease.done.set()
        lease.join(timeout=5)
        with factory() as s, s.begin():
            work.release_episode(
                s, claim.episode_id, claim.token, f"pull mode: {exc}", max_attempts=settings.max_attempts
            )
        log.info("episode %s: %s", claim.episode_id, exc)
        return False

    def on_step(record: StepRecord) -> None:
        lease.step = record.step + 1
        if lease.lost.is_set():
            raise ClaimLost

    try:
        result = run_episode(
            spec,
            policy,
            claim.setting,
            lookahead=claim.lookahead,
            time_budget_s=settings.episode_timeout_s,
            on_step=on_step,
        )
    except ClaimLost:
        log.info("episode %s: claim lost (cancelled or taken over); result dropped", claim.episode_id)
        return False
    except Exception as exc:  # noqa: BLE001 - a crash of the simulator: record it, bounded retries
        return _release_crashed(factory, claim, settings, exc, "episode")
    finally:
        lease.done.set()
        lease.join(timeout=5)
    data = result.to_dict()  # steps included: a Math episode's plan is kept on every track (complete_episode)
    data["max_boxes"] = settings.max_boxes or None
    with factory() as s, s.begin():
        return work.complete_episode(s, claim.episode_id, claim.token, data, keep_trace=claim.keep_trace)


def replay_claimed(factory: sessionmaker[Session], claim: Claim, settings: WorkerOptions) -> bool:
    """A paper-protocol episode: its Math Pack episode's actions and decision times (the plan recorded with
    that episode) replayed open loop in the claim's physical setting. No policy is called; under the same
    lease as any episode, so a crash hands it to the next worker and a late result is dropped."""
    lease = _Lease(factory, claim, settings.lease_s)
    try:
        spec = episode_spec(
            claim.dataset,
            claim.split,
            claim.group,
            groups=settings.groups,
            private_dir=settings.private_dir,
            provider=settings.spec_provider,
            max_boxes=settings.max_boxes,
        )
        with factory() as s:
            plan = work.episode_plan(s, claim.episode_id)
        if plan is None:
            raise RuntimeError("the paper-protocol episode has no plan (its Math Pack episode left none)")
        lease.start()
        result = replay_math_result(math_result_of(plan, spec), spec, claim.setting)
    except Exception as exc:  # noqa: BLE001 - a crash of the simulator: record it, bounded retries
        return _release_crashed(factory, claim, settings, exc, "paper-protocol episode")
    finally:
        lease.done.set()
        if lease.is_alive():
            lease.join(timeout=5)
    if lease.lost.is_set():
        log.info("episode %s: claim lost (cancelled or taken over); result dropped", claim.episode_id)
        return False
    data = {**result.to_dict(), "max_boxes": settings.max_boxes or None}
    with factory() as s, s.begin():
        return work.complete_episode(s, claim.episode_id, claim.token, data, keep_trace=claim.keep_trace)


def claim_and_run(factory: sessionmaker[Session], settings: WorkerOptions, worker: str) -> bool | None:
    """Claim the next episode and run it. ``None`` when there was nothing to do."""
    with factory() as s, s.begin():
        claim = work.claim_episode(
            s,
            worker,
            lease_s=settings.lease_s,
            max_attempts=settings.max_attempts,
            max_running_per_participant=settings.participant_max_running,
        )
    if claim is None:
        return None
    return run_claimed(factory, claim, settings)
