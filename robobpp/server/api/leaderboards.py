"""Leaderboards: raw metrics stored, scores and ranks computed on read (BENCHMARK.md §5)."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Request, Response

from robobpp.episode import TERMINATION_REASONS
from robobpp.schemas import DatasetName, Leaderboard, OverallGrid, ServiceInfo, SettingName
from robobpp.scoring import WEIGHTS
from robobpp.server.api.deps import SessionDep, SettingsDep
from robobpp.server.services import boards
from robobpp.server.services.boards import BoardCache

router = APIRouter(tags=["leaderboards"])
Track = Literal["private", "public"]


def board_cache(request: Request) -> BoardCache:
    """The app's board cache (version-checked against SQL on every read; see services.boards)."""
    cache = getattr(request.app.state, "board_cache", None)
    if cache is None:
        cache = request.app.state.board_cache = BoardCache()
    return cache


@router.get(
    "/leaderboards", response_model=OverallGrid, summary="The overall grid: every board's score and rank"
)
def overall(
    request: Request, session: SessionDep, settings: SettingsDep, track: Track = "private"
) -> OverallGrid:
    grid = boards.overall_grid(
        board_cache(request), session, settings.datasets, settings.enabled_settings, track
    )
    return OverallGrid.model_validate(grid)


@router.get("/leaderboards/{dataset}/{setting}", response_model=Leaderboard,
            summary="One leaderboard (dataset × setting) with raw metrics, normalised scores and rank")  # fmt: skip
def board(
    request: Request,
    dataset: DatasetName,
    setting: SettingName,
    session: SessionDep,
    track: Track = "private",
) -> Response:
    _data, body = board_cache(request).get(session, dataset, setting, track)
    return Response(body, media_type="application/json")


@router.get("/info", response_model=ServiceInfo, summary="What this service evaluates")
def info(settings: SettingsDep) -> ServiceInfo:
    reasons = {**TERMINATION_REASONS, "worker_lost": "no worker could finish the episode",
               "evaluation_error": "the service could not run the episode"}  # fmt: skip
    return ServiceInfo(datasets=list(settings.datasets), settings=list(settings.enabled_settings),
                       groups=settings.groups, weights=WEIGHTS, termination_reasons=reasons)  # fmt: skip
