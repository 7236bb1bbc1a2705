"""Leaderboards: raw metrics and per-group figures stored; scores, intervals and ranks computed once per
change of the board and served from the cache, a page at a time (BENCHMARK.md §5)."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request, Response

from robobpp.episode import TERMINATION_REASONS
from robobpp.leaderboard import board_view, grid_view
from robobpp.schemas import DatasetName, Leaderboard, OverallGrid, ServiceInfo, SettingName
from robobpp.scoring import WEIGHTS
from robobpp.server.api.deps import SessionDep, SettingsDep
from robobpp.server.services.boards import BoardCache, to_json

router = APIRouter(tags=["leaderboards"])
Track = Literal["private", "public"]


def board_cache(request: Request) -> BoardCache:
    """The app's board cache (version-checked against SQL on every read; see services.boards)."""
    cache = getattr(request.app.state, "board_cache", None)
    if cache is None:
        runtime = getattr(request.app.state, "runtime", None)
        refresh = runtime.settings.board_refresh_s if runtime is not None else 0.0
        cache = request.app.state.board_cache = BoardCache(runtime.session if runtime is not None else None,
                                                           refresh_s=refresh)  # fmt: skip
    return cache


View = Annotated[
    Literal["best", "all"],
    Query(description="best: each participant's best entry (default); all: every entry"),
]
Limit = Annotated[int, Query(ge=1, le=500)]
Offset = Annotated[int, Query(ge=0, le=10**7)]


@router.get("/leaderboards", response_model=OverallGrid,
            summary="The overall grid: every board's score and rank, and the Mean with intervals")  # fmt: skip
def overall(request: Request, session: SessionDep, settings: SettingsDep, track: Track = "private",
            view: View = "best", limit: Limit = 50, offset: Offset = 0) -> Response:  # fmt: skip
    cache, boards = board_cache(request), (tuple(settings.datasets), tuple(settings.enabled_settings))
    body = cache.response(session, track, ("api-grid", *boards, track, view, limit, offset),
                          lambda: to_json(grid_view(cache.grid(session, *boards, track), view, limit, offset)))  # fmt: skip
    return Response(body, media_type="application/json")


@router.get("/leaderboards/{dataset}/{setting}", response_model=Leaderboard,
            summary="One leaderboard (dataset × setting): raw metrics, both scores, intervals and rank intervals")  # fmt: skip
def board(request: Request, dataset: DatasetName, setting: SettingName, session: SessionDep,
          track: Track = "private", view: View = "best", limit: Limit = 50, offset: Offset = 0,
          submission: Annotated[int | None, Query(ge=1, le=2**62, description="Only this submission")] = None,
          ) -> Response:  # fmt: skip
    cache = board_cache(request)
    body = cache.response(session, track, ("api-board", dataset, setting, track, view, limit, offset, submission),
                          lambda: to_json(board_view(cache.board(session, dataset, setting, track), view, limit,
                                                     offset, submission)))  # fmt: skip
    return Response(body, media_type="application/json")


@router.get("/info", response_model=ServiceInfo, summary="What this service evaluates")
def info(settings: SettingsDep) -> ServiceInfo:
    reasons = {**TERMINATION_REASONS, "worker_lost": "no worker could finish the episode",
               "evaluation_error": "the service could not run the episode"}  # fmt: skip
    return ServiceInfo(datasets=list(settings.datasets), settings=list(settings.enabled_settings),
                       groups=settings.groups, weights=WEIGHTS, termination_reasons=reasons)  # fmt: skip
