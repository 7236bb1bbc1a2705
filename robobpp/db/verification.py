"""Verification on the hold-out draw (docs/server.md, "Hostile participants and the threat model of the private split").

Every private-track submission plays the same groups of the private split, and a remote policy sees each
box it is shown, so a participant can record the groups and tune to them. A top entry can therefore be
re-evaluated on the *hold-out* draw: groups drawn from the same private pool with a second secret seed,
which no submission ever plays except these verifications. The verification is an ordinary submission
with track ``verify`` (never on a board) pointing at the original (``verifies_id``), started by the operator
(``robobpp.server.services.verification``); when it finishes, :func:`record_verdict` (called by the run
completion in :mod:`robobpp.db.work`, which this module never imports) compares the two per leaderboard and
writes the verdict on the original, where the API (and the pages) show it: ``verified`` when every board's
result agrees within the two intervals, ``disagrees`` when one does not — the signature of a policy tuned to
the played groups.

A re-run that cannot be compared because of the participant's side is ``unverifiable``: a board where the
policy failed beyond the allowed share (:data:`robobpp.scoring.stats.POLICY_FAILURE_SHARE`: an unreachable
URL answers ``policy_error`` on every episode), or episodes that failed because no client of a pull
submission ever connected. Before, taking the policy offline during the re-run turned a coming ``disagrees``
into ``failed``: read as the service's failure, and started again by the board's ``verify?top=N``, as often
as the policy went offline. Like ``disagrees``, ``unverifiable`` stands (the board's ``verify?top=N`` does not
start it again; the operator may re-run one submission) and is flagged on the board. ``failed`` is left for
the service's own failures (episodes that failed for another reason), which the operator may re-run. A board that disagrees decides the verdict whatever the others did.

The compared figure is the run's space utilisation (the geometric metric every setting has) with the
board's own 95 % interval: the seeded bootstrap over groups of :mod:`robobpp.scoring.stats`, applied to each run
on its own (the two runs played different groups, so the resamples are not paired). Runs recorded before
per-group figures existed fall back to a normal-approximation interval of the per-episode values.
"""

from __future__ import annotations

import math
import statistics
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from robobpp.db.models import EpisodeRow, RunRow, Submission
from robobpp.scoring import stats
from robobpp.vocabulary import CLOSED

#: How a pull episode that no client of the participant served ends (robobpp/worker/run.py releases it with
#: ``pull mode: <NoClient>``; robobpp/worker/pull.py words NoClient "no client … connected within …").
NO_CLIENT_ERROR = "pull mode: no client"

#: Per-episode metric compared between the played groups and the hold-out draw.
METRIC = "space_utilization"
Z95 = 1.959963984540054


def interval(values: list[float]) -> dict[str, float]:
    """Mean and its normal-approximation 95 % interval (a single value has a zero-width interval)."""
    mean = statistics.fmean(values)
    half = Z95 * statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else 0.0
    return {"mean": mean, "low": mean - half, "high": mean + half, "n": len(values)}


def agree(a: dict[str, float], b: dict[str, float]) -> bool:
    """Two results agree when their intervals overlap."""
    return a["low"] <= b["high"] and b["low"] <= a["high"]


def run_interval(session: Session, submission_id: int, dataset: str, setting: str) -> dict[str, Any] | None:
    """The run's :data:`METRIC` with its 95 % interval, or ``None`` when the run did not complete."""
    run = session.execute(
        select(RunRow).where(
            RunRow.submission_id == submission_id,
            RunRow.dataset == dataset,
            RunRow.setting == setting,
            RunRow.protocol == CLOSED,
            RunRow.status == "completed",
        )
    ).scalar_one_or_none()
    if run is None:
        return None
    figures = run.figures or {}
    mean = (run.metrics or {}).get(METRIC)
    if figures.get("ids") and mean is not None:
        samples = stats.metric_samples([figures], METRIC, stats.resample_counts(len(figures["ids"])))
        low, high = stats.interval(samples)
        if np.isfinite(low[0]) and np.isfinite(high[0]):
            return {
                "mean": float(mean),
                "low": float(low[0]),
                "high": float(high[0]),
                "n": len(figures["ids"]),
                "method": "bootstrap",
            }
    values = _values(session, submission_id, dataset, setting)
    return {**interval(values), "method": "normal"} if values else None


def _values(session: Session, submission_id: int, dataset: str, setting: str) -> list[float]:
    rows = session.execute(
        select(EpisodeRow.metrics).where(
            EpisodeRow.submission_id == submission_id,
            EpisodeRow.dataset == dataset,
            EpisodeRow.setting == setting,
            EpisodeRow.protocol == CLOSED,
            EpisodeRow.status == "done",
        )
    ).scalars()
    return [float(m[METRIC]) for m in rows if m and m.get(METRIC) is not None]


def record_verdict(session: Session, verify: Submission) -> dict[str, Any] | None:
    """Compare a finished verification with its original and write the verdict on the original."""
    original = session.get(Submission, verify.verifies_id) if verify.verifies_id is not None else None
    if original is None:
        return None
    runs = []
    policy_failed = set(_policy_failed_boards(session, verify.id))
    for dataset in verify.datasets:
        for setting in verify.settings:
            if (dataset, setting) in policy_failed:  # the participant's policy failed the re-run here
                runs.append({"dataset": dataset, "setting": setting, "agree": None, "policy_failed": True})
                continue
            a = run_interval(session, original.id, dataset, setting)
            b = run_interval(session, verify.id, dataset, setting)
            if a is None or b is None:
                runs.append({"dataset": dataset, "setting": setting, "agree": None})
                continue
            runs.append(
                {
                    "dataset": dataset,
                    "setting": setting,
                    "metric": METRIC,
                    "played": a,
                    "holdout": b,
                    "agree": agree(a, b),
                }
            )
    unserved = _unserved_episodes(session, verify.id)
    if any(r["agree"] is False for r in runs):
        status = "disagrees"
    elif verify.status == "completed" and all(r["agree"] for r in runs):
        status = "verified"
    elif policy_failed or unserved:
        status = "unverifiable"
    else:
        status = "failed"
    verdict = {
        "status": status,
        "submission_id": verify.id,
        "checked_at": datetime.now(UTC).isoformat(),
        "runs": runs,
    }
    if unserved:
        verdict["unserved_episodes"] = unserved
    original.verification = verdict
    return verdict


def _policy_failed_boards(session: Session, submission_id: int) -> list[tuple[str, str]]:
    """The boards (dataset, setting) where the run's policy failures exceed the allowed share."""
    rows = session.execute(
        select(RunRow.dataset, RunRow.setting, RunRow.extras).where(
            RunRow.submission_id == submission_id, RunRow.protocol == CLOSED
        )
    ).all()
    return [
        (dataset, setting)
        for dataset, setting, extras in rows
        if extras and stats.run_failed(extras.get("terminations"), int(extras.get("episodes") or 0))
    ]


def _unserved_episodes(session: Session, submission_id: int) -> int:
    """Episodes of the re-run that failed because no client of the (pull) submission connected."""
    return len(
        session.execute(
            select(EpisodeRow.id).where(
                EpisodeRow.submission_id == submission_id,
                EpisodeRow.status == "failed",
                EpisodeRow.error.like(NO_CLIENT_ERROR + "%"),
            )
        ).all()
    )
