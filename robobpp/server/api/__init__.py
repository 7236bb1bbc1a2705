"""The JSON API under ``/api/v1``."""

from __future__ import annotations

from fastapi import APIRouter

from robobpp.server.api import leaderboards, participants, submissions

router = APIRouter()
router.include_router(participants.router)
router.include_router(submissions.router)
router.include_router(leaderboards.router)
