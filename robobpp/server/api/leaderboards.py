"""Leaderboards: raw metrics stored, scores and ranks computed on read (BENCHMARK.md §5)."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter

from robobpp.db import queries
from robobpp.episode import TERMINATION_REASONS
from robobpp.scoring import WEIGHTS
from robobpp.server.api.deps import SessionDep, SettingsDep
from robobpp.server.api.schemas import DatasetName, Leaderboard, OverallGrid, ServiceInfo, SettingName

router = APIRouter(tags=["leaderboards"])
Track = Literal["private", "public"]


@router.get(
    "/leaderboards", response_model=OverallGrid, summary="The overall grid: every board's score and rank"
)
def overall(session: SessionDep, settings: SettingsDep, track: Track = "private") -> OverallGrid:
    grid = queries.overall_grid(session, datasets=settings.datasets, settings=settings.enabled_settings,
                                track=track)  # fmt: skip
    return OverallGrid.model_validate(grid)


@router.get("/leaderboards/{dataset}/{setting}", response_model=Leaderboard,
            summary="One leaderboard (dataset × setting) with raw metrics, normalised scores and rank")  # fmt: skip
def board(
    dataset: DatasetName, setting: SettingName, session: SessionDep, track: Track = "private"
) -> Leaderboard:
    data = queries.leaderboard(session, dataset, setting, track=track)
    return Leaderboard.model_validate({**data, "weights": WEIGHTS[setting]})


@router.get("/info", response_model=ServiceInfo, summary="What this service evaluates")
def info(settings: SettingsDep) -> ServiceInfo:
    return ServiceInfo(datasets=list(settings.datasets), settings=list(settings.enabled_settings),
                       groups=settings.groups, weights=WEIGHTS, termination_reasons={
                           **TERMINATION_REASONS, "worker_lost": "no worker could finish the episode",
                           "evaluation_error": "the service could not run the episode"})  # fmt: skip
