"""A typed client for the evaluation server's JSON API (``/api/v1``).

Participants submit a policy URL, follow the evaluation and read the leaderboards with it instead of
curl; ``robobpp submit`` and ``robobpp submissions`` are thin layers over it. Answers are parsed into
the server's own pydantic models (``robobpp.schemas``, which import nothing but pydantic),
so the client and the server cannot drift apart silently. Every failure — an RFC 9457 problem, a
server that is not there, an answer that is not the API's — becomes one :class:`ServerError` whose
text is a single plain line fit to show a person.
"""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar
from urllib.parse import urlsplit

import httpx
from pydantic import BaseModel, TypeAdapter, ValidationError

from robobpp.schemas import (
    EpisodeDetail,
    EpisodePublic,
    Leaderboard,
    LeaderboardEntry,
    Me,
    OverallGrid,
    ServiceInfo,
    SubmissionPublic,
    TokenCreated,
    TokenPublic,
    clean_name,
)
from robobpp.vocabulary import CLOSED, BoardTrack, has_boards

API_PREFIX = "/api/v1"
DEFAULT_SERVER = "http://127.0.0.1:8000"
#: Submission statuses after which nothing changes any more.
FINISHED = frozenset({"completed", "failed", "cancelled"})
M = TypeVar("M")


class ServerError(Exception):
    """The server refused, failed, or could not be reached.

    ``status`` is the HTTP status (``None`` when no answer came back), ``title`` and ``detail`` the
    problem document's words, ``kind`` its type's last segment (``not-found``, ``quota-exceeded``…) for
    programs to branch on, ``errors`` the field errors of a validation problem.
    """

    def __init__(
        self,
        status: int | None,
        title: str,
        detail: str = "",
        *,
        kind: str | None = None,
        errors: list[dict[str, Any]] | None = None,
    ) -> None:
        self.status = status
        self.title = title
        self.detail = detail
        self.kind = kind
        self.errors = errors or []
        super().__init__(str(self))

    def __str__(self) -> str:
        words = f"{self.title}: {self.detail}" if self.detail and self.detail != self.title else self.title
        return f"{self.status}: {words}" if self.status is not None else words


@dataclass(frozen=True, slots=True)
class Standing:
    """Where one run of a submission stands on its board (dataset × setting × track)."""

    dataset: str
    setting: str
    status: str
    metrics: dict[str, float | None]
    metric_keys: list[str]
    rank: int | None
    score: float | None
    entries: int
    #: ``ranked``, ``failed`` or ``partial`` once the board includes the run; None while it does not (yet):
    #: boards are recomputed in the background, a moment after a submission finishes.
    board_status: str | None = None
    #: ``closed`` or ``paper`` (a physical setting's Math Pack actions replayed; docs/server.md).
    protocol: str = CLOSED
    #: The score against fixed anchors (never moves when others arrive; None while not ranked): alone on a
    #: board, the relative ``score`` is 0 by construction, and this is the figure that says how well it did.
    stable: float | None = None
    #: The board's own 95 % intervals of the entry (a bootstrap over the board's groups; None while not
    #: ranked): of the relative and the stable score, and the rank interval — the ranks it takes in 95 % of
    #: resamples (None on a large board until its next full computation, docs/server.md).
    score_low: float | None = None
    score_high: float | None = None
    stable_low: float | None = None
    stable_high: float | None = None
    rank_low: int | None = None
    rank_high: int | None = None
    #: Each metric's 95 % interval ``[low, high]`` on the board (None where the board has none).
    intervals: dict[str, list[float] | None] = field(default_factory=dict)
    #: Why a run listed apart (``board_status`` failed or partial) is not ranked, in the board's words.
    reason: str | None = None
    #: The board's bootstrap: its groups, seeded resamples and confidence level.
    groups: int = 0
    resamples: int = 0
    confidence: float = 0.95
    #: The next boxes its policy saw: it ranks on the boards of this lookahead (docs/server.md).
    lookahead: int = 0
    #: False for a run no board shows (a lookahead K > 0 under the paper protocol: lookahead-0 boards only).
    boarded: bool = True

    @property
    def board(self) -> str:
        return (
            f"{self.setting}/{self.dataset}"
            + (" (paper protocol)" if self.protocol != CLOSED else "")
            + (f" (lookahead {self.lookahead})" if self.lookahead else "")
        )


#: What a ranked run's :class:`Standing` takes from its board entry.
RANKED_FIGURES: set[str] = {
    "rank",
    "rank_low",
    "rank_high",
    "score",
    "score_low",
    "score_high",
    "stable",
    "stable_low",
    "stable_high",
    "intervals",
}


def _one_line(text: str, limit: int = 200) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def problem_from_response(response: httpx.Response) -> ServerError:
    """Turn an error answer into a :class:`ServerError`: RFC 9457 problems keep their own words; anything
    else (a proxy's HTML page, a server of another kind) gets its status and the start of its body."""
    status = response.status_code
    body: Any = None
    with contextlib.suppress(ValueError):
        body = response.json()
    if isinstance(body, dict) and isinstance(body.get("title"), str):
        kind = body.get("type")
        kind = kind.rstrip("/").rsplit("/", 1)[-1] if isinstance(kind, str) else None
        errors = body.get("errors") if isinstance(body.get("errors"), list) else None
        detail = found if isinstance(found := body.get("detail"), str) else ""
        return ServerError(status, _one_line(body["title"], 100), _one_line(detail), kind=kind, errors=errors)
    reason = response.reason_phrase or "HTTP error"
    text = _one_line(response.text, 120) if response.text.strip() else ""
    detail = f"not an API answer ({text!r})" if text else "not an API answer (empty body)"
    return ServerError(status, reason, detail)


def default_name(policy_url: str) -> str:
    """A submission name from the URL (``host-port-path``), within the server's name rules."""
    parts = urlsplit(policy_url.strip())
    raw = "-".join(p for p in (parts.hostname or "", str(parts.port or ""), parts.path.strip("/")) if p)
    return clean_name(re.sub(r"[^A-Za-z0-9._-]+", "-", raw).strip("-._"))


class ServerClient:
    """One evaluation server, one API token (``None`` is enough for the public leaderboards).

    ``base_url`` is the server's root (``http://host:8000``); a trailing ``/api/v1`` is accepted too.
    Use as a context manager, or call :meth:`close`.
    """

    def __init__(
        self, base_url: str = DEFAULT_SERVER, token: str | None = None, *, timeout: float = 30.0
    ) -> None:
        base = base_url.strip().rstrip("/")
        if base.endswith(API_PREFIX):
            base = base[: -len(API_PREFIX)]
        parts = urlsplit(base)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ServerError(None, "Invalid server URL", f"{base_url!r} is not an http(s):// URL")
        self.base_url = base
        headers = {"Accept": "application/json, application/problem+json"}
        token = (token or "").strip()
        if token:
            if not token.isascii() or not token.isprintable():
                raise ServerError(None, "Invalid API token", "it contains characters a header cannot carry")
            headers["Authorization"] = f"Bearer {token}"
        self._http = httpx.Client(
            base_url=base + API_PREFIX, headers=headers, timeout=timeout, follow_redirects=False
        )

    # -- plumbing ---------------------------------------------------------------------------------
    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> ServerClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> Any:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.TimeoutException:
            raise ServerError(
                None, f"no answer from {self.base_url} in time", f"{method} {API_PREFIX}{path} timed out"
            ) from None
        except httpx.TransportError as exc:
            reason = _one_line(str(exc) or type(exc).__name__, 120)
            raise ServerError(None, f"cannot reach the server at {self.base_url}", reason) from None
        if response.is_redirect:
            where = response.headers.get("location", "?")
            detail = f"the server sends {API_PREFIX}{path} to {where}; use that address as the server"
            raise ServerError(response.status_code, "Redirected", detail)
        if response.is_error:
            raise problem_from_response(response)
        try:
            return response.json()
        except ValueError:
            detail = f"{method} {API_PREFIX}{path} did not answer JSON; is {self.base_url} a robobpp server?"
            raise ServerError(response.status_code, "Unexpected answer", detail) from None

    def _get(self, path: str, model: type[M], **kwargs: Any) -> M:
        return self._parse(self._request("GET", path, **kwargs), model, path)

    @staticmethod
    def _parse(data: Any, model: type[M], path: str) -> M:
        try:
            if isinstance(model, type) and issubclass(model, BaseModel):
                parsed: M = model.model_validate(data)
                return parsed
            return TypeAdapter(model).validate_python(data)
        except ValidationError as exc:
            errors = exc.errors()
            loc, msg = (errors[0]["loc"], errors[0]["msg"]) if errors else ((), "invalid")
            where = ".".join(str(p) for p in loc) or "body"
            detail = f"{API_PREFIX}{path} does not match this client ({where}: {msg})"
            raise ServerError(None, "Unexpected answer", detail) from None

    # -- the API ----------------------------------------------------------------------------------
    def info(self) -> ServiceInfo:
        """What the server evaluates: datasets, settings, groups, weights, termination reasons."""
        return self._get("/info", ServiceInfo)

    def me(self) -> Me:
        """Who the token belongs to, and how much of the quota is used."""
        return self._get("/me", Me)

    def submit(
        self,
        policy_url: str | None,
        secret: str | None = None,
        name: str | None = None,
        datasets: list[str] | None = None,
        settings: list[str] | None = None,
        track: BoardTrack = "private",
        *,
        lookahead: int = 0,
        mode: Literal["push", "pull"] = "push",
    ) -> SubmissionPublic:
        """Submit a policy server for evaluation. The server probes ``/info`` before writing anything, so
        a wrong secret or an unreachable URL fails here, not halfway through the evaluation.

        ``mode="pull"`` (no URL): the policy connects out to the server instead
        (:func:`robobpp.client.connect.connect` does both steps)."""
        # without a name, the server names a push submission after its policy's /info (name and version)
        body: dict[str, Any] = {"mode": mode, "track": track, "lookahead": lookahead}
        if name or mode == "pull":
            body["name"] = name or default_name("pull")
        if policy_url is not None:
            body["policy_url"] = policy_url
        if secret:
            body["secret"] = secret
        if datasets:
            body["datasets"] = list(datasets)
        if settings:
            body["settings"] = list(settings)
        return self._parse(self._request("POST", "/submissions", json=body), SubmissionPublic, "/submissions")

    def submissions(self, *, limit: int = 50, offset: int = 0) -> list[SubmissionPublic]:
        """This token's submissions, newest first (the admin token sees every one)."""
        params = {"limit": limit, "offset": offset}
        return self._get("/submissions", list[SubmissionPublic], params=params)

    def submission(self, submission_id: int) -> SubmissionPublic:
        return self._get(f"/submissions/{int(submission_id)}", SubmissionPublic)

    def cancel(self, submission_id: int) -> SubmissionPublic:
        """Stop an evaluation: its unfinished episodes become ``cancelled`` (409 once it has finished)."""
        path = f"/submissions/{int(submission_id)}/cancel"
        return self._parse(self._request("POST", path), SubmissionPublic, path)

    def episodes(self, submission_id: int) -> list[EpisodePublic]:
        """Per-episode results with their termination reasons."""
        return self._get(f"/submissions/{int(submission_id)}/episodes", list[EpisodePublic])

    def episode(self, submission_id: int, episode_id: int) -> EpisodeDetail:
        """One episode; on the public track it carries its replay trace."""
        return self._get(f"/submissions/{int(submission_id)}/episodes/{int(episode_id)}", EpisodeDetail)

    def leaderboard(
        self,
        dataset: str,
        setting: str,
        track: BoardTrack = "private",
        *,
        view: str = "best",
        limit: int = 50,
        offset: int = 0,
        submission: int | None = None,
        protocol: str = CLOSED,
        lookahead: int = 0,
    ) -> Leaderboard:
        """One page of a board: each participant's best entry (``view="best"``) or ``"all"`` entries;
        ``protocol="paper"``: a physical setting's board under the paper protocol (docs/server.md);
        ``lookahead``: the board of the submissions that saw that many next boxes (0: the leaderboard)."""
        params: dict[str, Any] = {"track": track, "view": view, "limit": limit, "offset": offset}
        if submission is not None:
            params["submission"] = submission
        if protocol != CLOSED:  # the default goes unsaid: a server from before protocols answers alike
            params["protocol"] = protocol
        if lookahead:
            params["lookahead"] = lookahead
        board: Leaderboard = self._get(f"/leaderboards/{dataset}/{setting}", Leaderboard, params=params)
        if setting != "math":
            self._check_loop(board.protocol, protocol)
        self._check_lookahead(board.lookahead, lookahead)
        return board

    def grid(
        self,
        track: BoardTrack = "private",
        *,
        view: str = "best",
        limit: int = 50,
        offset: int = 0,
        protocol: str = CLOSED,
        lookahead: int = 0,
    ) -> OverallGrid:
        """The overall grid: ranked rows (a score and rank per ``setting/dataset`` board, and the Mean) and
        the partial or failed ones apart; ``protocol="paper"``: its physical columns under the paper protocol;
        ``lookahead``: of the submissions that saw that many next boxes."""
        params: dict[str, Any] = {"track": track, "view": view, "limit": limit, "offset": offset}
        if protocol != CLOSED:
            params["protocol"] = protocol
        if lookahead:
            params["lookahead"] = lookahead
        grid: OverallGrid = self._get("/leaderboards", OverallGrid, params=params)
        self._check_loop(grid.protocol, protocol)
        self._check_lookahead(grid.lookahead, lookahead)
        return grid

    def _check_lookahead(self, served: int, asked: int) -> None:
        """A server from before boards per lookahead ignores ``lookahead`` and serves its one board: say so."""
        if served != asked:
            raise ServerError(
                None,
                "Lookahead not offered",
                f"the server at {self.base_url} served the lookahead-{served} board, not lookahead {asked} "
                "(it predates boards per lookahead)",
                kind="protocol",
            )

    def _check_loop(self, served: str, asked: str) -> None:
        """A server from before protocols ignores ``protocol=paper`` and serves closed-loop boards: say so."""
        if served != asked:
            raise ServerError(
                None,
                "Protocol not offered",
                f"the server at {self.base_url} served the {served} "
                f"protocol, not {asked} (it predates the paper protocol)",
                kind="protocol",
            )

    def create_participant(self, name: str) -> TokenCreated:
        """(Admin) A new participant and its first API token — the only time the token is shown."""
        return self._parse(
            self._request("POST", "/participants", json={"name": name}), TokenCreated, "/participants"
        )

    def issue_token(self, participant_id: int) -> TokenCreated:
        """(Admin) Another API token for a participant (e.g. after revoking a leaked one)."""
        path = f"/participants/{int(participant_id)}/tokens"
        return self._parse(self._request("POST", path), TokenCreated, path)

    def tokens(self) -> list[TokenPublic]:
        return self._get("/tokens", list[TokenPublic])

    def revoke_token(self, token_id: int) -> TokenPublic:
        path = f"/tokens/{int(token_id)}"
        return self._parse(self._request("DELETE", path), TokenPublic, path)

    # -- conveniences -----------------------------------------------------------------------------
    def wait(
        self,
        submission_id: int,
        on_progress: Callable[[SubmissionPublic], None] | None = None,
        poll_s: float = 2.0,
        *,
        timeout_s: float | None = None,
        patience_s: float = 60.0,
    ) -> SubmissionPublic:
        """Poll until the submission has finished (completed, failed or cancelled) and return it.

        ``on_progress`` sees every polled state, the last one included. A server that cannot be reached
        for less than ``patience_s`` (a restart: queued work resumes) is waited for; HTTP errors
        (401, 404…) are raised at once. ``timeout_s`` bounds the whole wait (``ServerError`` after it).
        """
        started = last_ok = time.monotonic()
        while True:
            try:
                sub = self.submission(submission_id)
            except ServerError as exc:
                if exc.status is not None or time.monotonic() - last_ok > patience_s:
                    raise
            else:
                last_ok = time.monotonic()
                if on_progress is not None:
                    on_progress(sub)
                if sub.status in FINISHED:
                    return sub
            if timeout_s is not None and time.monotonic() - started > timeout_s:
                raise ServerError(
                    None, "Still running", f"submission {submission_id} did not finish within {timeout_s:g} s"
                )
            time.sleep(poll_s)

    def standings(
        self, submission: SubmissionPublic, *, wait_s: float = 0.0, poll_s: float = 0.5
    ) -> list[Standing]:
        """Each run of ``submission`` with its rank and score on its board (``None`` while not ranked).

        Boards are recomputed in the background, so a submission that has just finished may not be on them
        for a moment: ``wait_s`` > 0 polls, up to that long, until every completed run of a finished
        submission is on its board (ranked or listed apart); :attr:`Standing.board_status` says which ones
        still are not when it gives up.
        """
        deadline = time.monotonic() + max(0.0, wait_s)
        while True:
            out = [self._standing(submission, run) for run in submission.runs]
            awaited = submission.status in ("completed", "failed")
            missing = [
                s for s in out if awaited and s.status == "completed" and s.board_status is None and s.boarded
            ]
            if not missing or time.monotonic() + poll_s > deadline:
                return out
            time.sleep(poll_s)

    def _standing(self, submission: SubmissionPublic, run: Any) -> Standing:
        track: BoardTrack = "public" if submission.track == "public" else "private"
        protocol, lookahead = run.protocol, submission.lookahead
        if not has_boards(protocol, lookahead, run.setting):
            # the paper-protocol boards are lookahead 0 only: this run is on none
            return Standing(
                dataset=run.dataset,
                setting=run.setting,
                status=run.status,
                metrics=dict(run.metrics or {}),
                metric_keys=list(run.metrics or {}),
                rank=None,
                score=None,
                entries=0,
                protocol=protocol,
                lookahead=lookahead,
                boarded=False,
            )
        board = self.leaderboard(
            run.dataset,
            run.setting,
            track=track,
            view="all",
            submission=submission.id,
            protocol=protocol,
            lookahead=lookahead,
        )
        entry: LeaderboardEntry | None = next(
            (e for e in board.entries if e.submission_id == submission.id), None
        )
        apart = next((e for e in board.unranked if e.submission_id == submission.id), None)
        metrics = dict(entry.metrics if entry else run.metrics or {})
        # the board's own figures, as it serves them (none computed here: one source of truth)
        figures = entry.model_dump(include=RANKED_FIGURES) if entry else {"rank": None, "score": None}
        return Standing(
            dataset=run.dataset,
            setting=run.setting,
            status=run.status,
            metrics=metrics,
            metric_keys=list(board.metrics),
            entries=self.leaderboard(
                run.dataset,
                run.setting,
                track=track,
                view="all",
                limit=1,
                protocol=protocol,
                lookahead=lookahead,
            ).total,
            board_status="ranked" if entry else apart.status if apart else None,
            protocol=protocol,
            reason=apart.reason if apart else None,
            groups=board.groups,
            resamples=board.resamples,
            confidence=board.confidence,
            lookahead=lookahead,
            **figures,
        )
