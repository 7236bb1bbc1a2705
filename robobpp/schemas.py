"""The evaluation server's JSON API (``/api/v1``): request and response models.

They live on the SDK side of the package because both ends use them: the server's routes validate and
answer with them, and the SDK's API client (:mod:`robobpp.client.api`) parses every answer into them, so
the two cannot drift apart. Only pydantic is imported here. Requests forbid unknown fields and bound
every number and string.
"""

from __future__ import annotations

import math
import re
from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, model_validator

from robobpp.vocabulary import CLOSED, BoardTrack, DatasetName, EntryStatus, Loop, SettingName, UnrankedStatus

Name = Annotated[
    str,
    StringConstraints(
        strip_whitespace=True, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9 ._\-]*$"
    ),
]


def clean_name(raw: str, fallback: str = "policy") -> str:
    """``raw`` made a valid :data:`Name` (other characters become "-"; at most 64), else ``fallback``."""
    name = re.sub(r"[^A-Za-z0-9 ._-]+", "-", raw.strip())
    name = re.sub(r"^[^A-Za-z0-9]+", "", name)[:64].rstrip()
    return name or fallback


#: ``push``: the workers call the policy's URL. ``pull``: the participant's client connects out to the server
#: (``robobpp connect``), for policies behind NAT or a firewall; the workers drive it through that connection.
SubmissionMode = Literal["push", "pull"]
#: What a pull submission stores as its policy URL (it has none; the client connects to the server).
PULL_URL = "pull:"


#: The API field ``protocol`` is a :data:`robobpp.vocabulary.Loop` (its name on the wire since before the word).
LOOP_HELP = (
    "closed: closed loop, the policy asked at every step (the benchmark); paper: the paper's protocol, the "
    "submission's Math Pack actions replayed open loop (a Math Pack board is the same under both)"
)


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ParticipantCreate(Strict):
    name: Name


class ParticipantPublic(BaseModel):
    id: int
    name: str
    is_builtin: bool
    created_at: datetime


class TokenCreated(BaseModel):
    """The token is shown once; only its hash is stored. ``id`` names it for revocation."""

    participant: ParticipantPublic
    token: str
    prefix: str
    id: int


class TokenPublic(BaseModel):
    """A token as listings show it: never the token itself, only its first characters."""

    id: int
    participant_id: int
    prefix: str
    created_at: datetime
    revoked_at: datetime | None


class Me(BaseModel):
    admin: bool
    participant: ParticipantPublic | None
    quota: dict[str, int] | None = None


#: The most next boxes a submission's policy may be shown (each lookahead ranks on boards of its own).
MAX_SUBMISSION_LOOKAHEAD = 10


class SubmissionCreate(Strict):
    name: Name | None = Field(
        default=None,
        description="Name on the leaderboard; default: the policy's /info name and version (push mode)",
    )
    mode: SubmissionMode = Field(
        default="push",
        description="push: the workers call policy_url. pull: no URL; the policy connects out to this server "
        "(robobpp connect, WebSocket /api/v1/pull/connect?submission=ID) and is driven through that connection",
    )
    policy_url: Annotated[str, StringConstraints(min_length=1, max_length=2048)] | None = Field(
        default=None,
        description="Base URL of a policy server speaking robobpp/1 (http or https); required in push mode, "
        "absent in pull mode",
    )
    secret: Annotated[str, StringConstraints(min_length=8, max_length=256)] | None = Field(
        default=None, description="HMAC key the workers sign policy requests with (never shown again)"
    )
    datasets: list[DatasetName] | None = Field(default=None, min_length=1, max_length=3)
    settings: list[SettingName] | None = Field(default=None, min_length=1, max_length=3)
    track: BoardTrack = "private"
    lookahead: int = Field(default=0, ge=0, le=MAX_SUBMISSION_LOOKAHEAD)

    @model_validator(mode="after")
    def _url_matches_mode(self) -> SubmissionCreate:
        if self.mode == "push" and not self.policy_url:
            raise ValueError("policy_url is required in push mode (or use mode 'pull')")
        if self.mode == "pull" and self.policy_url:
            raise ValueError("a pull submission has no policy_url: the policy connects to the server")
        return self


class Progress(BaseModel):
    episodes_total: int
    episodes_done: int
    episodes_running: int
    episodes_pending: int
    episodes_failed: int
    episodes_cancelled: int
    phase: str | None


class RunPublic(BaseModel):
    dataset: str
    setting: str
    protocol: Loop = CLOSED
    status: str
    episodes_total: int
    metrics: dict[str, float | None] | None
    extras: dict[str, Any] | None
    completed_at: datetime | None


class QueuePlace(BaseModel):
    """Where a queued submission stands in the fair-share order (docs/server.md, "Where a queued submission
    stands")."""

    position: int | None = Field(
        description="1: its first episode is the next one claimed (None: beyond the replay limit)"
    )
    ahead: int | None = Field(
        description="episodes claimed before its first one, if nothing finished meanwhile"
    )
    running: int = Field(description="episodes running now, across all participants")
    estimated_start_s: float | None = Field(
        description="an estimate, not a promise: seconds until its first episode starts, from the running "
        "episodes' progress and the expected time of the episodes ahead (None: no episode time known yet)"
    )
    estimated_start: datetime | None = Field(description="the same estimate as a time")


def start_estimate_text(seconds: float) -> str:
    """An estimated start as the pages and ``submit --wait`` word it: rounded up, and said to be an estimate."""
    if seconds < 60:
        return f"estimated start in about {max(1, math.ceil(seconds))} s"
    if seconds < 3600:
        return f"estimated start in about {math.ceil(seconds / 60)} min"
    return f"estimated start in about {seconds / 3600:.1f} h"


class SubmissionPublic(BaseModel):
    id: int
    name: str
    participant: str
    baseline: bool
    policy_url: str
    mode: SubmissionMode = "push"
    track: str
    datasets: list[str]
    settings: list[str]
    lookahead: int = Field(
        description="Next boxes its policy saw at each step: it ranks on the boards of this lookahead only"
    )
    status: str
    created_at: datetime
    finished_at: datetime | None
    error: str | None
    progress: Progress
    runs: list[RunPublic]
    #: Re-evaluation on the hold-out draw (docs/server.md, threat model): ``status`` (running, verified,
    #: disagrees, unverifiable, failed, cancelled), the verification's ``submission_id``, and per board both
    #: intervals.
    verification: dict[str, Any] | None = None
    #: Only while queued, and only on the one-submission answers (``GET /submissions/{id}``, its page).
    queue: QueuePlace | None = None
    #: What produced its results and what it ran (docs/benchmark.md, "Provenance"): robobpp version and
    #: commit, datasets manifest sha256, physics, Math rules, sampler and anchors versions, protocol,
    #: lookahead, split, seed (null: the secret test draw), groups. A version that differs between episodes is a list.
    provenance: dict[str, Any] | None = None


class EpisodePublic(BaseModel):
    id: int
    dataset: str
    setting: str
    protocol: Loop = CLOSED
    split: str
    group: int
    status: str
    attempts: int
    step: int
    termination: str | None
    termination_detail: str | None
    boxes_total: int | None
    boxes_placed: int | None
    metrics: dict[str, float | None] | None
    counters: dict[str, int] | None
    finished_at: datetime | None
    has_trace: bool


class EpisodeDetail(EpisodePublic):
    trace: dict[str, Any] | None = None


class LeaderboardEntry(BaseModel):
    """A ranked entry. ``*_low``/``*_high``: bootstrap 95 % interval over groups; ``rank_low``–``rank_high``:
    the ranks it takes in 95 % of resamples (null in the all-entries view for an entry that arrived since the
    board's last full computation, docs/server.md). ``score`` is the paper's relative score (it ranks the
    board), ``stable`` the score against fixed anchors (it never moves when others arrive)."""

    rank: int
    rank_low: int | None = None
    rank_high: int | None = None
    score: float
    score_low: float
    score_high: float
    stable: float
    stable_low: float
    stable_high: float
    submission_id: int
    name: str
    participant: str
    baseline: bool
    best: bool = Field(description="Whether this is its participant's best entry on the board")
    entries_submitted: int = Field(
        1,
        description="How many entries its participant has on this board (ranked or not): a best of many "
        "runs of a stochastic policy is optimistic",
    )
    metrics: dict[str, float | None]
    intervals: dict[str, list[float] | None] = Field(description="Each metric's 95 % interval [low, high]")
    normalized: dict[str, float]
    extras: dict[str, Any]
    completed_at: datetime | None
    #: Verdict of the entry's re-evaluation on the hold-out draw: verified, disagrees, unverifiable, failed,
    #: or null.
    verification: str | None = None


class UnrankedEntry(BaseModel):
    """A failed or partial entry: shown apart, never ranked, never in a normalisation."""

    status: UnrankedStatus
    reason: str
    submission_id: int
    name: str
    participant: str
    baseline: bool
    entries_submitted: int = 1
    metrics: dict[str, float | None]
    extras: dict[str, Any]
    completed_at: datetime | None
    #: Verdict of the entry's re-evaluation on the hold-out draw: verified, disagrees, unverifiable, failed,
    #: or null.
    verification: str | None = None


#: The lookahead fields of a board and of the grid (docs/server.md, "Boards per lookahead").
LOOKAHEAD_HELP = (
    "The next boxes its entries' policies saw: 0, the leaderboard; a submission made with lookahead K > 0 "
    "ranks only on the boards of K (closed loop)"
)
LOOKAHEADS_HELP = "The lookaheads with boards on this track: 0 and each K > 0 some entry saw, ascending"


class Leaderboard(BaseModel):
    dataset: str
    setting: str
    track: str
    protocol: Loop = Field(CLOSED, description=LOOP_HELP)
    lookahead: int = Field(0, description=LOOKAHEAD_HELP)
    lookaheads: list[int] = Field(default_factory=lambda: [0], description=LOOKAHEADS_HELP)
    metrics: list[str]
    weights: dict[str, float]
    ranked_by: str = Field(description="Which score orders the board: relative (the paper's min–max)")
    anchors: str = Field(description="Version of the stable score's fixed anchors")
    groups: int
    resamples: int
    confidence: float
    view: Literal["best", "all"]
    total: int
    limit: int
    offset: int
    entries: list[LeaderboardEntry]
    unranked_total: int
    unranked: list[UnrankedEntry]
    column_tops: dict[str, list[float]] = Field(
        default_factory=dict,
        description="The view's best distinct values of each column (score, each metric), best first: what a "
        "page of it highlights (a page shows a slice of the view)",
    )


class GridCell(BaseModel):
    score: float
    score_low: float
    score_high: float
    rank: int
    rank_low: int | None = None
    rank_high: int | None = None
    stable: float
    stable_low: float
    stable_high: float
    pph: float | None = None


class GridRow(BaseModel):
    """A submission on the overall grid. The Mean (and its rank) exists only for ``ranked`` rows: those
    ranked on every board; ``partial`` and ``failed`` rows are listed apart."""

    submission_id: int
    name: str
    participant: str
    baseline: bool
    status: EntryStatus
    boards: int
    cells: dict[str, GridCell]
    unranked: dict[str, str] = Field(default_factory=dict, description="Boards where it is failed or partial")
    mean: float | None = None
    mean_low: float | None = None
    mean_high: float | None = None
    stable: float | None = None
    stable_low: float | None = None
    stable_high: float | None = None
    rank: int | None = None
    rank_low: int | None = None
    rank_high: int | None = None
    best: bool = False


class OverallGrid(BaseModel):
    datasets: list[str]
    settings: list[str]
    track: str
    protocol: Loop = Field(CLOSED, description=LOOP_HELP)
    lookahead: int = Field(0, description=LOOKAHEAD_HELP)
    lookaheads: list[int] = Field(default_factory=lambda: [0], description=LOOKAHEADS_HELP)
    boards: int
    ranked_by: str
    view: Literal["best", "all"]
    total: int
    limit: int
    offset: int
    rows: list[GridRow]
    apart_total: int
    apart: list[GridRow]
    column_tops: dict[str, list[float]] = Field(
        default_factory=dict,
        description="The view's best distinct scores of each board's column (``setting/dataset``), best "
        "first: what a page of it highlights",
    )


class ServiceInfo(BaseModel):
    datasets: list[str]
    settings: list[str]
    groups: int
    weights: dict[str, dict[str, float]]
    termination_reasons: dict[str, str]


class ReproductionRun(BaseModel):
    """A stored baseline run the Reproduction compares (Math Pack closed; Physics and Execution paper)."""

    setting: str
    dataset: str
    policy: str
    protocol: Loop
    submission_id: int
    groups: int


class ReproductionCell(BaseModel):
    setting: str
    dataset: str
    policy: str
    metric: str
    ours: float | None
    paper: float | None = Field(description="The paper's published figure (null: not tabulated)")
    diff: float | None = Field(description="ours − paper")
    table: str | None = Field(description="The paper table the figure is from (its LaTeX label)")
    paper_only: bool = Field(
        description="A method robobpp does not run: the paper's figure alone (ours null), compared with nothing"
    )


class ReproductionAgreement(BaseModel):
    setting: str
    dataset: str
    metric: str
    policies: list[str]
    spearman: float | None = Field(
        description="Spearman's rank correlation, ours vs the paper (null: under 3, or not ranked)"
    )
    mean_abs_diff: float | None
    ranked: bool = Field(
        description="False: the metric's ranking is not compared (Decision Time, PPH): no Spearman"
    )


class ReproductionExpectation(BaseModel):
    why: str = Field(description="Why our figures of the metric are expected to differ from the paper's")
    doc: str = Field(description="The experiment in the docs: a link relative to the repository root")
    ranked: bool


class ReproductionScore(BaseModel):
    """The paper's weighted min–max score over the compared methods of one (setting, dataset), twice."""

    setting: str
    dataset: str
    weights: dict[str, float] = Field(
        description="The setting's score weights without Decision Time (and PPH), renormalised to sum to 1"
    )
    policies: list[str]
    ours: list[float] = Field(description="The score from our figures, per policy")
    paper: list[float] = Field(
        description="The score from the paper's figures of the same methods, per policy"
    )
    spearman: float | None


class Reproduction(BaseModel):
    """The paper's baselines under the paper protocol (stored runs of this server) beside the paper's tables."""

    track: str
    protocol: Loop
    paper: str
    tables: dict[str, str] = Field(description="The paper's table labels and captions")
    runs: list[ReproductionRun]
    cells: list[ReproductionCell]
    agreement: list[ReproductionAgreement]
    expected: dict[str, ReproductionExpectation] = Field(
        description="Per metric: why a difference is expected"
    )
    scores: list[ReproductionScore]
