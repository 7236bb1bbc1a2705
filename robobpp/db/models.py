"""SQLAlchemy 2.0 models. SQL is the record of truth for every submission and episode.

Work unit: one :class:`EpisodeRow` (submission × dataset × setting × group). A :class:`RunRow` holds the
aggregated raw metrics of one submission on one (dataset, setting) leaderboard, written once, when its
last episode completes; scores are never stored (they are relative, computed on read).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship
from sqlalchemy.types import TypeDecorator

from robobpp.vocabulary import CLOSED


def utcnow() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC timestamps on every backend (SQLite forgets the zone otherwise)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        return value.astimezone(UTC)

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        return value


class Base(DeclarativeBase):
    type_annotation_map = {datetime: UTCDateTime(), dict[str, Any]: JSON(), list[Any]: JSON()}


# Statuses, tracks and a run's and an episode's ``protocol`` (its loop) are the strings of robobpp.vocabulary,
# so reports and SQL read alike. ``protocol`` is a :data:`robobpp.vocabulary.Loop`: ``closed``, the policy asked
# at every step and seeing this setting's real pile (the benchmark), or ``paper``, the submission's Math Pack
# actions and decision times replayed open loop in a physical setting (no policy call); the column keeps the
# name it was created with (migration 0007).


class Participant(Base):
    __tablename__ = "participants"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    #: Built-in participants own the baselines; their policies run in-process.
    is_builtin: Mapped[bool] = mapped_column(default=False)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    tokens: Mapped[list[ApiToken]] = relationship(back_populates="participant", cascade="all, delete-orphan")


class ApiToken(Base):
    """Only the SHA-256 of a token is stored; the token itself is shown once, at creation."""

    __tablename__ = "api_tokens"

    id: Mapped[int] = mapped_column(primary_key=True)
    participant_id: Mapped[int] = mapped_column(ForeignKey("participants.id", ondelete="CASCADE"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    #: First characters of the token, to tell tokens apart in listings without revealing them.
    prefix: Mapped[str] = mapped_column(String(12))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(default=None)

    participant: Mapped[Participant] = relationship(back_populates="tokens")


class WebSession(Base):
    """A signed-in browser (migration 0009): its cookie names this row, so signing out — or revoking the
    token it signed in with — ends it on the server, whatever copies of the cookie exist."""

    __tablename__ = "web_sessions"

    id: Mapped[int] = mapped_column(primary_key=True)
    #: The participant's token it signed in with (``None``: the operator, signed in with the admin token).
    token_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_tokens.id", ondelete="CASCADE"), index=True, default=None
    )
    admin: Mapped[bool] = mapped_column(default=False)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(default=None)


class Submission(Base):
    __tablename__ = "submissions"

    id: Mapped[int] = mapped_column(primary_key=True)
    participant_id: Mapped[int] = mapped_column(ForeignKey("participants.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(80))
    policy_url: Mapped[str] = mapped_column(String(2048))
    #: HMAC key the workers sign policy requests with. Needed in clear to sign; never served or logged.
    secret: Mapped[str | None] = mapped_column(String(256), default=None)
    #: The address the host resolved to when the submission was checked (resolve once, then pin).
    pinned_ip: Mapped[str | None] = mapped_column(String(64), default=None)
    #: ``private`` (the leaderboard, test split), ``public`` (train split, traces kept) or ``verify`` (the
    #: held-out draw of the private pool; never on a board).
    track: Mapped[str] = mapped_column(String(16), default="private")
    #: ``push``: workers call ``policy_url``; ``pull``: the participant's client connects out to the server
    #: (``robobpp connect``) and workers drive episodes through that connection (``policy_url`` is unused).
    mode: Mapped[str] = mapped_column(String(8), default="push", server_default="push")
    datasets: Mapped[list[Any]] = mapped_column()
    settings: Mapped[list[Any]] = mapped_column()
    lookahead: Mapped[int] = mapped_column(default=0)
    status: Mapped[str] = mapped_column(String(16), default="queued", index=True)
    episodes_total: Mapped[int] = mapped_column(default=0)
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    #: A verification run (track ``verify``) names the submission it re-evaluates on never-played groups.
    verifies_id: Mapped[int | None] = mapped_column(Integer, default=None, index=True)
    #: On the verified submission: the verdict of its latest verification (docs/server.md, threat model).
    verification: Mapped[dict[str, Any] | None] = mapped_column(default=None)

    #: The board version check (``boards.store.board_version``) aggregates finished submissions per track.
    __table_args__ = (Index("ix_submissions_track_finished", "track", "finished_at"),)

    participant: Mapped[Participant] = relationship()
    runs: Mapped[list[RunRow]] = relationship(
        back_populates="submission", cascade="all, delete-orphan", order_by="RunRow.id"
    )


class RunRow(Base):
    """One submission on one leaderboard (dataset × setting): progress and aggregated raw metrics."""

    __tablename__ = "runs"
    __table_args__ = (
        UniqueConstraint("submission_id", "dataset", "setting", "protocol", name="uq_run"),
        Index("ix_runs_board", "dataset", "setting", "protocol", "status"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    submission_id: Mapped[int] = mapped_column(ForeignKey("submissions.id", ondelete="CASCADE"), index=True)
    dataset: Mapped[str] = mapped_column(String(32))
    setting: Mapped[str] = mapped_column(String(16))
    #: A :data:`robobpp.vocabulary.Loop` (0007; rows stored before are ``closed``).
    protocol: Mapped[str] = mapped_column(String(8), default=CLOSED, server_default=CLOSED)
    status: Mapped[str] = mapped_column(String(16), default="pending")
    episodes_total: Mapped[int] = mapped_column(default=0)
    metrics: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    #: Pooled counters and side figures (boxes placed, episodes ended by collapse, PPH).
    extras: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    #: Per-group figures (``robobpp.scoring.stats.group_figures``), written with the aggregate: what the board's
    #: bootstrap intervals resample, so a board never reads episode rows.
    figures: Mapped[dict[str, Any] | None] = mapped_column(default=None, deferred=True)
    #: The run's own part of the board scoring (``robobpp.scoring.entries.EntryPart.encode``: figures as a
    #: matrix, metric and stable intervals), computed once with the aggregate (0010).
    entry: Mapped[bytes | None] = mapped_column(LargeBinary, default=None, deferred=True)
    completed_at: Mapped[datetime | None] = mapped_column(default=None)

    submission: Mapped[Submission] = relationship(back_populates="runs")


class EpisodeRow(Base):
    """One unit of work. ``lease_token`` makes completion idempotent: only the current claim may write."""

    __tablename__ = "episodes"
    __table_args__ = (
        UniqueConstraint("submission_id", "dataset", "setting", "group", "protocol", name="uq_episode"),
        Index("ix_episodes_claim", "status", "lease_expires_at"),
        # a page's progress (episodes by status of 50 submissions) counted from the index alone (0006)
        Index("ix_episodes_submission_status", "submission_id", "status"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    submission_id: Mapped[int] = mapped_column(ForeignKey("submissions.id", ondelete="CASCADE"))
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    dataset: Mapped[str] = mapped_column(String(32))
    setting: Mapped[str] = mapped_column(String(16))
    split: Mapped[str] = mapped_column(String(16))
    group: Mapped[int] = mapped_column(Integer)
    #: A :data:`robobpp.vocabulary.Loop` (0007; rows stored before are ``closed``).
    protocol: Mapped[str] = mapped_column(String(8), default=CLOSED, server_default=CLOSED)
    status: Mapped[str] = mapped_column(String(16), default="pending")
    attempts: Mapped[int] = mapped_column(default=0)
    worker: Mapped[str | None] = mapped_column(String(128), default=None)
    lease_token: Mapped[str | None] = mapped_column(String(64), default=None)
    lease_expires_at: Mapped[datetime | None] = mapped_column(default=None)
    #: When a broker message was last sent for this pending episode (Celery executor): a restarted server
    #: sends nothing that is already queued. Cleared when the episode goes back to pending without one.
    enqueued_at: Mapped[datetime | None] = mapped_column(default=None)
    started_at: Mapped[datetime | None] = mapped_column(default=None)
    finished_at: Mapped[datetime | None] = mapped_column(default=None)
    #: Boxes handled so far in the current attempt (progress display).
    step: Mapped[int] = mapped_column(default=0)
    termination: Mapped[str | None] = mapped_column(String(64), default=None)
    termination_detail: Mapped[str | None] = mapped_column(Text, default=None)
    boxes_total: Mapped[int | None] = mapped_column(default=None)
    boxes_placed: Mapped[int | None] = mapped_column(default=None)
    #: ``EpisodeResult.physics_version`` (None: Math Pack); a board shows only the current version's runs.
    physics_version: Mapped[str | None] = mapped_column(String(32), default=None)
    #: What produced the result (``robobpp.provenance``): robobpp version and commit, datasets manifest sha256,
    #: Math rules and sampler versions (None: recorded before 0008, version 1 of both). Merged per run into
    #: ``RunRow.extras["provenance"]``; a board shows only the current Math rules and sampler versions.
    provenance: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    metrics: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    counters: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    #: Per-step trace; kept for the public track only (private episodes have no replay).
    trace: Mapped[dict[str, Any] | None] = mapped_column(default=None)
    #: A paper-protocol episode's input: its Math Pack episode's actions and decision times
    #: (``robobpp.worker.paper.plan_of``), written when that episode is recorded, cleared when the replay is.
    #: Every track has one (a private episode keeps no trace); never served.
    plan: Mapped[dict[str, Any] | None] = mapped_column(default=None, deferred=True)
    error: Mapped[str | None] = mapped_column(Text, default=None)


class BoardPublication(Base):
    """A track's published boards (boards/store.py): which version of each board readers serve, and the
    lease of the one board worker that computes the next (docs/server.md, "How boards are published")."""

    __tablename__ = "board_publications"

    track: Mapped[str] = mapped_column(String(16), primary_key=True)
    #: Bumped on every publication; readers key what they cache by it.
    version: Mapped[int] = mapped_column(default=0)
    #: ``boards.store.board_source`` when they were computed (the data's version and the code's); None asks
    #: the board worker to recompute (``robobpp db refresh-boards``).
    source: Mapped[list[Any] | None] = mapped_column(default=None)
    #: Board key (``repetitive/math/closed``, ``grid/closed``; a lookahead K > 0's end in ``/lookahead-K``) ->
    #: [its parts' version, digest of its parts].
    boards: Mapped[dict[str, Any]] = mapped_column(default=dict)
    #: Wall time of the last publication (computation and writing).
    seconds: Mapped[float] = mapped_column(Float, default=0.0)
    published_at: Mapped[datetime | None] = mapped_column(default=None)
    #: The board worker computing this track's next version, and until when its claim holds.
    holder: Mapped[str | None] = mapped_column(String(64), default=None)
    lease_until: Mapped[datetime | None] = mapped_column(default=None)


class BoardPart(Base):
    """One pre-serialised part of a published board: its head, a chunk of a view's entries, or its
    submission index. Read by (track, board, version, part), never scanned."""

    __tablename__ = "board_parts"

    id: Mapped[int] = mapped_column(primary_key=True)
    track: Mapped[str] = mapped_column(String(16))
    board: Mapped[str] = mapped_column(String(64))
    version: Mapped[int] = mapped_column()
    part: Mapped[str] = mapped_column(String(32))
    body: Mapped[bytes] = mapped_column(LargeBinary)

    #: Part first: a publication deletes an entry row's older versions by part (migration 0012).
    __table_args__ = (UniqueConstraint("track", "board", "part", "version", name="uq_board_parts_key"),)
