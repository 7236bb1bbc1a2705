"""First start: schema, the built-in participant, the private split and the baseline submissions.

Idempotent: every step checks before it writes, so each start of the server runs it.
"""

from __future__ import annotations

import logging
import secrets
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from robobpp.db import queries, work
from robobpp.db.migrate import upgrade
from robobpp.db.models import EpisodeRow, Participant, RunRow, Submission
from robobpp.policies import BASELINES, LEARNED, TITLES
from robobpp.replay import paper_settings
from robobpp.sim.physics.config import PHYSICS_VERSION
from robobpp.vocabulary import BOARD_TRACKS, CLOSED, PAPER, PHYSICAL

log = logging.getLogger("robobpp.server")

#: The participant that owns the baselines; its policies (``builtin:NAME``) run inside the workers.
BUILTIN_PARTICIPANT = "baselines"


def ensure_private_split(settings: Any) -> bool:
    """Build the private split with a random secret seed if it is absent, and again (fresh seed) for each
    dataset drawn by another sampler version: version 1's Repetitive groups can be looked up in the public
    data, so an upgraded server must not keep serving them. ``False`` if impossible."""
    if settings.spec_provider:
        return True
    from robobpp import datasets

    build = getattr(datasets, "build_private", None)
    if build is None:
        log.warning("robobpp.datasets.build_private is not available; the private track cannot run")
        return False
    from robobpp.datasets.private import HOLDOUT_DIR, stale_datasets
    from robobpp.datasets.sampling import SAMPLER_VERSION

    # The split every submission plays, and the hold-out draw that only verifications play (own seed).
    for root in (settings.private_dir, settings.private_dir / HOLDOUT_DIR):
        stale = stale_datasets(root, list(settings.datasets))
        if not stale:
            continue
        why = (
            "first start"
            if not (root / "manifest.json").is_file()
            else f"absent, or not drawn by sampler {SAMPLER_VERSION}"
        )
        log.warning("building the private split of %s in %s with a fresh secret seed (%s)", stale, root, why)
        build(root, seed=secrets.randbits(63), groups=settings.groups, datasets=stale)
    return True


def ensure_baselines(
    session: Session,
    settings: Any,
    stale: dict[str, list[str]] | None = None,
    queued: list[int] | None = None,
) -> int:
    """One current submission per built-in baseline on every offered (dataset, setting) of both tracks: the
    public track carries the baselines too, so a debug run there is compared with something.

    A baseline is queued again when its latest evaluation no longer fits the boards (:func:`stale_reason`): a
    deployment upgraded across a physics version, or one that now offers more datasets or settings, or the
    paper protocol, shows its baselines on every board again without the operator re-submitting them. The
    older submission stays (its history); boards rank each baseline by its best current entry.

    ``stale`` (if given) gets the baselines queued again by reason, ``queued`` the sizes (episodes) of the
    submissions created."""
    participant = session.execute(
        select(Participant).where(Participant.name == BUILTIN_PARTICIPANT)
    ).scalar_one()
    created = 0
    names = (*BASELINES, *LEARNED) if settings.baselines is None else settings.baselines
    for track in BOARD_TRACKS if settings.public_baselines else ("private",):
        latest: dict[str, Submission] = {}
        for sub in session.execute(
            select(Submission)
            .where(Submission.participant_id == participant.id, Submission.track == track)
            .order_by(Submission.id)
        ).scalars():
            latest[sub.policy_url] = sub
        for name in names:
            url = f"builtin:{name}"
            if url in latest:
                reason = stale_reason(session, latest[url], settings)
                if reason is None:
                    continue
                log.warning("baseline %s (%s track) queued again: %s", name, track, reason)
                if stale is not None:
                    stale.setdefault(reason, []).append(f"{TITLES.get(name, name)} ({track})")
            sub = work.create_submission(
                session,
                participant,
                name=TITLES.get(name, name),
                policy_url=url,
                datasets=list(settings.datasets),
                settings=list(settings.enabled_settings),
                groups=settings.groups,
                track=track,
            )
            if queued is not None:
                queued.append(sub.episodes_total)
            created += 1
    return created


def stale_reason(session: Session, sub: Submission, settings: Any) -> str | None:
    """Why a baseline's completed evaluation no longer fits the boards, or None (also while it is still
    running, or when it failed: a failure is the operator's to look at, not to repeat at every start)."""
    if sub.status != "completed":
        return None
    reasons = []
    runs = session.execute(
        select(RunRow.episodes_total, RunRow.extras).where(
            RunRow.submission_id == sub.id, RunRow.protocol == CLOSED
        )
    ).all()
    played = min((int(n or 0) for n, _e in runs), default=settings.groups)
    if played < settings.groups:  # every board would list it as partial
        reasons.append(f"it ran {played} group(s) per board, the boards have {settings.groups}")
    # the demo's episodes play the first boxes of each group only (a list: runs of several caps)
    capped = {str(((extras or {}).get("provenance") or {}).get("max_boxes")) for _n, extras in runs}
    if capped != {str(settings.max_boxes or None)}:
        had = "every box" if capped == {"None"} else "the first " + " or ".join(sorted(capped - {"None"}))
        wanted = f"the first {settings.max_boxes}" if settings.max_boxes else "every box"
        reasons.append(f"its episodes played {had} of each group, the boards play {wanted}")
    missing = sorted(set(settings.datasets) - set(sub.datasets)) + sorted(
        set(settings.enabled_settings) - set(sub.settings)
    )
    if missing:
        reasons.append(f"it was not evaluated on {', '.join(missing)}")
    if reasons:
        return "; ".join(reasons)
    protocols = set(session.execute(select(RunRow.protocol).where(RunRow.submission_id == sub.id)).scalars())
    if paper_settings(list(sub.settings), sub.track) and PAPER not in protocols:
        return "it has no paper-protocol runs (evaluated before the server computed them)"
    old = session.execute(
        select(EpisodeRow.physics_version)
        .where(
            EpisodeRow.submission_id == sub.id,
            EpisodeRow.setting.in_(PHYSICAL),
            EpisodeRow.status == "done",
            EpisodeRow.physics_version.is_distinct_from(PHYSICS_VERSION),
        )
        .limit(1)
    ).first()
    if old is not None:
        return f"its physical episodes ran physics version {old[0] or 'unversioned'}, not {PHYSICS_VERSION}"
    # A board leaves out a run of other Math rules or another sampler version (runs recorded before either was
    # versioned carry no provenance: not queued again here).
    for extras in session.execute(select(RunRow.extras).where(RunRow.submission_id == sub.id)).scalars():
        if (extras or {}).get("provenance") is not None and not queries.current_rules(extras):
            return "its runs used another sampler version or other Math rules than the boards show"
    return None


def bootstrap(runtime: Any) -> None:
    settings = runtime.settings
    upgrade(settings.sqlalchemy_url, engine=runtime.engine)
    with runtime.session() as session:
        if (
            session.execute(select(Participant.id).where(Participant.name == BUILTIN_PARTICIPANT)).first()
            is None
        ):
            session.add(Participant(name=BUILTIN_PARTICIPANT, is_builtin=True))
            session.flush()
    _ = settings.effective_admin_token  # dev: generate and store it now, so the operator can read it
    try:
        ensure_private_split(settings)
    except Exception:
        log.exception("could not build the private split; private evaluations will fail until it exists")
    if settings.evaluate_baselines:
        stale: dict[str, list[str]] = {}
        queued: list[int] = []
        with runtime.session() as session:
            n = ensure_baselines(session, settings, stale, queued)
        for reason, which in stale.items():
            log.warning(
                "%d baseline entr%s no longer fit this server's settings (%s): %s; queued again for the "
                "current settings (until they finish, the boards list the old entries apart or leave them out)",
                len(which),
                "y" if len(which) == 1 else "ies",
                reason,
                ", ".join(which),
            )
        if n:
            log.warning(
                "queued %d baseline submission(s), %d episodes, behind any participant's or operator's own "
                "submission; the log reports the backlog and its expected end every minute",
                n,
                sum(queued),
            )
