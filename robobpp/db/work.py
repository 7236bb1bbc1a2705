"""The work queue in SQL: create, claim (lease), heartbeat, complete, fail, cancel.

Every executor (the local process pool, Celery tasks) uses these functions and nothing else to move an
episode through ``pending → running → done | failed | cancelled``, so the guarantees hold everywhere:

* a claim takes a *lease* (expiry + random token); an expired lease is taken over by the next claimer,
  up to ``max_attempts`` claims, after which the episode is recorded ``failed`` (``worker_lost``);
* completion is idempotent: it writes only while the caller's token is the current one and the episode is
  still running, so a late or repeated completion changes nothing and nothing is counted twice;
* the run's aggregate is written in the same transaction as its last episode, under a row lock on the run.

Callers own the transaction (``with runtime.session() as s: claim_episode(s, ...)``).
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any, cast

from sqlalchemy import CursorResult, Result, and_, func, insert, or_, select, update
from sqlalchemy.orm import Session

from robobpp.db.models import EpisodeRow, Participant, RunRow, Submission, utcnow
from robobpp.db.verification import record_verdict
from robobpp.provenance import environment, merge, merged
from robobpp.replay import paper_settings, plan_of
from robobpp.scoring.entries import part_of_run
from robobpp.scoring.metrics import aggregate
from robobpp.scoring.stats import POLICY_FAILURE_SHARE, group_figures, run_failed
from robobpp.vocabulary import ACTIVE_SUBMISSION, CLOSED, PAPER, QUEUED_EPISODE, TERMINAL_EPISODE

#: Extra termination code of an episode whose workers kept dying (not the policy's fault).
WORKER_LOST = "worker_lost"
#: Which groups a track plays: the private split, the public train groups, or the private pool's hold-out
#: draw (verifications only; docs/server.md, threat model).
SPLIT_OF_TRACK = {"private": "test", "public": "train", "verify": "holdout"}


@dataclass(frozen=True, slots=True)
class Claim:
    """Everything a worker needs to run one episode (plain data: it crosses process boundaries)."""

    episode_id: int
    token: str
    attempt: int
    submission_id: int
    dataset: str
    setting: str
    split: str
    group: int
    policy_url: str
    secret: str | None
    pinned_ip: str | None
    lookahead: int
    keep_trace: bool
    mode: str = "push"
    #: ``paper``: replay the plan stored on the episode (:func:`episode_plan`), no policy involved.
    protocol: str = CLOSED


def create_submission(
    session: Session,
    participant: Participant,
    *,
    name: str,
    policy_url: str,
    datasets: list[str],
    settings: list[str],
    groups: int,
    track: str = "private",
    secret: str | None = None,
    pinned_ip: str | None = None,
    lookahead: int = 0,
    mode: str = "push",
) -> Submission:
    """The submission with one run per (dataset, setting) and one episode per group, in one transaction."""
    split = SPLIT_OF_TRACK[track]
    boards = [(d, s, CLOSED) for d in datasets for s in settings]
    boards += [(d, s, PAPER) for d in datasets for s in paper_settings(settings, track)]
    sub = Submission(
        participant=participant,
        name=name,
        policy_url=policy_url,
        secret=secret,
        pinned_ip=pinned_ip,
        track=track,
        mode=mode,
        datasets=list(datasets),
        settings=list(settings),
        lookahead=lookahead,
        status="queued",
        episodes_total=len(boards) * groups,
    )
    session.add(sub)
    session.flush()
    for dataset, setting, protocol in boards:
        run = RunRow(
            submission_id=sub.id, dataset=dataset, setting=setting, protocol=protocol, episodes_total=groups
        )
        session.add(run)
        session.flush()
        # a replay waits for its Math Pack episode (``waiting`` is never claimed): see ``_settle_replays``
        status = "pending" if protocol == CLOSED else "waiting"
        session.execute(
            insert(EpisodeRow),
            [  # one bulk INSERT: submitting stays cheap
                {
                    "submission_id": sub.id,
                    "run_id": run.id,
                    "dataset": dataset,
                    "setting": setting,
                    "split": split,
                    "group": g,
                    "protocol": protocol,
                    "status": status,
                    "attempts": 0,
                    "step": 0,
                }
                for g in range(groups)
            ],
        )
    session.flush()
    return sub


def _settle_replays(
    session: Session,
    math_episode_id: int,
    *,
    plan: dict[str, Any] | None = None,
    failure: tuple[str, str] | None = None,
) -> None:
    """A Math Pack episode was recorded: its paper-protocol replays (same submission, dataset and group;
    ``waiting`` until now) become ``pending`` with its ``plan``, or — when it ``failure`` (termination,
    detail) — ``failed`` too, their runs finalised. In the caller's transaction: the replays are released
    exactly when the episode is recorded, never twice, never lost."""
    ep = session.execute(
        select(
            EpisodeRow.submission_id,
            EpisodeRow.dataset,
            EpisodeRow.group,
            EpisodeRow.setting,
            EpisodeRow.protocol,
        ).where(EpisodeRow.id == math_episode_id)
    ).one()
    if ep.setting != "math" or ep.protocol != CLOSED:
        return
    replays = and_(
        EpisodeRow.submission_id == ep.submission_id,
        EpisodeRow.dataset == ep.dataset,
        EpisodeRow.group == ep.group,
        EpisodeRow.protocol == PAPER,
        EpisodeRow.status == "waiting",
    )
    if failure is None:
        session.execute(
            update(EpisodeRow)
            .where(replays)
            .values(status="pending", plan=plan)
            .execution_options(synchronize_session=False)
        )
        return
    runs = (
        session.execute(
            update(EpisodeRow)
            .where(replays)
            .values(
                status="failed",
                termination=failure[0],
                finished_at=utcnow(),
                termination_detail=f"its Math Pack episode could not be evaluated: {failure[1]}"[:4000],
            )
            .returning(EpisodeRow.run_id)
            .execution_options(synchronize_session=False)
        )
        .scalars()
        .all()
    )
    for run_id in sorted(set(runs)):
        finalize_run(session, run_id)


def take_unsent(
    session: Session,
    *,
    stale_after_s: float,
    ids: list[int] | None = None,
    now: datetime | None = None,
    limit: int = 1000,
) -> list[int]:
    """Pending episodes of active submissions with no broker message out, marked as sent now.

    The caller sends their messages inside the same transaction: if the broker refuses, the marks roll
    back and the next round tries again; a commit that fails after the send leaves a duplicate message,
    which the claim turns into a no-op. The conditional UPDATE makes concurrent dispatchers (server
    replicas, worker sweepers) send each episode once. A message older than ``stale_after_s`` (longer than
    the broker keeps an unacknowledged one) is presumed lost and sent again.
    """
    now = now or utcnow()
    unsent = and_(
        EpisodeRow.status == "pending",
        or_(
            EpisodeRow.enqueued_at.is_(None), EpisodeRow.enqueued_at < now - timedelta(seconds=stale_after_s)
        ),
    )
    query = (
        select(EpisodeRow.id)
        .join(Submission, Submission.id == EpisodeRow.submission_id)
        .where(unsent, Submission.status.in_(ACTIVE_SUBMISSION))
        .order_by(EpisodeRow.id)
        .limit(limit)
    )
    if ids is not None:
        query = query.where(EpisodeRow.id.in_(ids))
    candidates = list(session.execute(query).scalars())
    if not candidates:
        return []
    return sorted(
        session.execute(
            update(EpisodeRow)
            .where(EpisodeRow.id.in_(candidates), unsent)
            .values(enqueued_at=now)
            .returning(EpisodeRow.id)
            .execution_options(synchronize_session=False)
        ).scalars()
    )


def has_overdue(session: Session, *, older_than_s: float, now: datetime | None = None) -> bool:
    """Whether a pending episode of an active submission has had its message out for over ``older_than_s``.

    The cheap first question of the lost-message check (:func:`robobpp.worker.celery_executor.resend_lost`):
    only when it says yes does the dispatcher ask the broker how long the queue is."""
    cutoff = (now or utcnow()) - timedelta(seconds=older_than_s)
    row = session.execute(
        select(EpisodeRow.id)
        .join(Submission, Submission.id == EpisodeRow.submission_id)
        .where(
            EpisodeRow.status == "pending",
            EpisodeRow.enqueued_at < cutoff,
            Submission.status.in_(ACTIVE_SUBMISSION),
        )
        .limit(1)
    ).first()
    return row is not None


def _busy_participants(max_running: int) -> Any:
    """Participants with ``max_running`` remote episodes running: the claim skips their other episodes."""
    return (
        select(Submission.participant_id)
        .join(EpisodeRow, EpisodeRow.submission_id == Submission.id)
        .where(EpisodeRow.status == "running", ~Submission.policy_url.startswith("builtin:"))
        .group_by(Submission.participant_id)
        .having(func.count() >= max_running)
    )


def _expired(now: datetime) -> Any:
    return and_(EpisodeRow.status == "running", EpisodeRow.lease_expires_at < now)


def reap_expired(session: Session, max_attempts: int, now: datetime | None = None) -> int:
    """Record as ``failed`` the episodes whose last allowed lease expired; finalise their runs."""
    now = now or utcnow()
    rows = session.execute(
        select(EpisodeRow.id, EpisodeRow.run_id)
        .where(_expired(now), EpisodeRow.attempts >= max_attempts)
        .with_for_update(skip_locked=True)
    ).all()
    for episode_id, run_id in rows:
        detail = f"no worker finished the episode in {max_attempts} attempts"
        session.execute(
            update(EpisodeRow)
            .where(EpisodeRow.id == episode_id, _expired(now))
            .values(
                status="failed",
                termination=WORKER_LOST,
                finished_at=now,
                lease_token=None,
                termination_detail=detail,
            )
        )
        finalize_run(session, run_id)
        _settle_replays(session, episode_id, failure=(WORKER_LOST, detail))
    return len(rows)


@dataclass(frozen=True, slots=True)
class Load:
    """One participant with active submissions, as the fair order sees it."""

    participant_id: int
    builtin: bool
    running: int
    last_start: datetime | None
    first_submission: int


def participant_loads(session: Session) -> list[Load]:
    """Every participant with an active submission, fairest first (:func:`fair_key`).

    Reads the active submissions and only the episodes of theirs that ever started (by the submission-status
    index), never the pending backlog: the cost does not grow with the number of episodes waiting."""
    active = (
        select(Submission.participant_id.label("pid"), func.min(Submission.id).label("first"))
        .where(Submission.status.in_(ACTIVE_SUBMISSION))
        .group_by(Submission.participant_id)
        .subquery()
    )
    started = (
        select(
            Submission.participant_id.label("pid"),
            func.count().filter(EpisodeRow.status == "running").label("running"),
            func.max(EpisodeRow.started_at).label("last"),
        )
        .join(EpisodeRow, EpisodeRow.submission_id == Submission.id)
        .where(Submission.status.in_(ACTIVE_SUBMISSION), EpisodeRow.status.in_(("running", "done", "failed")))
        .group_by(Submission.participant_id)
        .subquery()
    )
    rows = session.execute(
        select(
            active.c.pid,
            Participant.is_builtin,
            func.coalesce(started.c.running, 0),
            started.c.last,
            active.c.first,
        )
        .join(Participant, Participant.id == active.c.pid)
        .outerjoin(started, started.c.pid == active.c.pid)
    ).all()
    return sorted((Load(pid, bool(b), int(n), last, first) for pid, b, n, last, first in rows), key=fair_key)


def fair_key(load: Load) -> tuple[Any, ...]:
    """Participants' work before the baselines' (built-in participants), then the participant with the fewest
    episodes running, then the one whose last episode started longest ago (one that never started first),
    then the one whose oldest active submission is oldest.

    So a participant's episodes get a free slot only while no participant with fewer running ones waits: one
    participant holds the whole pool only while nobody else has work, and loses it one slot per finished
    episode once someone does (the second participant starts within one episode-time). The last start breaks
    ties round-robin: a participant whose episodes all finished at once does not take every freed slot back
    ahead of one that is still waiting."""
    started = load.last_start is not None
    return (load.builtin, load.running, started, load.last_start if started else 0, load.first_submission)


def is_baseline(policy_url: str) -> bool:
    """A built-in policy's submission (``builtin:NAME``): the baselines the server queues itself."""
    return policy_url.startswith("builtin:")


def submission_order() -> tuple[Any, ...]:
    """The order of one participant's active submissions in the claim: oldest first, except that the built-in
    participant's submissions of a policy URL (the operator's own, submitted with the admin token) go before
    its baselines. The baselines a first start queues (thousands of episodes) then never bury the operator's
    check of a deployment; participants' work goes before both (:func:`fair_key`)."""
    return (Submission.policy_url.startswith("builtin:"), Submission.id)


def claim_episode(
    session: Session,
    worker: str,
    *,
    lease_s: float,
    max_attempts: int,
    now: datetime | None = None,
    episode_id: int | None = None,
    max_running_per_participant: int | None = None,
) -> Claim | None:
    """Lease the fairest runnable episode (pending, or running with an expired lease) to ``worker``: the
    oldest of the fairest participant that has one (:func:`fair_key`).

    ``episode_id`` is the episode a broker message was sent for (the Celery executor). The message is a
    ticket for one claim: it takes the fairest episode that has a message out (``enqueued_at`` set), which
    need not be its own — the queue is first come, first served, the claim is not, and every message still
    yields one claim, so none is lost. Only when no other such episode is free does it claim its own,
    waiting for the row (its sender may not have committed yet).
    ``max_running_per_participant`` bounds how many episodes of one participant's remote policies run at
    once (outbound calls to one participant's server), whatever the number of workers."""
    fixed_now = now
    now = now or utcnow()
    reap_expired(session, max_attempts, now)
    runnable = or_(EpisodeRow.status == "pending", and_(_expired(now), EpisodeRow.attempts < max_attempts))
    eligible = runnable
    if max_running_per_participant is not None:  # checked at select time: two racing claims may pass it both
        eligible = and_(
            runnable,
            or_(
                Submission.policy_url.startswith("builtin:"),
                Submission.participant_id.not_in(_busy_participants(max_running_per_participant)),
            ),
        )
    fair = eligible if episode_id is None else and_(eligible, EpisodeRow.enqueued_at.is_not(None))
    for load in participant_loads(session):
        # Submission by submission (oldest first; a participant has a few active ones, the built-in one its
        # operator's before the baselines: :func:`submission_order`), each through the (submission, status)
        # index: a backlog of others' pending episodes is never scanned.
        for submission_id in session.execute(
            select(Submission.id)
            .where(Submission.participant_id == load.participant_id, Submission.status.in_(ACTIVE_SUBMISSION))
            .order_by(*submission_order())
        ).scalars():
            claim = _claim_one(
                session,
                worker,
                and_(fair, EpisodeRow.submission_id == submission_id),
                runnable,
                skip_locked=True,
                lease_s=lease_s,
                now=fixed_now,
            )
            if claim is not None:
                return claim
    if episode_id is None:
        return None
    return _claim_one(
        session,
        worker,
        and_(eligible, EpisodeRow.id == episode_id),
        runnable,
        skip_locked=False,
        lease_s=lease_s,
        now=fixed_now,
    )


def _claim_one(
    session: Session,
    worker: str,
    where: Any,
    runnable: Any,
    *,
    skip_locked: bool,
    lease_s: float,
    now: datetime | None,
) -> Claim | None:
    for _ in range(
        5
    ):  # another claimer may win the row between select and update (SQLite has no SKIP LOCKED)
        row = session.execute(
            select(EpisodeRow.id)
            .join(Submission, Submission.id == EpisodeRow.submission_id)
            # the status list repeats what ``where`` implies, in a form the (submission, status) index serves
            .where(
                where, EpisodeRow.status.in_(("pending", "running")), Submission.status.in_(ACTIVE_SUBMISSION)
            )
            .order_by(EpisodeRow.id)
            .limit(1)
            # Any episode: skip rows another claimer holds. One named episode: wait for the row instead. Its
            # sender publishes inside the transaction that marks it sent, so a fast worker can get the
            # message before that commit; skipping the row then would turn the message into a no-op.
            .with_for_update(skip_locked=skip_locked, of=EpisodeRow)
        ).first()
        if row is None:
            return None
        taken_at = now or utcnow()  # after any wait for the row: the lease starts now, not before
        token = secrets.token_hex(16)
        claimed = session.execute(
            update(EpisodeRow)
            .where(EpisodeRow.id == row.id, runnable)
            .values(
                status="running",
                attempts=EpisodeRow.attempts + 1,
                worker=worker[:128],
                lease_token=token,
                lease_expires_at=taken_at + timedelta(seconds=lease_s),
                started_at=taken_at,
                step=0,
            )
            .execution_options(synchronize_session=False)
        )
        if _rowcount(claimed) == 1:
            ep = session.get(EpisodeRow, row.id, populate_existing=True)
            assert ep is not None
            sub = session.get(Submission, ep.submission_id)
            assert sub is not None
            if sub.status == "queued":
                sub.status = "running"
            return Claim(
                ep.id,
                token,
                ep.attempts,
                sub.id,
                ep.dataset,
                ep.setting,
                ep.split,
                ep.group,
                sub.policy_url,
                sub.secret,
                sub.pinned_ip,
                sub.lookahead,
                sub.track == "public",
                sub.mode,
                ep.protocol,
            )
    return None


def _rowcount(result: Result[Any]) -> int:
    """The rows an UPDATE matched (``Session.execute`` is typed as a plain ``Result``; an UPDATE's is a
    ``CursorResult``)."""
    return cast(CursorResult[Any], result).rowcount


def heartbeat(
    session: Session,
    episode_id: int,
    token: str,
    *,
    lease_s: float,
    step: int,
    boxes_total: int | None = None,
    now: datetime | None = None,
) -> bool:
    """Extend the lease and record progress: boxes handled so far and, when given, the episode's boxes (the
    queue's estimate reads both: robobpp.db.waiting). ``False``: the claim is gone (cancelled, taken over) —
    stop."""
    now = now or utcnow()
    progress: dict[str, Any] = (
        {"step": step} if boxes_total is None else {"step": step, "boxes_total": boxes_total}
    )
    result = session.execute(
        update(EpisodeRow)
        .where(EpisodeRow.id == episode_id, EpisodeRow.lease_token == token, EpisodeRow.status == "running")
        .values(lease_expires_at=now + timedelta(seconds=lease_s), **progress)
        .execution_options(synchronize_session=False)
    )
    return _rowcount(result) == 1


def episode_plan(session: Session, episode_id: int) -> dict[str, Any] | None:
    """A paper-protocol episode's plan (:func:`robobpp.replay.plan_of` of its Math Pack episode)."""
    return session.execute(select(EpisodeRow.plan).where(EpisodeRow.id == episode_id)).scalar_one_or_none()


def complete_episode(
    session: Session, episode_id: int, token: str, result: dict[str, Any], *, keep_trace: bool
) -> bool:
    """Record an episode's result under its claim. Returns ``False`` (and writes nothing) otherwise.

    ``result`` is the whole ``EpisodeResult.to_dict()``, steps included: the trace is stored only with
    ``keep_trace``, but a Math Pack episode's plan is handed to its paper-protocol replays on every track."""
    values: dict[str, Any] = {
        "status": "done",
        "finished_at": utcnow(),
        "lease_token": None,
        "termination": result["termination"],
        "termination_detail": result.get("termination_detail", "")[:4000],
        "boxes_total": result["boxes_total"],
        "boxes_placed": result["boxes_placed"],
        "physics_version": result.get("physics_version"),
        # the recording process is the worker that ran it: its installation and data produced the result
        "provenance": {
            **environment(),
            "math_rules": result.get("rules_version"),
            "sampler": result.get("sampler_version"),
            # recorded only when the episode played the first boxes of its group only (the demo's)
            **({"max_boxes": result["max_boxes"]} if result.get("max_boxes") else {}),
        },
        "step": len(result.get("steps", ())) or result["boxes_placed"],
        "metrics": result["metrics"],
        "counters": result["counters"],
        "trace": {
            "steps": result.get("steps", []),
            "final": result.get("final", []),
            "container": result.get("container"),
        }
        if keep_trace
        else None,
        "plan": None,  # a replay's input, spent
    }
    done = session.execute(
        update(EpisodeRow)
        .where(EpisodeRow.id == episode_id, EpisodeRow.lease_token == token, EpisodeRow.status == "running")
        .values(**values)
        .execution_options(synchronize_session=False)
    )
    if _rowcount(done) != 1:
        return False
    run_id = session.execute(select(EpisodeRow.run_id).where(EpisodeRow.id == episode_id)).scalar_one()
    finalize_run(session, run_id)
    _settle_replays(session, episode_id, plan=plan_of(result))
    return True


def release_episode(
    session: Session, episode_id: int, token: str, error: str, *, max_attempts: int, final: bool = False
) -> bool:
    """The worker could not run the episode (infrastructure error): retry it, or record it failed."""
    ep = session.execute(
        select(EpisodeRow)
        .where(EpisodeRow.id == episode_id, EpisodeRow.lease_token == token, EpisodeRow.status == "running")
        .with_for_update()
    ).scalar_one_or_none()
    if ep is None:
        return False
    ep.error = error[:4000]
    ep.lease_token = None
    if final or ep.attempts >= max_attempts:
        ep.status = "failed"
        ep.termination = "evaluation_error"
        ep.termination_detail = error[:4000]
        ep.finished_at = utcnow()
        session.flush()
        finalize_run(session, ep.run_id)
        _settle_replays(session, ep.id, failure=("evaluation_error", error))
    else:
        ep.status = "pending"
        ep.lease_expires_at = None
        ep.enqueued_at = None  # no message is out for it now: a dispatcher sends one
    return True


def release_dead_workers(session: Session, host_prefix: str, alive: set[int]) -> int:
    """After a restart: hand back the episodes held by this host's dead worker processes right away."""
    rows = session.execute(
        select(EpisodeRow).where(EpisodeRow.status == "running", EpisodeRow.worker.like(host_prefix + "%"))
    ).scalars()
    n = 0
    for ep in rows:
        try:
            pid = int((ep.worker or "").rsplit(":", 1)[1])
        except (IndexError, ValueError):
            continue
        if pid not in alive or pid == os.getpid():
            ep.status, ep.lease_token, ep.lease_expires_at = "pending", None, None
            n += 1
    return n


def finalize_run(session: Session, run_id: int) -> None:
    """Once every episode of the run is terminal, write its aggregate; then the submission's status."""
    run = session.execute(select(RunRow).where(RunRow.id == run_id).with_for_update()).scalar_one()
    if run.status in ("completed", "failed", "cancelled"):
        return
    counts = dict(
        session.execute(
            select(EpisodeRow.status, func.count())
            .where(EpisodeRow.run_id == run_id)
            .group_by(EpisodeRow.status)
        ).all()
    )
    if sum(counts.get(s, 0) for s in TERMINAL_EPISODE) < run.episodes_total:
        return
    now = utcnow()
    if counts.get("failed"):
        run.status = "failed"
    elif counts.get("cancelled"):
        run.status = "cancelled"
    else:
        rows = session.execute(
            select(
                EpisodeRow.metrics,
                EpisodeRow.counters,
                EpisodeRow.termination,
                EpisodeRow.boxes_placed,
                EpisodeRow.group,
                EpisodeRow.provenance,
                EpisodeRow.physics_version,
            ).where(EpisodeRow.run_id == run_id)
        ).all()
        # group order, not the order the episodes finished in: a float mean depends on its order, and two
        # runs of the same figures must give the same last bit (their min-max otherwise tells them apart)
        rows = sorted(rows, key=lambda r: r[4])
        run.metrics, run.extras = run_figures([r[:4] for r in rows], run.setting)
        run.extras["provenance"] = {
            **merge(p or {} for *_x, p, _v in rows),
            "physics": merged(v for *_x, v in rows),
            "protocol": run.protocol,
        }
        run.figures = group_figures(
            ({**(m or {}), **(c or {}), "group": g} for m, c, _t, _b, g, *_p in rows), run.setting
        )
        run.entry = part_of_run(run.figures, run.setting)  # what every board update reuses
        run.status = "completed"
    run.completed_at = now
    session.flush()
    _finalize_submission(session, run.submission_id, now)


def run_figures(rows: Any, setting: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """A run's raw metrics (docs/benchmark.md, "Metrics" aggregation) and its side figures."""
    merged = [{**(m or {}), **(c or {})} for m, c, _t, _b in rows]
    metrics = aggregate(merged, setting)
    terminations: dict[str, int] = {}
    for _m, _c, termination, _b in rows:
        terminations[termination] = terminations.get(termination, 0) + 1
    extras: dict[str, Any] = {
        "episodes": len(rows),
        "boxes_placed_mean": sum(b or 0 for *_x, b in rows) / len(rows) if rows else 0.0,
        "episodes_collapsed": terminations.get("collapse", 0),
        "terminations": terminations,
    }
    if setting == "execution":
        dt, traj = metrics.get("decision_time"), metrics.get("trajectory_length")
        extras["pph"] = 3600.0 / (dt + traj / 0.34 + 2.0) if dt is not None and traj is not None else None
    return metrics, extras


def _finalize_submission(session: Session, submission_id: int, now: datetime) -> None:
    sub = session.execute(
        select(Submission).where(Submission.id == submission_id).with_for_update()
    ).scalar_one()
    if sub.status not in ACTIVE_SUBMISSION:
        return
    statuses = (
        session.execute(select(RunRow.status).where(RunRow.submission_id == submission_id)).scalars().all()
    )
    if any(s not in ("completed", "failed", "cancelled") for s in statuses):
        return
    sub.status = "failed" if "failed" in statuses else "completed"
    if sub.status == "failed":
        sub.error = "some episodes could not be evaluated; see the episode list"
    else:
        failing = _policy_failed_runs(session, submission_id)
        if failing:
            sub.status = "failed"
            share = f"{100 * POLICY_FAILURE_SHARE:.0f} %"
            sub.error = f"more than {share} of the episodes ended in a policy failure on {', '.join(failing)}"
    sub.finished_at = now
    if sub.verifies_id is not None:  # a verification: its verdict goes onto the verified submission
        record_verdict(session, sub)


def _policy_failed_runs(session: Session, submission_id: int) -> list[str]:
    """The boards (``setting/dataset``) where the policy failed beyond the allowed share (never ranked)."""
    runs = session.execute(  # closed loop: a replay repeats its Math episode's policy failures
        select(RunRow.dataset, RunRow.setting, RunRow.extras).where(
            RunRow.submission_id == submission_id, RunRow.protocol == CLOSED
        )
    ).all()
    return [
        f"{setting}/{dataset}"
        for dataset, setting, extras in runs
        if extras and run_failed(extras.get("terminations"), int(extras.get("episodes") or 0))
    ]


def cancel_submission(session: Session, sub: Submission) -> bool:
    """Stop a submission: unfinished episodes become ``cancelled`` (running workers see it at their next
    heartbeat and stop). Returns ``False`` when it had already finished."""
    if sub.status not in ACTIVE_SUBMISSION:
        return False
    now = utcnow()
    session.execute(
        update(EpisodeRow)
        .where(EpisodeRow.submission_id == sub.id, EpisodeRow.status.in_(QUEUED_EPISODE))
        .values(status="cancelled", lease_token=None, finished_at=now)
        .execution_options(synchronize_session=False)
    )
    session.execute(
        update(RunRow)
        .where(RunRow.submission_id == sub.id, RunRow.status == "pending")
        .values(status="cancelled", completed_at=now)
        .execution_options(synchronize_session=False)
    )
    sub.status = "cancelled"
    sub.finished_at = now
    if sub.verifies_id is not None:
        original = session.get(Submission, sub.verifies_id)
        if original is not None and (original.verification or {}).get("submission_id") == sub.id:
            original.verification = {"status": "cancelled", "submission_id": sub.id}
    return True
