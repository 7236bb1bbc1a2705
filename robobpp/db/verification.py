"""Verification on the hold-out draw (docs/server.md, "Threat model of the private split").

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
            RunRow.protocol == "closed",
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
            EpisodeRow.protocol == "closed",
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
    for dataset in verify.datasets:
        for setting in verify.settings:
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
    if verify.status != "completed" or any(r["agree"] is None for r in runs):
        status = "failed"
    else:
        status = "verified" if all(r["agree"] for r in runs) else "disagrees"
    verdict = {
        "status": status,
        "submission_id": verify.id,
        "checked_at": datetime.now(UTC).isoformat(),
        "runs": runs,
    }
    original.verification = verdict
    return verdict
