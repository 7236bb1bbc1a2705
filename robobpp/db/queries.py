"""Read queries shared by the JSON API and the HTML pages (``robobpp.server.pages``).

For page authors, the entry points are:

* :func:`board_rows` — the stored runs a board (dataset × setting × protocol) is composed from (the
  composition, scores and intervals, is ``robobpp.boards.engine``'s);
* :func:`submission_view` / :func:`submission_progress` — one submission with its runs and progress;
* :func:`episode_rows` / :func:`get_episode` — per-episode results (traces only on the public track);
* :func:`list_submission_keys` / :func:`submissions_by_id` — a page of submissions, newest first.

Each takes an open :class:`~sqlalchemy.orm.Session` (``with app.state.runtime.session() as s``) and
returns plain dicts ready for JSON or templates.
"""

from __future__ import annotations

import functools
import hashlib
import re
from collections.abc import Mapping, Sequence
from datetime import datetime, timedelta
from typing import Any, NamedTuple, TypedDict

from sqlalchemy import Select, and_, exists, func, or_, select
from sqlalchemy.orm import Session, joinedload

from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.db.models import ApiToken, EpisodeRow, Participant, RunRow, Submission, utcnow
from robobpp.provenance import merge, merged
from robobpp.scoring.scores import ANCHORS_VERSION
from robobpp.sim.math_pack import MATH_RULES_VERSION
from robobpp.sim.physics.config import PHYSICS_VERSION
from robobpp.vocabulary import (
    ACTIVE_SUBMISSION,
    CLOSED,
    PAPER,
    PHYSICAL,
    QUEUED_EPISODE,
    TRACKS,
    board_loop,
)

# The board modules' names of the vocabulary's orders (kept until their rewrite).


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


#: The most characters of policy-supplied text (termination details, errors) any page or API answer shows.
#: The full text (up to 4,000 characters) stays in the database for the operator.
SHOWN_TEXT_LIMIT = 500
#: C0/C1 control characters and the bidirectional overrides that could disguise text in a page or terminal.
_HIDDEN_CHARS = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def shown_text(text: str | None, limit: int = SHOWN_TEXT_LIMIT) -> str | None:
    """Policy-supplied text as pages and the API show it: one line, no control or direction-override
    characters, at most ``limit`` characters (cut with an ellipsis). HTML escaping is the template's job."""
    if text is None:
        return None
    flat = _HIDDEN_CHARS.sub(" ", text)
    return flat if len(flat) <= limit else flat[: limit - 1] + "…"


def active_token(session: Session, token: str) -> ApiToken | None:
    """The live (unrevoked) API token row of ``token``, or None."""
    return session.execute(
        select(ApiToken).where(ApiToken.token_hash == hash_token(token), ApiToken.revoked_at.is_(None))
    ).scalar_one_or_none()


def live_prefix_owner(session: Session, prefix: str) -> int | None:
    """The participant holding a live API token with this prefix (its first 10 characters), if any."""
    return session.execute(
        select(ApiToken.participant_id)
        .where(ApiToken.prefix == prefix, ApiToken.revoked_at.is_(None))
        .limit(1)
    ).scalar_one_or_none()


#: The episode statuses ``/metrics`` counts: the queue. Finished episodes are history (millions of rows);
#: counting them per scrape cost 0.6 s at 2.7 M rows, while the queue is read from ix_episodes_claim.
#: ``waiting``: paper-protocol replays whose Math Pack episode is still to come (docs/server.md).
QUEUE_STATUSES = QUEUED_EPISODE


def episode_status_counts(session: Session) -> dict[str, int]:
    """Episodes waiting or running (an index range scan: its cost follows the queue, not the history)."""
    counts: dict[str, int] = dict.fromkeys(QUEUE_STATUSES, 0)
    for status in QUEUE_STATUSES:  # one equality lookup each: both backends stay on the index
        counts[status] = int(
            session.execute(
                select(func.count()).select_from(EpisodeRow).where(EpisodeRow.status == status)
            ).scalar_one()
        )
    return counts


def submission_status_counts(session: Session, statuses: Sequence[str] | None = None) -> dict[str, int]:
    """Submissions by status: every status (a scan of the status index), or only ``statuses`` (one
    equality lookup each, whose cost follows their count: the active ones are few)."""
    if statuses is None:
        return dict(
            session.execute(select(Submission.status, func.count()).group_by(Submission.status)).all()
        )
    return {
        status: int(
            session.execute(
                select(func.count()).select_from(Submission).where(Submission.status == status)
            ).scalar_one()
        )
        for status in statuses
    }


def queue_snapshot(session: Session) -> tuple[dict[str, int], dict[str, int], tuple[Any, ...]]:
    """What a /metrics scrape reads, in one statement (one round trip): episodes by queue status, active
    submissions by status, and :func:`last_finished`. Each part is an index lookup whose cost follows the
    queue, not the history."""
    row = session.execute(_queue_statement()).one()
    q, a = len(QUEUE_STATUSES), len(ACTIVE_SUBMISSION)
    episodes: dict[str, int] = {s: int(n) for s, n in zip(QUEUE_STATUSES, row[:q], strict=True)}
    active: dict[str, int] = {s: int(n) for s, n in zip(ACTIVE_SUBMISSION, row[q : q + a], strict=True)}
    return episodes, active, tuple(row[q + a :])


@functools.cache
def _queue_statement() -> Select[Any]:
    """Built once: assembling its eight subqueries cost more CPU than running them."""
    parts = [
        select(func.count()).select_from(EpisodeRow).where(EpisodeRow.status == s).scalar_subquery()
        for s in QUEUE_STATUSES
    ]
    parts += [
        select(func.count()).select_from(Submission).where(Submission.status == s).scalar_subquery()
        for s in ACTIVE_SUBMISSION
    ]
    parts += [
        select(func.max(Submission.finished_at)).where(Submission.track == t).scalar_subquery()
        for t in TRACKS
    ]
    return select(*parts)


def last_finished(session: Session) -> tuple[Any, ...]:
    """The latest finish time on each track (ix_submissions_track_finished: one index lookup per track).
    Moves whenever a submission completes, fails or is cancelled: what finished counts are cached by."""
    return tuple(
        session.execute(
            select(func.max(Submission.finished_at)).where(Submission.track == track)
        ).scalar_one()
        for track in TRACKS
    )


def quota_usage(session: Session, participant_id: int, now: datetime | None = None) -> tuple[int, int]:
    """(submissions in the last 24 h, submissions queued or running) of one participant."""
    now = now or utcnow()
    day = session.execute(
        select(func.count())
        .select_from(Submission)
        .where(
            Submission.participant_id == participant_id,
            Submission.created_at > now - timedelta(days=1),
            Submission.track != "verify",
        )  # the operator's verifications use no quota
    ).scalar_one()
    active = session.execute(
        select(func.count())
        .select_from(Submission)
        .where(
            Submission.participant_id == participant_id,
            Submission.status.in_(ACTIVE_SUBMISSION),
            Submission.track != "verify",
        )
    ).scalar_one()
    return int(day), int(active)


def board_rows(
    session: Session, dataset: str, setting: str, track: str, protocol: str = CLOSED, lookahead: int = 0
) -> list[dict[str, Any]]:
    """Every completed run on the board of a finished submission (failed ones too: they are shown apart),
    with its per-group ``figures``; ``lookahead``: the board of submissions that saw that many next boxes."""
    return board_runs(
        session, track, boards=[(dataset, setting, protocol)], lookahead=lookahead, figures=True
    )


_BOARD_KEYS = (
    "submission_id",
    "metrics",
    "extras",
    "figures",
    "episodes_total",
    "completed_at",
    "name",
    "submission_status",
    "participant",
    "baseline",
    "verification",
    "dataset",
    "setting",
    "protocol",
    "lookahead",
)


def board_runs(
    session: Session,
    track: str,
    *,
    boards: Sequence[tuple[str, str, str]] | None = None,
    submission_ids: Sequence[int] | None = None,
    lookahead: int | None = None,
    figures: bool = False,
) -> list[dict[str, Any]]:
    """The completed runs shown on the track's boards (``boards``: only those (dataset, setting, protocol);
    ``submission_ids``: only theirs; ``lookahead``: only submissions that saw that many next boxes), by
    submission id, each with ``dataset``, ``setting``, ``protocol``, its submission's ``lookahead``, and its
    per-group ``figures`` or (``figures=False``) its stored scoring part ``entry`` (bytes or None)."""
    where = _board_where(track, boards)
    if submission_ids is not None:
        where.append(RunRow.submission_id.in_(list(submission_ids)))
    if lookahead is not None:  # boards never mix lookaheads (docs/benchmark.md, "Scoring")
        where.append(Submission.lookahead == lookahead)
    rows = (
        session.connection()
        .execute(
            select(
                RunRow.submission_id,
                RunRow.metrics,
                RunRow.extras,
                RunRow.figures if figures else RunRow.entry,
                RunRow.episodes_total,
                RunRow.completed_at,
                Submission.name,
                Submission.status,
                Participant.name,
                Participant.is_builtin,
                Submission.verification,
                RunRow.dataset,
                RunRow.setting,
                RunRow.protocol,
                Submission.lookahead,
            )
            .join(Submission, Submission.id == RunRow.submission_id)
            .join(Participant, Participant.id == Submission.participant_id)
            .where(*where)
            .order_by(RunRow.submission_id)
        )
        .all()
    )
    keys = _BOARD_KEYS if figures else tuple("entry" if k == "figures" else k for k in _BOARD_KEYS)
    out = []
    for r in rows:  # a board's start reads 10,000 a board: one dict each, set in place
        if current_rules(r[2]):
            run = dict(zip(keys, r, strict=True))
            run["baseline"], run["verification"] = bool(r[9]), board_verdict(r[10])
            out.append(run)
    return out


def _board_where(track: str, boards: Sequence[tuple[str, str, str]] | None) -> list[Any]:
    """What puts a run on the track's boards (``boards``: on one of those (dataset, setting, protocol))."""
    # A physical setting's board shows only runs whose every episode ran the current physics version.
    other_physics = exists().where(
        EpisodeRow.run_id == RunRow.id, EpisodeRow.physics_version.is_distinct_from(PHYSICS_VERSION)
    )
    where: list[Any] = [
        RunRow.status == "completed",
        Submission.track == track,
        Submission.status.in_(("completed", "failed")),
        or_(RunRow.setting.not_in(PHYSICAL), ~other_physics),
    ]
    if boards is not None:
        where.append(
            or_(
                *(
                    and_(
                        RunRow.dataset == d,
                        RunRow.setting == st,
                        RunRow.protocol == board_loop(st, p),
                    )
                    for d, st, p in boards
                )
            )
        )
    return where


def board_lookaheads(session: Session, track: str, boards: Sequence[tuple[str, str, str]]) -> list[int]:
    """The lookaheads K > 0 with a run on one of the track's ``boards`` (dataset, setting, protocol): each has
    boards of its own (lookahead 0, the leaderboard, always has them). Reads only the runs of submissions that
    saw next boxes (few), with what :func:`board_runs` checks."""
    rows = session.execute(
        select(Submission.lookahead, RunRow.extras)
        .join(Submission, Submission.id == RunRow.submission_id)
        .where(*_board_where(track, boards), Submission.lookahead > 0)
    ).all()
    return sorted({int(k) for k, extras in rows if current_rules(extras)})


def run_figures_of(
    session: Session, track: str, dataset: str, setting: str, protocol: str, submission_ids: Sequence[int]
) -> dict[int, Any]:
    """The per-group figures of some runs of a board, by submission id (for a run whose stored part is
    missing or of an older format)."""
    rows = session.execute(
        select(RunRow.submission_id, RunRow.figures)
        .join(Submission, Submission.id == RunRow.submission_id)
        .where(
            RunRow.dataset == dataset,
            RunRow.setting == setting,
            RunRow.protocol == board_loop(setting, protocol),
            Submission.track == track,
            RunRow.submission_id.in_(list(submission_ids)),
        )
    ).all()
    return dict(rows)


def run_entries_of(
    session: Session, track: str, dataset: str, setting: str, protocol: str, submission_ids: Sequence[int]
) -> dict[int, bytes | None]:
    """The stored scoring parts of some runs of a board, by submission id."""
    query = (
        select(RunRow.submission_id, RunRow.entry)
        .join(Submission, Submission.id == RunRow.submission_id)
        .where(
            RunRow.dataset == dataset,
            RunRow.setting == setting,
            RunRow.protocol == board_loop(setting, protocol),
            Submission.track == track,
        )
    )
    wanted = set(submission_ids)
    if len(wanted) <= 500:  # a few: by key; many (a renormalisation): the whole board in one pass
        query = query.where(RunRow.submission_id.in_(list(wanted)))
    return {sid: entry for sid, entry in session.execute(query) if sid in wanted}


def current_rules(extras: Mapping[str, Any] | None) -> bool:
    """Whether a run ran the current Math rules and sampler (a board never mixes versions). A run recorded
    before they were versioned has none: it ran version 1 of both. A version recorded as null: boxes not
    drawn by the sampler (a spec provider's), rules not applied."""
    recorded = (extras or {}).get("provenance") or {}
    rules, sampler = recorded.get("math_rules", "1"), recorded.get("sampler", "1")
    return rules in (None, MATH_RULES_VERSION) and sampler in (None, SAMPLER_VERSION)


def board_verdict(verification: dict[str, Any] | None) -> str | None:
    """What a board shows of a verification: its verdict, or ``pending`` while the hold-out re-run runs
    (nothing when the operator cancelled it)."""
    status = (verification or {}).get("status")
    if status == "running":
        return "pending"
    return status if status in ("verified", "disagrees", "unverifiable", "failed") else None


def submission_progress(session: Session, submission_id: int) -> dict[str, Any]:
    """Episodes by status and the current phase (the (dataset, setting) being evaluated; only looked up
    while episodes wait or run: a finished submission has none)."""
    return submissions_progress(session, [submission_id])[submission_id]


def waiting_counts(session: Session, keys: Sequence[Any]) -> dict[int, dict[str, int]]:
    """:func:`episode_counts` of the listed submissions not finished (``keys``: rows of
    :func:`list_submission_keys`). A queued one has had no episode claimed — the claim of its first episode
    makes it running, in the same transaction — so all its episodes are pending and it needs no count: a
    backlog of queued submissions costs nothing here however many episodes wait."""
    waiting = [k for k in keys if k.finished_at is None]
    counts = episode_counts(session, [k.id for k in waiting if k.status != "queued"])
    counts.update({k.id: {"pending": k.episodes_total} for k in waiting if k.status == "queued"})
    return counts


def episode_counts(session: Session, submission_ids: Sequence[int]) -> dict[int, dict[str, int]]:
    """Each submission's episodes by status, in one aggregate."""
    counts: dict[int, dict[str, int]] = {i: {} for i in submission_ids}
    if counts:
        for sid, status, n in session.execute(
            select(EpisodeRow.submission_id, EpisodeRow.status, func.count())
            .where(EpisodeRow.submission_id.in_(list(counts)))
            .group_by(EpisodeRow.submission_id, EpisodeRow.status)
        ):
            counts[sid][status] = n
    return counts


def submissions_progress(
    session: Session, submission_ids: Sequence[int], known: Mapping[int, dict[str, int]] | None = None
) -> dict[int, dict[str, Any]]:
    """:func:`submission_progress` of several submissions in two queries whatever their number: the
    episodes by status (those not already ``known``, from :func:`episode_counts`), and the phase of those
    still waiting or running (a page of 50 queued submissions once cost a phase lookup each, 50 round
    trips; BENCHMARKS.md)."""
    known = known or {}
    counts = episode_counts(session, [i for i in submission_ids if i not in known])
    counts.update({i: known[i] for i in submission_ids if i in known})
    phases: dict[int, str] = {}
    waiting = [sid for sid, c in counts.items() if c.get("running") or c.get("pending")]
    if waiting:
        # the phase is that of the first episode (creation order) still waiting or running
        first = (
            select(func.min(EpisodeRow.id).label("id"))
            .where(EpisodeRow.submission_id.in_(waiting), EpisodeRow.status.in_(("running", "pending")))
            .group_by(EpisodeRow.submission_id)
            .subquery()
        )
        for sid, dataset, setting, protocol in session.execute(
            select(
                EpisodeRow.submission_id, EpisodeRow.dataset, EpisodeRow.setting, EpisodeRow.protocol
            ).join(first, EpisodeRow.id == first.c.id)
        ):
            phases[sid] = f"{setting}/{dataset}" + (" (paper protocol)" if protocol != CLOSED else "")
    return {sid: _progress(c, phases.get(sid)) for sid, c in counts.items()}


def _progress(counts: dict[str, int], phase: str | None) -> dict[str, Any]:
    total = sum(counts.values())
    finished = counts.get("done", 0) + counts.get("failed", 0)
    return {
        "episodes_total": total,
        "episodes_done": finished,
        "episodes_running": counts.get("running", 0),
        # a paper-protocol replay waiting for its Math Pack episode is pending work like any other
        "episodes_pending": counts.get("pending", 0) + counts.get("waiting", 0),
        "episodes_failed": counts.get("failed", 0),
        "episodes_cancelled": counts.get("cancelled", 0),
        "phase": phase,
    }


def submission_view(
    session: Session,
    sub: Submission,
    progress: dict[str, Any] | None = None,
    runs: Sequence[RunRow] | None = None,
) -> dict[str, Any]:
    """``progress`` (its entry of :func:`submissions_progress`) and ``runs`` (of :func:`runs_of`) when
    already looked up for several submissions."""
    runs = sub.runs if runs is None else runs
    return {
        "id": sub.id,
        "name": sub.name,
        "participant": sub.participant.name,
        "baseline": sub.participant.is_builtin,
        "policy_url": sub.policy_url,
        "track": sub.track,
        "mode": sub.mode,
        "datasets": sub.datasets,
        "settings": sub.settings,
        "lookahead": sub.lookahead,
        "status": sub.status,
        "created_at": sub.created_at,
        "finished_at": sub.finished_at,
        "error": shown_text(sub.error),
        "progress": progress if progress is not None else submission_progress(session, sub.id),
        "runs": [
            {
                "dataset": r.dataset,
                "setting": r.setting,
                "protocol": r.protocol,
                "status": r.status,
                "episodes_total": r.episodes_total,
                "metrics": r.metrics,
                "extras": r.extras,
                "completed_at": r.completed_at,
            }
            for r in runs
        ],
        "verification": sub.verification,
        "provenance": submission_provenance(sub, runs),
    }


def submission_provenance(sub: Submission, runs: Sequence[RunRow]) -> dict[str, Any]:
    """What produced a submission's results (its completed runs' provenance, merged; docs/benchmark.md,
    "Provenance") and what it ran: protocol, lookahead (the next boxes its policy saw), split, seed (the public
    groups' 0; the test draw's is secret), groups."""
    from robobpp.db.work import SPLIT_OF_TRACK

    produced = merge((r.extras or {}).get("provenance") or {} for r in runs if r.status == "completed")
    return {
        **{
            k: v for k, v in produced.items() if k not in ("protocol", "lookahead", "split", "seed", "groups")
        },
        "anchors": ANCHORS_VERSION,
        "protocol": merged(r.protocol for r in runs) or CLOSED,
        "lookahead": sub.lookahead,
        "split": SPLIT_OF_TRACK.get(sub.track, sub.track),
        "seed": 0 if sub.track == "public" else None,
        "groups": max((r.episodes_total for r in runs), default=0),
    }


def runs_of(session: Session, submission_ids: Sequence[int]) -> dict[int, list[RunRow]]:
    """The runs of several submissions in one query (in id order, as ``Submission.runs``)."""
    out: dict[int, list[RunRow]] = {i: [] for i in submission_ids}
    if submission_ids:
        rows = session.execute(
            select(RunRow).where(RunRow.submission_id.in_(list(submission_ids))).order_by(RunRow.id)
        ).scalars()
        for run in rows:
            out[run.submission_id].append(run)
    return out


def participants_version(session: Session) -> tuple[Any, ...]:
    """Moves whenever :func:`participant_summaries` may change: a participant, token or submission is added
    or a token revoked (none is ever deleted). Four lookups of a maximum, three of them on primary keys."""
    return tuple(session.execute(_participants_version_statement()).one())


@functools.cache
def _participants_version_statement() -> Select[Any]:
    return select(
        select(func.max(Participant.id)).scalar_subquery(),
        select(func.max(Submission.id)).scalar_subquery(),
        select(func.max(ApiToken.id)).scalar_subquery(),
        select(func.max(ApiToken.revoked_at)).scalar_subquery(),
    )


class ParticipantSummary(NamedTuple):
    id: int
    name: str
    builtin: bool
    created_at: datetime
    tokens: int
    submissions: int


def participant_summaries(session: Session) -> list[ParticipantSummary]:
    """Every participant with its active tokens and submissions counted, in one statement (the operator
    page; reading participants as objects cost more CPU than the page's other work together)."""
    return [ParticipantSummary(*row) for row in session.execute(_participants_statement())]


@functools.cache
def _participants_statement() -> Select[int, str, bool, datetime, int, int]:  # a ParticipantSummary
    tokens = (
        select(ApiToken.participant_id, func.count().label("n"))
        .where(ApiToken.revoked_at.is_(None))
        .group_by(ApiToken.participant_id)
        .subquery()
    )
    subs = (
        select(Submission.participant_id, func.count().label("n"))
        .group_by(Submission.participant_id)
        .subquery()
    )
    return (
        select(
            Participant.id,
            Participant.name,
            Participant.is_builtin,
            Participant.created_at,
            func.coalesce(tokens.c.n, 0),
            func.coalesce(subs.c.n, 0),
        )
        .outerjoin(tokens, tokens.c.participant_id == Participant.id)
        .outerjoin(subs, subs.c.participant_id == Participant.id)
        .order_by(Participant.id)
    )


def list_submission_keys(
    session: Session, participant_id: int | None, *, limit: int = 50, offset: int = 0
) -> list[Any]:
    """A page of submissions (``participant_id``'s, or everyone's; newest first) as rows of ``id, status,
    finished_at, verification, episodes_total`` only: what tells whether a built form of each is still current
    (``server.services.submissions.stamp``, :func:`waiting_counts`)."""
    query = (
        select(
            Submission.id,
            Submission.status,
            Submission.finished_at,
            Submission.verification,
            Submission.episodes_total,
        )
        .order_by(Submission.id.desc())
        .limit(limit)
        .offset(offset)
    )
    if participant_id is not None:
        query = query.where(Submission.participant_id == participant_id)
    return list(session.execute(query).all())


def submissions_by_id(session: Session, ids: Sequence[int]) -> dict[int, Submission]:
    """Submissions with their participant, by id (one query)."""
    if not ids:
        return {}
    query = select(Submission).options(joinedload(Submission.participant)).where(Submission.id.in_(list(ids)))
    return {s.id: s for s in session.execute(query).scalars()}


class EpisodeSummary(TypedDict):
    """One episode as the API lists it and the pages show it (served as ``schemas.EpisodePublic``)."""

    id: int
    dataset: str
    setting: str
    protocol: str
    split: str
    group: int
    status: str
    attempts: int
    step: int
    termination: str | None
    termination_detail: str | None
    boxes_total: int | None
    boxes_placed: int | None
    metrics: dict[str, Any] | None
    counters: dict[str, Any] | None
    finished_at: datetime | None
    has_trace: bool


def episode_summary(ep: EpisodeRow) -> EpisodeSummary:
    return {
        "id": ep.id,
        "dataset": ep.dataset,
        "setting": ep.setting,
        "protocol": ep.protocol,
        "split": ep.split,
        "group": ep.group,
        "status": ep.status,
        "attempts": ep.attempts,
        "step": ep.step,
        "termination": ep.termination,
        "termination_detail": shown_text(ep.termination_detail),
        "boxes_total": ep.boxes_total,
        "boxes_placed": ep.boxes_placed,
        "metrics": ep.metrics,
        "counters": ep.counters,
        "finished_at": ep.finished_at,
        "has_trace": ep.trace is not None,
    }


def episode_rows(session: Session, submission_id: int) -> list[EpisodeSummary]:
    rows = session.execute(
        select(EpisodeRow).where(EpisodeRow.submission_id == submission_id).order_by(EpisodeRow.id)
    ).scalars()
    return [episode_summary(ep) for ep in rows]


def get_episode(session: Session, submission_id: int, episode_id: int) -> EpisodeRow | None:
    return session.execute(
        select(EpisodeRow).where(EpisodeRow.id == episode_id, EpisodeRow.submission_id == submission_id)
    ).scalar_one_or_none()


def baseline_runs(session: Session, track: str) -> list[dict[str, Any]]:
    """The built-in baselines' completed runs as the paper made its tables: Math Pack, and the physical
    settings under the paper protocol (current physics version only, as on a board), lookahead 0, of finished
    submissions, oldest first (a later run of the same policy and board replaces an earlier one for the caller)."""
    current = ~exists().where(
        EpisodeRow.run_id == RunRow.id, EpisodeRow.physics_version.is_distinct_from(PHYSICS_VERSION)
    )
    rows = session.execute(
        select(
            RunRow.submission_id,
            RunRow.dataset,
            RunRow.setting,
            RunRow.protocol,
            RunRow.metrics,
            RunRow.extras,
            Submission.policy_url,
        )
        .join(Submission, Submission.id == RunRow.submission_id)
        .join(Participant, Participant.id == Submission.participant_id)
        .where(
            Participant.is_builtin.is_(True),
            Submission.track == track,
            Submission.lookahead == 0,  # the paper's methods see one box at a time
            Submission.status.in_(("completed", "failed")),
            RunRow.status == "completed",
            or_(
                and_(RunRow.setting == "math", RunRow.protocol == CLOSED),
                and_(RunRow.setting.in_(PHYSICAL), RunRow.protocol == PAPER, current),
            ),
        )
        .order_by(RunRow.submission_id)
    ).all()
    keys = ("submission_id", "dataset", "setting", "protocol", "metrics", "extras", "policy_url")
    return [dict(zip(keys, r, strict=True)) for r in rows]
