"""Pull mode's relay: participants' clients connect out to the server, workers drive episodes through them.

Two WebSocket routes meet here:

- ``/api/v1/pull/connect?submission=ID`` — a participant's client (``robobpp connect``), authenticated by
  its API token. Each connection serves one episode at a time; a client opens several to serve several.
- ``/api/v1/pull/episodes/{episode_id}`` — a worker (a local process or a Celery worker on another
  machine), authenticated by the episode's lease token, which only the worker holding the claim knows.
  It is paired with an idle connection of the episode's submission, and from then on every frame is
  forwarded unchanged in both directions.

The relay never interprets a frame beyond its size: the worker signs, times and validates exactly as in
push mode (:mod:`robobpp.worker.pull`). When the client drops, the worker's socket is closed with
:data:`GONE` so that it waits for the client to come back and resumes the episode on a new connection.

The connections live in this process: serve the API from one process (``robobpp serve`` does), or route
``/api/v1/pull/*`` of one submission to one process.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections import defaultdict, deque
from typing import Any

from fastapi import APIRouter, WebSocket
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from robobpp import protocol as P
from robobpp.db.models import EpisodeRow, Submission
from robobpp.db.work import ACTIVE_SUBMISSION
from robobpp.server.api.deps import auth_refused_for, principal_for_token
from robobpp.server.problems import ProblemError

log = logging.getLogger("robobpp.server.pull")
router = APIRouter(tags=["pull"])

#: WebSocket close codes the relay uses (4000-4999 are the application's).
GONE = 4001  # the participant's client disconnected mid-episode
REFUSED = 4003  # bad token, not a pull submission, or not a running episode under this lease
NO_CLIENT = 4004  # no client of the submission connected within the worker's wait
FINISHED = 4010  # the submission is over: the client may stop
TOO_LARGE = 4009  # the client's answer passed the size cap
TOO_MANY = 4029  # the submission or the participant has as many client connections open as allowed
#: Slack over the answer cap for the frame's envelope line.
ENVELOPE_BYTES = 4096
MAX_WAIT_S = 300.0


class ClientConnection:
    """One participant connection; frames it sends while paired go to the worker through ``inbox``."""

    def __init__(self, ws: WebSocket, submission_id: int) -> None:
        self.ws = ws
        self.submission_id = submission_id
        self.inbox: asyncio.Queue[bytes | int] = asyncio.Queue()
        self.alive = True
        self.busy = False


class PullHub:
    """Idle client connections per submission, and the workers waiting for one."""

    def __init__(self) -> None:
        self._idle: defaultdict[int, deque[ClientConnection]] = defaultdict(deque)
        self._waiting: defaultdict[int, deque[asyncio.Future[ClientConnection]]] = defaultdict(deque)
        #: Open client connections (idle or busy) per submission and per participant: the caps' counts.
        self.open_per_submission: defaultdict[int, int] = defaultdict(int)
        self.open_per_participant: defaultdict[int, int] = defaultdict(int)

    def admit(
        self, submission_id: int, participant_id: int, per_submission: int, per_participant: int
    ) -> bool:
        """Count a new client connection in, unless its submission or participant is at its cap (a flood of
        idle sockets costs file handles and memory, and serves nothing: one per episode served at once)."""
        if (
            self.open_per_submission[submission_id] >= per_submission
            or self.open_per_participant[participant_id] >= per_participant
        ):
            return False
        self.open_per_submission[submission_id] += 1
        self.open_per_participant[participant_id] += 1
        return True

    def leave(self, submission_id: int, participant_id: int) -> None:
        for table, key in (
            (self.open_per_submission, submission_id),
            (self.open_per_participant, participant_id),
        ):
            table[key] -= 1
            if table[key] <= 0:
                del table[key]

    def connected(self, submission_id: int) -> int:
        """Idle connections of a submission (busy ones serve an episode)."""
        return sum(c.alive for c in self._idle.get(submission_id, ()))

    def release(self, conn: ClientConnection) -> None:
        """The connection is free: hand it to the first waiting worker, or keep it idle."""
        conn.busy = False
        if not conn.alive:
            return
        while not conn.inbox.empty():  # late answers of the last episode are nobody's business now
            conn.inbox.get_nowait()
        waiting = self._waiting[conn.submission_id]
        while waiting:
            future = waiting.popleft()
            if not future.done():
                conn.busy = True
                future.set_result(conn)
                return
        self._idle[conn.submission_id].append(conn)

    async def take(self, submission_id: int, timeout_s: float) -> ClientConnection | None:
        idle = self._idle[submission_id]
        while idle:
            conn = idle.popleft()
            if conn.alive:
                conn.busy = True
                return conn
        future: asyncio.Future[ClientConnection] = asyncio.get_running_loop().create_future()
        self._waiting[submission_id].append(future)
        try:
            return await asyncio.wait_for(future, timeout_s)
        except TimeoutError:
            return None

    def drop(self, conn: ClientConnection) -> None:
        conn.alive = False
        if conn in self._idle[conn.submission_id]:
            self._idle[conn.submission_id].remove(conn)
        conn.inbox.put_nowait(GONE)  # wakes the worker paired with it, if any


def hub_of(ws: WebSocket) -> PullHub:
    hub = getattr(ws.app.state, "pull_hub", None)
    if hub is None:
        hub = ws.app.state.pull_hub = PullHub()
    return hub


def _client_submission(ws: WebSocket, token: str, submission_id: int) -> tuple[int, int]:
    wait = auth_refused_for(ws)  # type: ignore[arg-type]  # a WebSocket has .app and .client like a Request
    if wait:
        raise ProblemError(
            429, "too-many-failures", "Too many failed authentications", f"retry in {wait:.0f} s"
        )
    principal = principal_for_token(ws, token)  # type: ignore[arg-type]
    if principal is None:
        raise ProblemError(
            401, "unauthorized", "Unauthorized", "the API token is not valid (unknown or revoked)"
        )
    with ws.app.state.runtime.session() as session:
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
    settings = ws.app.state.settings
    hub = hub_of(ws)
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
        cap = settings.response_cap_bytes + ENVELOPE_BYTES
        await ws.send_text(
            json.dumps({"type": "welcome", "submission": submission_id, "protocol": P.PROTOCOL})
        )
        conn = ClientConnection(ws, submission_id)
        hub.release(conn)
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                frame = message.get("bytes")
                if frame is None or not conn.busy:
                    continue  # text frames carry nothing for a worker; an idle connection has no one to answer
                conn.inbox.put_nowait(TOO_LARGE if len(frame) > cap else frame)
        finally:
            hub.drop(conn)
    finally:
        hub.leave(submission_id, participant_id)


async def _to_client(ws: WebSocket, conn: ClientConnection) -> int | None:
    while True:
        message = await ws.receive()
        if message["type"] == "websocket.disconnect":
            return None
        frame = message.get("bytes")
        if frame is None:
            continue
        try:
            await conn.ws.send_bytes(frame)
        except Exception:  # noqa: BLE001 - the client's socket broke under us: same as a disconnect
            return GONE


async def _to_worker(ws: WebSocket, conn: ClientConnection) -> int:
    while True:
        item = await conn.inbox.get()
        if isinstance(item, int):
            return item
        await ws.send_bytes(item)


@router.websocket("/pull/episodes/{episode_id}")
async def worker_drives(ws: WebSocket, episode_id: int, wait: float = 30.0) -> None:
    """A worker holding the episode's lease: paired with an idle client of its submission, then relayed."""
    runtime = ws.app.state.runtime
    lease = ws.headers.get("x-robobpp-lease", "")
    submission_id = await run_in_threadpool(_worker_submission, runtime, episode_id, lease) if lease else None
    await ws.accept()
    if submission_id is None:
        await ws.close(REFUSED, "not a running pull episode under this lease")
        return
    hub = hub_of(ws)
    conn = await hub.take(submission_id, min(max(wait, 0.0), MAX_WAIT_S))
    if conn is None:
        await ws.close(NO_CLIENT, f"no client of submission {submission_id} connected in time")
        return
    code: int | None = None
    try:
        await ws.send_text("paired")
        tasks = {asyncio.create_task(_to_client(ws, conn)), asyncio.create_task(_to_worker(ws, conn))}
        done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for task in pending:
            task.cancel()
        code = next(iter(done)).result()
    except Exception:  # noqa: BLE001 - the worker's socket broke: the client is free again
        log.debug("pull relay of episode %s ended", episode_id, exc_info=True)
    finally:
        if conn.alive:
            hub.release(conn)
    if code is not None:
        reason = (
            "the client's answer is larger than the cap" if code == TOO_LARGE else "the client disconnected"
        )
        with contextlib.suppress(Exception):  # already closed by the worker
            await ws.close(code, reason)
