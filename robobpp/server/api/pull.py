"""Pull mode's relay: participants' clients connect out to the server, workers drive episodes through them.

Two WebSocket routes meet here:

- ``/api/v1/pull/connect?submission=ID`` — a participant's client (``robobpp connect``), authenticated by
  its API token. Each connection serves one episode at a time; a client opens several to serve several.
- ``/api/v1/pull/episodes/{episode_id}`` — a worker (a local process or a Celery worker on another
  machine), authenticated by the episode's lease token, which only the worker holding the claim knows.
  It is paired with an idle connection of the episode's submission, and from then on every frame is
  forwarded unchanged in both directions.

The relay never interprets a frame beyond its size: the worker signs, times and validates exactly as in
push mode (:mod:`robobpp.worker.pull`). An answer over the cap is never forwarded: the worker's socket is
closed with :data:`TOO_LARGE`. When the client drops, the worker's socket is closed with :data:`GONE` so that
it waits for the client to come back and resumes the episode on a new connection.

The two sockets of an episode need not land on the same API process. Each handler owns an endpoint of the
relay bus (:mod:`robobpp.server.relay_bus`) and the two talk only through it: in-process when the API runs as
one process with no broker configured, through the deployment's broker otherwise, Redis or RabbitMQ
(``robobpp serve --server-workers N``, or replicas on several hosts; docs/deploy.md, "Several API processes"). Pairing is one exchange: the worker's
side takes an idle client address from the submission's queue and asks it to ``PAIR``; the client's side
answers ``PAIRED``, or ``GONE`` if it was taken meanwhile, and the worker's side tries the next one.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from typing import Any

from fastapi import APIRouter, WebSocket
from sqlalchemy import select
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool

from robobpp import protocol as P
from robobpp.db.models import EpisodeRow, Submission
from robobpp.server.principal import auth_refused_for, principal_for_token
from robobpp.server.problems import ProblemError
from robobpp.server.relay_bus import (
    FRAME,
    PAIR,
    PAIRED,
    RELEASE,
    WATCH_S,
    Endpoint,
)
from robobpp.server.relay_bus import GONE as GONE_MESSAGE
from robobpp.server.relay_bus import TOO_LARGE as TOO_LARGE_MESSAGE
from robobpp.server.relay_hub import PullHub
from robobpp.server.state import state_of
from robobpp.vocabulary import ACTIVE_SUBMISSION

log = logging.getLogger("robobpp.server.pull")
router = APIRouter(tags=["pull"])

#: WebSocket close codes the relay uses (4000-4999 are the application's).
GONE = 4001  # the participant's client disconnected mid-episode
REFUSED = 4003  # bad token, not a pull submission, or not a running episode under this lease
NO_CLIENT = 4004  # no client of the submission connected within the worker's wait
FINISHED = 4010  # the submission is over: the client may stop
TOO_LARGE = 4009  # the client's answer passed the size cap
TOO_MANY = 4029  # the submission or the participant has as many client connections open as allowed
BUSY = 1013  # "try again later": the relay's broker did not take the new connection's offer
#: Slack over the answer cap for the frame's envelope line.
ENVELOPE_BYTES = 4096
MAX_WAIT_S = 300.0
#: How long the worker's side waits for an idle client connection to answer ``PAIR`` before trying the next.
PAIR_REPLY_S = 5.0


async def hub_of(app: Starlette) -> PullHub:
    """The app's relay hub (made with the app), its bus started on first use (the app's lifespan closes it)."""
    return await state_of(app).pull_hub.start()


def _client_submission(ws: WebSocket, token: str, submission_id: int) -> tuple[int, int]:
    wait = auth_refused_for(ws, token)
    if wait:
        raise ProblemError(
            429, "too-many-failures", "Too many failed authentications", f"retry in {wait:.0f} s"
        )
    principal = principal_for_token(ws, token)
    if principal is None:
        raise ProblemError(
            401, "unauthorized", "Unauthorized", "the API token is not valid (unknown or revoked)"
        )
    with state_of(ws.app).runtime.session() as session:
        sub = session.get(Submission, submission_id)
        if sub is None or not (principal.admin or sub.participant_id == principal.participant_id):
            raise ProblemError(404, "not-found", "Not found", f"no submission {submission_id} of yours")
        if sub.mode != "pull":
            raise ProblemError(
                409, "not-pull", "Not a pull submission", f"submission {submission_id} is in {sub.mode} mode"
            )
        if sub.status not in ACTIVE_SUBMISSION:
            raise ProblemError(410, "finished", "Finished", f"submission {submission_id} is {sub.status}")
        return sub.id, sub.participant_id


def _worker_submission(runtime: Any, episode_id: int, lease: str) -> int | None:
    with runtime.session() as session:
        row = session.execute(
            select(EpisodeRow.submission_id)
            .join(Submission, Submission.id == EpisodeRow.submission_id)
            .where(
                EpisodeRow.id == episode_id,
                EpisodeRow.lease_token == lease,
                EpisodeRow.status == "running",
                Submission.mode == "pull",
            )
        ).first()
    return None if row is None else int(row[0])


@router.websocket("/pull/connect")
async def client_connects(ws: WebSocket, submission: int) -> None:
    """A participant's client: one connection = one episode at a time (``robobpp connect``)."""
    auth = ws.headers.get("authorization", "")
    token = auth[7:].strip() if auth.lower().startswith("bearer ") else ""
    await ws.accept()
    try:
        if not token:
            raise ProblemError(401, "unauthorized", "Unauthorized", "send 'Authorization: Bearer <token>'")
        submission_id, participant_id = await run_in_threadpool(_client_submission, ws, token, submission)
    except ProblemError as exc:
        await ws.close(FINISHED if exc.status == 410 else REFUSED, f"{exc.title}: {exc.detail}"[:120])
        return
    settings = state_of(ws.app).settings
    hub = await hub_of(ws.app)
    if not hub.admit(
        submission_id, participant_id, settings.pull_max_per_submission, settings.pull_max_per_participant
    ):
        await ws.close(
            TOO_MANY,
            f"too many connections: at most {settings.pull_max_per_submission} per submission "
            f"and {settings.pull_max_per_participant} per participant",
        )
        return
    try:
        await ws.send_text(
            json.dumps({"type": "welcome", "submission": submission_id, "protocol": P.PROTOCOL})
        )
        side = _ClientSide(
            ws,
            hub.bus.endpoint(),
            submission_id,
            settings.response_cap_bytes + ENVELOPE_BYTES,
            hub.bus_slot(participant_id),
        )
        try:
            try:
                await side.offer()
            except Exception as exc:  # noqa: BLE001 - the broker is away or saturated: the client retries
                log.warning("pull relay: could not offer a client connection: %s", _why(exc))
                with contextlib.suppress(Exception):
                    await ws.close(BUSY, "the relay is busy; connect again")
                return
            await _first_done(side.from_client(), side.from_bus())
        finally:
            await side.leave()
    finally:
        hub.leave(submission_id, participant_id)


def _why(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:200]


class _ClientSide:
    """A client connection's handler: idle (queued for its submission) or paired with one worker's side."""

    def __init__(
        self, ws: WebSocket, endpoint: Endpoint, submission_id: int, cap: int, slot: asyncio.Semaphore
    ) -> None:
        self.ws, self.endpoint, self.submission_id, self.cap = ws, endpoint, submission_id, cap
        self.bus = endpoint.bus
        #: Held around every bus call: the participant's share of the broker's connections (PullHub).
        self.slot = slot
        #: The paired worker side's address; ``None`` while idle.
        self.peer: str | None = None

    async def offer(self) -> None:
        self.peer = None
        async with self.slot:
            await self.bus.offer(self.submission_id, self.endpoint.address)

    async def _check(self) -> None:
        """What silence cannot tell: an idle connection is still queued, a paired one's worker still there."""
        async with self.slot:
            if self.peer is None:
                await self.bus.still_offered(self.submission_id, self.endpoint.address)
                return
            alive = await self.bus.alive(self.peer)
        if not alive:
            await self.offer()  # the worker's process went away: free for the next episode

    async def from_client(self) -> None:
        """The client's frames go to the paired worker (an idle connection has no one to answer)."""
        while True:
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            frame = message.get("bytes")
            peer = self.peer
            if frame is None or peer is None:
                continue  # text frames carry nothing for a worker; late answers of the last episode neither
            if len(frame) > self.cap:  # never forwarded: the worker ends the episode as in push mode
                await self.endpoint.send(peer, TOO_LARGE_MESSAGE)
            else:
                await self.endpoint.send(peer, FRAME, frame)

    async def from_bus(self) -> None:
        """Pairing requests and the paired worker's frames; returns when the client's socket broke."""
        while True:
            message = await self.endpoint.receive(WATCH_S)
            if message is None:  # silence: check what silence cannot tell
                try:
                    await self._check()
                except Exception as exc:  # noqa: BLE001 - the broker is away or saturated: check again later
                    log.warning("pull relay: idle check of a client connection failed: %s", _why(exc))
                continue
            if message.kind == PAIR:
                if self.peer is None:
                    self.peer = message.sender
                    await self.endpoint.send(message.sender, PAIRED)
                elif message.sender != self.peer:
                    await self.endpoint.send(message.sender, GONE_MESSAGE)  # taken meanwhile
                continue
            if message.sender != self.peer:
                continue  # a former peer's late message
            if message.kind == FRAME:
                try:
                    await self.ws.send_bytes(message.payload)
                except Exception:  # noqa: BLE001 - the client's socket broke under us: same as a disconnect
                    return
            elif message.kind in (RELEASE, GONE_MESSAGE):
                try:
                    await self.offer()
                except Exception as exc:  # noqa: BLE001 - idle now: the next idle check queues it again
                    log.warning("pull relay: could not offer a client connection again: %s", _why(exc))

    async def leave(self) -> None:
        """The client is gone: its worker (if any) hears ``GONE``, its idle entry goes."""
        try:
            if self.peer is not None:
                await self.endpoint.send(self.peer, GONE_MESSAGE)
            else:
                async with self.slot:
                    await self.bus.withdraw(self.submission_id, self.endpoint.address)
        except Exception as exc:  # noqa: BLE001 - the broker is away: the peer notices our silence (bus.alive)
            log.warning("pull relay: could not tell the bus a client left: %s", _why(exc))
        finally:
            self.endpoint.close()


async def _first_done(*coroutines: Any) -> Any:
    """Run the coroutines until one returns (or raises); cancel the others; its result."""
    tasks = [asyncio.ensure_future(c) for c in coroutines]
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    return next(iter(done)).result()


async def _pair(endpoint: Endpoint, submission_id: int, wait_s: float) -> str | None:
    """Take idle client connections of the submission until one accepts ``PAIR``; ``None`` after ``wait_s``."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + wait_s
    while (left := deadline - loop.time()) > 0:
        address = await endpoint.bus.take(submission_id, left)
        if address is None:
            return None
        await endpoint.send(address, PAIR)
        answer_by = loop.time() + PAIR_REPLY_S
        while (left := answer_by - loop.time()) > 0:
            message = await endpoint.receive(left)
            if message is None or message.sender == address:
                break
        else:
            message = None
        if message is not None and message.kind == PAIRED:
            return address
        if message is None:  # no answer: should it accept later, it is released at once
            await endpoint.send(address, RELEASE)
    return None


async def _to_client(ws: WebSocket, endpoint: Endpoint, peer: str) -> int | None:
    """The worker's frames go to the client; ``None`` when the worker closed its socket."""
    while True:
        message = await ws.receive()
        if message["type"] == "websocket.disconnect":
            return None
        frame = message.get("bytes")
        if frame is not None:
            await endpoint.send(peer, FRAME, frame)


async def _to_worker(ws: WebSocket, endpoint: Endpoint, peer: str) -> int:
    """The client's answers go to the worker; the close code when the client side ended the pairing."""
    while True:
        message = await endpoint.receive(WATCH_S)
        if message is None:
            if not await endpoint.bus.alive(peer):
                return GONE  # the client's process went away with its socket
            continue
        if message.sender != peer:
            continue
        if message.kind == FRAME:
            await ws.send_bytes(message.payload)
        elif message.kind == TOO_LARGE_MESSAGE:
            return TOO_LARGE
        elif message.kind == GONE_MESSAGE:
            return GONE


@router.websocket("/pull/episodes/{episode_id}")
async def worker_drives(ws: WebSocket, episode_id: int, wait: float = 30.0) -> None:
    """A worker holding the episode's lease: paired with an idle client of its submission, then relayed."""
    runtime = state_of(ws.app).runtime
    lease = ws.headers.get("x-robobpp-lease", "")
    submission_id = await run_in_threadpool(_worker_submission, runtime, episode_id, lease) if lease else None
    await ws.accept()
    if submission_id is None:
        await ws.close(REFUSED, "not a running pull episode under this lease")
        return
    hub = await hub_of(ws.app)
    endpoint = hub.bus.endpoint()
    code: int | None = None
    peer: str | None = None
    try:
        peer = await _pair(endpoint, submission_id, min(max(wait, 0.0), MAX_WAIT_S))
        if peer is None:
            await ws.close(NO_CLIENT, f"no client of submission {submission_id} connected in time")
            return
        await ws.send_text("paired")
        code = await _first_done(_to_client(ws, endpoint, peer), _to_worker(ws, endpoint, peer))
    except Exception:
        log.debug("pull relay of episode %s ended", episode_id, exc_info=True)
    finally:
        if peer is not None and code != GONE:
            with contextlib.suppress(Exception):  # the broker is away: the client notices our silence
                await endpoint.send(peer, RELEASE)
        endpoint.close()
    if code is not None:
        reason = (
            "the client's answer is larger than the cap" if code == TOO_LARGE else "the client disconnected"
        )
        with contextlib.suppress(Exception):  # already closed by the worker
            await ws.close(code, reason)
