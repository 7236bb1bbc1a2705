"""Leaderboards: raw metrics and per-group figures stored; scores, intervals and ranks computed once per
change of the board and served from the cache, a page at a time (docs/benchmark.md, "Scoring and uncertainty")."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request, Response
from sqlalchemy.orm import Session

from robobpp.episode import TERMINATION_REASONS
from robobpp.schemas import (
    PROTOCOL_HELP,
    DatasetName,
    Leaderboard,
    OverallGrid,
    ProtocolName,
    Reproduction,
    ServiceInfo,
    SettingName,
)
from robobpp.scoring.boards import board_view, grid_view
from robobpp.scoring.scores import WEIGHTS
from robobpp.server.api.deps import SettingsDep, in_read_session
from robobpp.server.runtime import Runtime
from robobpp.server.services.boards import BoardCache, to_json

router = APIRouter(tags=["leaderboards"])
Track = Literal["private", "public"]


def board_cache(request: Request) -> BoardCache:
    """The app's board cache (version-checked against SQL; see services.boards)."""
    cache = getattr(request.app.state, "board_cache", None)
    if cache is None:
        cache = request.app.state.board_cache = make_board_cache(request.app.state.runtime)
    return cache


def make_board_cache(runtime: Runtime) -> BoardCache:
    settings = runtime.settings
    return BoardCache(
        runtime.read_session,
        refresh_s=settings.board_refresh_s,
        datasets=tuple(settings.datasets),
        settings=tuple(settings.enabled_settings),
        database_url=settings.sqlalchemy_url,
        process_from=settings.board_process_from,
        store_dir=settings.state_dir,
    )


async def cached_body(
    request: Request, track: str, key: tuple[Any, ...], build: Callable[[Session], bytes]
) -> bytes:
    """A served body shared by every reader of ``key`` (services.boards): answered on the event loop when
    it is current (no thread, no session), else built or version-checked in a worker thread."""
    cache = board_cache(request)
    body = cache.fresh_response(track, key)
    if body is not None:
        return body

    return await in_read_session(
        request, lambda session: cache.response(session, track, key, lambda: build(session))
    )


View = Annotated[
    Literal["best", "all"],
    Query(description="best: each participant's best entry (default); all: every entry"),
]
Protocol = Annotated[ProtocolName, Query(description=PROTOCOL_HELP)]
Limit = Annotated[int, Query(ge=1, le=500)]
Offset = Annotated[int, Query(ge=0, le=10**7)]


@router.get(
    "/leaderboards",
    response_model=OverallGrid,
    summary="The overall grid: every board's score and rank, and the Mean with intervals",
)
async def overall(
    request: Request,
    settings: SettingsDep,
    track: Track = "private",
    view: View = "best",
    limit: Limit = 50,
    offset: Offset = 0,
    protocol: Protocol = "closed",
) -> Response:
    cache, boards = board_cache(request), (tuple(settings.datasets), tuple(settings.enabled_settings))
    body = await cached_body(
        request,
        track,
        ("api-grid", *boards, track, view, limit, offset, protocol),
        lambda s: to_json(grid_view(cache.grid(s, *boards, track, protocol), view, limit, offset)),
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
    track: Track = "private",
    view: View = "best",
    limit: Limit = 50,
    offset: Offset = 0,
    submission: Annotated[int | None, Query(ge=1, le=2**62, description="Only this submission")] = None,
    protocol: Protocol = "closed",
) -> Response:
    cache = board_cache(request)
    key = ("api-board", dataset, setting, track, view, limit, offset, submission, protocol)
    body = await cached_body(
        request,
        track,
        key,
        lambda s: to_json(
            board_view(cache.board(s, dataset, setting, track, protocol), view, limit, offset, submission)
        ),
    )
    return Response(body, media_type="application/json")


@router.get(
    "/reproduction",
    response_model=Reproduction,
    summary="The paper's baselines under the paper protocol beside the paper's published tables",
)
async def reproduction_route(request: Request, track: Track = "private") -> Response:
    from robobpp.server.services.reproduction import reproduction

    body = await cached_body(
        request, track, ("api-reproduction", track), lambda s: to_json(reproduction(s, track))
    )
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
