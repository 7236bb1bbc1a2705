"""Leaderboards: raw metrics and per-group figures stored; scores, intervals and ranks computed by the board
worker once per change of the board, published in SQL and served a page at a time (docs/benchmark.md, "Scoring and uncertainty")."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from robobpp.boards.reader import BoardCache
from robobpp.boards.store import BoardsUnavailable, board_key, grid_key, to_json
from robobpp.episode import TERMINATION_REASONS
from robobpp.schemas import (
    LOOP_HELP,
    MAX_SUBMISSION_LOOKAHEAD,
    Leaderboard,
    OverallGrid,
    Reproduction,
    ServiceInfo,
)
from robobpp.scoring.scores import WEIGHTS
from robobpp.server.api.deps import SettingsDep
from robobpp.server.problems import ProblemError
from robobpp.server.runtime import Runtime
from robobpp.server.state import state_of
from robobpp.vocabulary import CLOSED, BoardTrack, DatasetName, Loop, SettingName, has_boards

router = APIRouter(tags=["leaderboards"])


def board_cache(request: Request) -> BoardCache:
    """The app's reader of the published boards (boards/reader.py)."""
    return state_of(request.app).board_cache


def make_board_cache(runtime: Runtime, wake: Callable[[], None] | None = None) -> BoardCache:
    settings = runtime.settings
    return BoardCache(
        runtime.read_session,
        refresh_s=settings.board_refresh_s,
        wait_s=settings.board_wait_s,
        datasets=tuple(settings.datasets),
        settings=tuple(settings.enabled_settings),
        wake=wake,
    )


async def cached_body(
    request: Request,
    track: str,
    board: str | None,
    key: tuple[Any, ...],
    build: Callable[[BoardCache], bytes],
    lookahead: int = 0,
) -> bytes:
    """A served body of ``board`` (None: of the track's whole publication) shared by every reader of ``key``
    (boards.reader): answered on the event loop when it is current (no thread, no query), else built or
    version-checked in a worker thread. A board not published yet answers 503 with Retry-After (a fresh
    server's first computation); a board of a lookahead K > 0 that no entry saw, 404."""
    cache = board_cache(request)
    body = cache.fresh_response(track, board, key)
    if body is not None:
        return body
    try:
        return await run_in_threadpool(cache.response, track, board, key, lambda: build(cache))
    except BoardsUnavailable as exc:
        if lookahead:
            known = await run_in_threadpool(known_lookaheads, cache, track)
            if known is not None and lookahead not in known:
                raise ProblemError(
                    404,
                    "not-found",
                    "No such board",
                    f"no {track}-track entry saw lookahead {lookahead}; this track has boards for "
                    f"lookahead {', '.join(map(str, known))}",
                ) from exc
        raise ProblemError(
            503,
            "boards-not-ready",
            "Boards not ready",
            "the boards are being computed for the first time; try again in a moment",
            headers={"Retry-After": "2"},
        ) from exc


def known_lookaheads(cache: BoardCache, track: str) -> list[int] | None:
    """The lookaheads the track's publication has boards of (None: nothing published yet)."""
    try:
        return cache.lookaheads(track)
    except BoardsUnavailable:
        return None


def lookahead_board(protocol: str, setting: str | None, lookahead: int) -> None:
    """A lookahead K > 0 has closed-loop boards only (docs/server.md, "Boards per lookahead")."""
    if not has_boards(protocol, lookahead, setting):
        raise ProblemError(
            404,
            "not-found",
            "No such board",
            "the paper-protocol boards are lookahead 0 only (the paper's tables were made without lookahead); "
            "a lookahead K > 0 has closed-loop boards",
        )


View = Annotated[
    Literal["best", "all"],
    Query(description="best: each participant's best entry (default); all: every entry"),
]
LoopQuery = Annotated[Loop, Query(description=LOOP_HELP)]
Limit = Annotated[int, Query(ge=1, le=500)]
Offset = Annotated[int, Query(ge=0, le=10**7)]
Lookahead = Annotated[
    int,
    Query(
        ge=0,
        le=MAX_SUBMISSION_LOOKAHEAD,
        description="The boards of the submissions that saw this many next boxes (0: the leaderboard); "
        "each lookahead ranks apart",
    ),
]


@router.get(
    "/leaderboards",
    response_model=OverallGrid,
    summary="The overall grid: every board's score and rank, and the Mean with intervals",
)
async def overall(
    request: Request,
    settings: SettingsDep,
    track: BoardTrack = "private",
    view: View = "best",
    limit: Limit = 50,
    offset: Offset = 0,
    protocol: LoopQuery = CLOSED,
    lookahead: Lookahead = 0,
) -> Response:
    lookahead_board(protocol, None, lookahead)
    body = await cached_body(
        request,
        track,
        grid_key(protocol, lookahead),
        ("api-grid", track, view, limit, offset, protocol, lookahead),
        lambda cache: to_json(cache.grid_page(track, protocol, view, limit, offset, lookahead)),
        lookahead,
    )
    return Response(body, media_type="application/json")


@router.get(
    "/leaderboards/{dataset}/{setting}",
    response_model=Leaderboard,
    summary="One leaderboard (dataset × setting): raw metrics, both scores, intervals and rank intervals",
)
async def board(
    request: Request,
    dataset: DatasetName,
    setting: SettingName,
    track: BoardTrack = "private",
    view: View = "best",
    limit: Limit = 50,
    offset: Offset = 0,
    submission: Annotated[int | None, Query(ge=1, le=2**62, description="Only this submission")] = None,
    protocol: LoopQuery = CLOSED,
    lookahead: Lookahead = 0,
) -> Response:
    settings_ = state_of(request.app).settings
    if dataset not in settings_.datasets or setting not in settings_.enabled_settings:
        raise ProblemError(404, "not-found", "Not found", f"this server has no {dataset} × {setting} board")
    lookahead_board(protocol, setting, lookahead)
    key = ("api-board", dataset, setting, track, view, limit, offset, submission, protocol, lookahead)
    body = await cached_body(
        request,
        track,
        board_key(dataset, setting, protocol, lookahead),
        key,
        lambda cache: to_json(
            cache.board_page(dataset, setting, track, protocol, view, limit, offset, submission, lookahead)
        ),
        lookahead,
    )
    return Response(body, media_type="application/json")


@router.get(
    "/reproduction",
    response_model=Reproduction,
    summary="The paper's baselines under the paper protocol beside the paper's published tables",
)
async def reproduction_route(request: Request, track: BoardTrack = "private") -> Response:
    from robobpp.server.services.reproduction import reproduction

    def build(_cache: BoardCache) -> bytes:
        with state_of(request.app).runtime.read_session() as session:
            return to_json(reproduction(session, track))

    # the baselines' runs change only when their boards do: built once per publication of the track
    body = await cached_body(request, track, None, ("api-reproduction", track), build)
    return Response(body, media_type="application/json")


@router.get("/info", response_model=ServiceInfo, summary="What this service evaluates")
async def info(settings: SettingsDep) -> ServiceInfo:
    reasons = {
        **TERMINATION_REASONS,
        "worker_lost": "no worker could finish the episode",
        "evaluation_error": "the service could not run the episode",
    }
    return ServiceInfo(
        datasets=list(settings.datasets),
        settings=list(settings.enabled_settings),
        groups=settings.groups,
        weights=WEIGHTS,
        termination_reasons=reasons,
    )
