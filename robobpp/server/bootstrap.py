"""First start: schema, the built-in participant, the private split and the baseline submissions.

Idempotent: every step checks before it writes, so each start of the server runs it.
"""

from __future__ import annotations

import logging
import secrets
from typing import Any

from sqlalchemy import select

from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import Participant, Submission
from robobpp.policies import BASELINES, LEARNED, TITLES

log = logging.getLogger("robobpp.server")

#: The participant that owns the baselines; its policies (``builtin:NAME``) run inside the workers.
BUILTIN_PARTICIPANT = "baselines"


def ensure_private_split(settings: Any) -> bool:
    """Build the private split with a random secret seed if it is absent. ``False`` if impossible."""
    if settings.spec_provider:
        return True
    from robobpp import datasets

    build = getattr(datasets, "build_private", None)
    if build is None:
        log.warning("robobpp.datasets.build_private is not available; the private track cannot run")
        return False
    from robobpp.datasets.private import HOLDOUT_DIR

    # The split every submission plays, and the hold-out draw that only verifications play (own seed).
    for root in (settings.private_dir, settings.private_dir / HOLDOUT_DIR):
        if (root / "manifest.json").is_file():
            continue
        log.warning("building the private split in %s with a fresh secret seed (first start)", root)
        build(root, seed=secrets.randbits(63), groups=settings.groups, datasets=list(settings.datasets))
    return True


def ensure_baselines(session: Any, settings: Any) -> int:
    """One submission per built-in baseline on every offered (dataset, setting) of both tracks, once: the
    public track carries the baselines too, so a debug run there is compared with something."""
    participant = session.execute(
        select(Participant).where(Participant.name == BUILTIN_PARTICIPANT)
    ).scalar_one()
    created = 0
    names = (*BASELINES, *LEARNED) if settings.baselines is None else settings.baselines
    for track in ("private", "public") if settings.public_baselines else ("private",):
        existing = set(
            session.execute(
                select(Submission.policy_url).where(
                    Submission.participant_id == participant.id, Submission.track == track
                )
            ).scalars()
        )
        for name in names:
            url = f"builtin:{name}"
            if url in existing:
                continue
            work.create_submission(
                session,
                participant,
                name=TITLES.get(name, name),
                policy_url=url,
                datasets=list(settings.datasets),
                settings=list(settings.enabled_settings),
                groups=settings.groups,
                track=track,
            )
            created += 1
    return created


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
    except Exception:  # noqa: BLE001 - the API must still come up (e.g. no network for the data)
        log.exception("could not build the private split; private evaluations will fail until it exists")
    if settings.evaluate_baselines:
        with runtime.session() as session:
            n = ensure_baselines(session, settings)
        if n:
            log.warning("queued %d baseline submission(s)", n)
