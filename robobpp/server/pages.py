"""The HTML pages of the service (server-rendered Jinja2; JavaScript only adds sorting, charts and 3D).

Every figure comes from ``robobpp.db.queries`` — the same functions the JSON API serves — so a page can
never disagree with the API or compute a second leaderboard. Public pages show what a public leaderboard
shows (names, scores, replays of public-track episodes). A submission's own page, its live status and
its failure reasons are its owner's and the operator's only (others get the 404 a missing one gets,
like the API); baselines' pages are public. Signing in, submitting and the operator's pages are in
``robobpp.server.site``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Path, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse
from markupsafe import Markup
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp.boards.reader import BoardCache
from robobpp.boards.store import BoardsUnavailable, board_key, grid_key
from robobpp.datasets import DATASETS
from robobpp.db import queries, waiting
from robobpp.db.models import Submission
from robobpp.episode import TERMINATION_REASONS
from robobpp.schemas import MAX_SUBMISSION_LOOKAHEAD
from robobpp.scoring.metrics import METRICS
from robobpp.scoring.scores import WEIGHTS
from robobpp.server.api.deps import SessionDep, SettingsDep, in_read_session
from robobpp.server.api.leaderboards import board_cache, cached_body, known_lookaheads
from robobpp.server.problems import ProblemError
from robobpp.server.services import access, progress
from robobpp.server.site import account, operator
from robobpp.server.site.render import not_found, render, root, with_csrf
from robobpp.server.site.session import Viewer, load_viewer, resolved_in_handler, viewer
from robobpp.server.state import state_of
from robobpp.vocabulary import ACTIVE_SUBMISSION, CLOSED, PHYSICAL, BoardTrack, Loop, board_loop, has_boards
from robobpp.web import SETTING_TITLES, environment, tables
from robobpp.web.trace import TraceError, viewer_payload

router = APIRouter(include_in_schema=False, dependencies=[Depends(load_viewer)])
router.include_router(account.router)
router.include_router(operator.router)

#: ``closed`` (the benchmark, the default) or ``paper``: the physical boards under the paper protocol.
DatasetPath = Annotated[str, Path(max_length=32)]
SettingPath = Annotated[str, Path(max_length=16)]
#: Termination reasons that are not the policy's fault or are plain endings, for colouring badges.
NEUTRAL_ENDINGS = {"completed", "no_feasible_placement", "too_high"}
NOT_READY = "The boards are being computed for the first time; this page will show them in a moment."
EXTRA_REASONS = {
    "worker_lost": "no worker could finish the episode",
    "evaluation_error": "the service could not run the episode",
}


def _board_names(settings: SettingsDep) -> tuple[tuple[str, ...], tuple[str, ...]]:
    return tuple(settings.datasets), tuple(settings.enabled_settings)


View = Literal["best", "all"]
Page = Annotated[int, Query(ge=1, le=10**5)]
#: The boards of the submissions that saw this many next boxes (0: the leaderboard's).
Lookahead = Annotated[int, Query(ge=0, le=MAX_SUBMISSION_LOOKAHEAD)]
PAPER_LOOKAHEAD = (
    "The paper-protocol boards are lookahead 0 only (the paper’s tables were made without lookahead); "
    "a lookahead above 0 has closed-loop boards."
)


@router.get("/", response_class=HTMLResponse)
async def overall_page(
    request: Request,
    settings: SettingsDep,
    track: BoardTrack = "private",
    view: View = "best",
    page: Page = 1,
    protocol: Loop = CLOSED,
    lookahead: Lookahead = 0,
) -> HTMLResponse:
    datasets, setting_names = _board_names(settings)
    if not has_boards(protocol, lookahead):
        return not_found(request, PAPER_LOOKAHEAD)

    def build(cache: BoardCache) -> HTMLResponse:
        shown = cache.grid_page(
            track, protocol, view, tables.PAGE_SIZE, (page - 1) * tables.PAGE_SIZE, lookahead
        )
        return render(
            request,
            "index.html",
            title="Leaderboard",
            nav="leaderboard",
            track=track,
            view=view,
            table=tables.grid_table(shown),
            datasets_info=DATASETS,
            top=tables.TOP,
            pages=tables.pages(shown, page),
            protocol=protocol,
            has_physical=bool(set(setting_names) & set(PHYSICAL)),
            lookahead=lookahead,
            lookaheads=shown.get("lookaheads", [0]),
            status=_status(request, settings),
        )

    return await _shared(
        request,
        track,
        grid_key(protocol, lookahead),
        ("home", root(request), track, view, page, protocol, lookahead),
        build,
        lookahead,
    )


def _status(request: Request, settings: Any) -> dict[str, Any]:
    """The demo, the backlog and baselines queued again, as the boards' pages say them (services/progress.py)."""
    with state_of(request.app).runtime.read_session() as session:
        return progress.page_status(session, settings)


async def _shared(
    request: Request,
    track: str,
    board: str | None,
    key: tuple[Any, ...],
    build: Callable[[BoardCache], HTMLResponse],
    lookahead: int = 0,
) -> HTMLResponse:
    """An anonymous visitor's board page, rendered once per version of ``board`` and shared by every such
    reader (boards/reader.py; answered on the event loop while current); a page naming its viewer or
    carrying a CSRF nonce is rendered for that viewer, in a worker thread. A lookahead no entry saw: 404."""
    who = viewer(request)
    try:
        if who.signed_in or who.nonce:
            return await run_in_threadpool(build, board_cache(request))
        return HTMLResponse(
            await cached_body(request, track, board, key, lambda c: bytes(build(c).body), lookahead)
        )
    except (BoardsUnavailable, ProblemError) as exc:
        if isinstance(exc, ProblemError) and exc.status == 404:
            return not_found(request, exc.detail)
        known = await run_in_threadpool(known_lookaheads, board_cache(request), track) if lookahead else None
        if known is not None and lookahead not in known:
            return not_found(request, f"No entry on this track saw lookahead {lookahead}.")
        page = render(
            request, "error.html", 503, title="Boards not ready", nav="leaderboard", message=NOT_READY
        )
        page.headers["Retry-After"] = "2"
        return page


async def _static(request: Request, key: tuple[Any, ...], build: Callable[[], HTMLResponse]) -> HTMLResponse:
    """A page that changes only with the configuration (datasets, protocol): an anonymous visitor's copy
    is rendered once per process."""
    who = viewer(request)
    if who.signed_in or who.nonce:
        return await run_in_threadpool(build)
    pages: dict[tuple[Any, ...], bytes] = state_of(request.app).static_pages
    key = (*key, root(request))
    if key not in pages:
        pages[key] = bytes((await run_in_threadpool(build)).body)
    return HTMLResponse(pages[key])


@router.get("/boards/{dataset}/{setting}", response_class=HTMLResponse)
async def board_page(
    request: Request,
    dataset: DatasetPath,
    setting: SettingPath,
    settings: SettingsDep,
    track: BoardTrack = "private",
    view: View = "best",
    page: Page = 1,
    protocol: Loop = CLOSED,
    lookahead: Lookahead = 0,
) -> HTMLResponse:
    datasets, setting_names = _board_names(settings)
    if dataset not in datasets or setting not in setting_names:
        return not_found(request, f"There is no leaderboard for dataset “{dataset}” and setting “{setting}”.")
    served = board_loop(setting, protocol)  # Math Pack: one board for both
    if not has_boards(served, lookahead):
        return not_found(request, PAPER_LOOKAHEAD)

    def build(cache: BoardCache) -> HTMLResponse:
        shown = cache.board_page(
            dataset,
            setting,
            track,
            served,
            view,
            tables.PAGE_SIZE,
            (page - 1) * tables.PAGE_SIZE,
            lookahead=lookahead,
        )
        title = f"{DATASETS[dataset].title} · {SETTING_TITLES[setting]}"
        if served != CLOSED:
            title += " · paper protocol"
        if lookahead:
            title += f" · lookahead {lookahead}"
        return render(
            request,
            "board.html",
            title=title,
            nav="leaderboard",
            dataset=DATASETS[dataset],
            setting=setting,
            track=track,
            view=view,
            table=tables.board_table(shown),
            weights=WEIGHTS[setting],
            top=tables.TOP,
            pages=tables.pages(shown, page),
            board=shown,
            protocol=served,
            has_physical=setting in PHYSICAL,
            lookahead=lookahead,
            lookaheads=shown.get("lookaheads", [0]),
            other_boards=[
                (d, s, f"{DATASETS[d].title} · {SETTING_TITLES[s]}")  # as the titles read
                for s in setting_names
                for d in datasets
            ],
            status=_status(request, settings),
        )

    return await _shared(
        request,
        track,
        board_key(dataset, setting, served, lookahead),
        ("board-page", root(request), dataset, setting, track, view, page, served, lookahead),
        build,
        lookahead,
    )


def _submission(session: Session, submission_id: int) -> Submission | None:
    return session.get(Submission, submission_id)


def _is_owner(who: Viewer, sub: Submission) -> bool:
    """May ``who`` see this submission's details, live status and failure reasons? (The API's rule.)"""
    return access.is_owner(sub, admin=who.admin, participant_id=who.participant_id)


def _visible(request: Request, session: Session, submission_id: int) -> Submission | None:
    who = viewer(request, session)  # a signed-in viewer's rows read in this transaction
    sub = _submission(session, submission_id)
    if sub is None or not access.may_see(sub, admin=who.admin, participant_id=who.participant_id):
        return None
    return sub


def _page_view(request: Request, session: Session, sub: Submission, owner: bool) -> dict[str, Any]:
    """The submission as the API returns it; a baseline seen by the public loses its policy URL."""
    view = dict(
        state_of(request.app).finished_views.get(
            ("view",), sub, lambda: queries.submission_view(session, sub)
        )
    )
    if not owner:
        view.pop("policy_url", None)
    view["queue"] = waiting.queue_place(
        session,
        sub,
        slots=state_of(request.app).settings.worker_slots,
        per_worker=state_of(request.app).settings.episodes_per_worker,
    )
    return view


@router.get("/submissions/{submission_id}", response_class=HTMLResponse)
@resolved_in_handler
async def submission_page(
    request: Request, submission_id: Annotated[int, Path(ge=1, le=2**62)]
) -> HTMLResponse:
    return await in_read_session(request, lambda session: _submission_page(request, session, submission_id))


def _submission_page(request: Request, session: Session, submission_id: int) -> HTMLResponse:
    sub = _visible(request, session, submission_id)
    if sub is None:  # missing, or someone else's: the same answer, so ids reveal nothing
        return not_found(request, f"There is no submission {submission_id}.")
    who = viewer(request)
    owner = _is_owner(who, sub)
    cache = board_cache(request)
    try:
        published = cache.version(sub.track, None)
    except BoardsUnavailable:
        return _render_submission(request, session, sub, owner, cache)
    # A finished submission's page changes only with its boards and the kind of viewer (the navigation
    # names a signed-in one): kept per publication of its track, with the viewer's CSRF nonce put in when
    # served — not rendered again (10 ms of a page of 270 kB) for every reader.
    kind = (
        "page",
        owner,
        str(request.base_url),
        root(request),
        who.signed_in,
        who.admin,
        who.name,
        published,
    )
    body = state_of(request.app).finished_views.get(
        kind, sub, lambda: bytes(_render_submission(request, session, sub, owner, cache, csrf_slot=True).body)
    )
    return with_csrf(request, body)


def _render_submission(
    request: Request,
    session: Session,
    sub: Submission,
    owner: bool,
    cache: BoardCache,
    csrf_slot: bool = False,
) -> HTMLResponse:
    view = _page_view(request, session, sub, owner)
    ranks, entries, apart, bootstrap = {}, {}, {}, []
    for r in view["runs"]:
        if r["status"] != "completed":
            continue
        key = (r["dataset"], r["setting"], r["protocol"])
        try:
            standing = _standing(cache, sub, *key)
        except BoardsUnavailable:  # not published yet (a fresh server): the page shows no rank
            continue
        if standing is None:  # a lookahead K > 0 under the paper protocol: no board shows it
            continue
        entry, of, board = standing
        if entry is not None:
            ranks[key] = tables.standing(entry, of)  # the board's own figures, as its rows show them
            entries[key] = (entry, of)
            bootstrap.append(board)
        elif board["unranked"]:  # failed or partial: the board's reason for ranking it apart
            apart[key] = board["unranked"][0]
    closed = [r for r in view["runs"] if r["protocol"] == CLOSED]  # the radar: the benchmark's boards
    # the results table lists a paper-protocol run right under its closed-loop run
    place = {(r["dataset"], r["setting"]): i for i, r in enumerate(closed)}
    view = {
        **view,
        "runs": sorted(
            view["runs"],
            key=lambda r: (place.get((r["dataset"], r["setting"]), len(place)), r["protocol"] != CLOSED),
        ),
    }
    public = sub.track == "public"
    reasons = {**TERMINATION_REASONS, **EXTRA_REASONS}
    views = state_of(request.app).finished_views

    def episode_table() -> tuple[Markup, dict[str, list[str] | list[int]]]:
        """The episode table and the utilisation histogram: a finished submission's are built once."""
        episodes = queries.episode_rows(session, sub.id)
        utilisation = [
            (e["metrics"] or {}).get("space_utilization")
            for e in episodes
            if e["status"] == "done" and e["metrics"]
        ]
        html = (
            environment()
            .get_template("_episodes_table.html")
            .render(
                root=root(request),
                sub=view,
                episodes=episodes,
                owner=owner,
                public=public,
                reasons=reasons,
                neutral=NEUTRAL_ENDINGS,
            )
        )
        return Markup(html), tables.histogram([u for u in utilisation if u is not None])

    table, histogram = views.get(("page-episodes", owner, public, root(request)), sub, episode_table)
    closed_entries = {(d, s): e for (d, s, p), e in entries.items() if p == CLOSED}
    charts = {"radar": tables.radar_groups(closed, closed_entries), "utilization": histogram}
    ran = {r["setting"] for r in view["runs"]}
    columns = [m for m in METRICS if ran & set(m.settings)]
    return render(
        request,
        "submission.html",
        title=f"Submission {sub.id}",
        nav="leaderboard",
        sub=view,
        has_pph="execution" in ran,
        owner=owner,
        site=str(request.base_url).rstrip("/"),
        can_cancel=owner
        and view["status"] in ACTIVE_SUBMISSION
        and (sub.track != "verify" or viewer(request).admin),
        episodes_table=table,
        ranks=ranks,
        apart=apart,
        bootstrap=_bootstrap(bootstrap),
        charts=charts,
        metrics=columns,
        public=public,
        reasons=reasons,
        neutral=NEUTRAL_ENDINGS,
        csrf_slot=csrf_slot,
    )


def _standing(
    cache: BoardCache, sub: Submission, dataset: str, setting: str, protocol: str
) -> tuple[dict[str, Any] | None, int, dict[str, Any]] | None:
    """The submission's ranked entry on a board of its lookahead (None: not ranked), how many entries it
    ranks, and the board as seen from that submission alone: its bootstrap (groups, resamples, confidence)
    and, for an entry listed apart, its ``unranked`` row with the board's reason. None where no board can
    show the run (a lookahead K > 0 has no paper-protocol boards)."""
    if not has_boards(protocol, sub.lookahead, setting):
        return None
    entry, of = cache.ranked_entry(dataset, setting, sub.track, protocol, sub.id, sub.lookahead)
    for attempt in (0, 1):
        try:
            board = cache.board_page(
                dataset,
                setting,
                sub.track,
                protocol,
                view="all",
                limit=1,
                submission_id=sub.id,
                lookahead=sub.lookahead,
            )
            return entry, of, board
        except BoardsUnavailable:
            raise
        except LookupError:  # the version just read was replaced meanwhile (boards/reader.py): read again
            if attempt:
                raise
            cache.publication(sub.track, force=True)
    raise AssertionError("unreachable")


def _bootstrap(boards: list[dict[str, Any]]) -> dict[str, Any] | None:
    """What the page's note on intervals says: the boards' confidence, resamples and groups ("2", or "2–30"
    when its boards differ); None when no board ranks the submission."""
    if not boards:
        return None
    groups = sorted({b["groups"] for b in boards})
    return {
        "confidence": boards[0]["confidence"],
        "resamples": boards[0]["resamples"],
        "groups": str(groups[0]) if len(groups) == 1 else f"{groups[0]}–{groups[-1]}",
    }


@router.get("/submissions/{submission_id}/status.json")
@resolved_in_handler
async def submission_status(
    request: Request, submission_id: Annotated[int, Path(ge=1, le=2**62)]
) -> JSONResponse:
    """What the submission page polls while an evaluation runs (its owner's and the operator's)."""
    return await in_read_session(request, lambda session: _submission_status(request, session, submission_id))


def _submission_status(request: Request, session: Session, submission_id: int) -> JSONResponse:
    sub = _visible(request, session, submission_id)
    if sub is None:
        return JSONResponse(
            {"detail": f"no submission {submission_id}"},
            status_code=404,
            headers={"Cache-Control": "no-store"},
        )
    view = state_of(request.app).finished_views.get(
        ("view",), sub, lambda: queries.submission_view(session, sub)
    )
    runs = [{k: r[k] for k in ("dataset", "setting", "status", "episodes_total")} for r in view["runs"]]
    queue = waiting.queue_place(
        session,
        sub,
        slots=state_of(request.app).settings.worker_slots,
        per_worker=state_of(request.app).settings.episodes_per_worker,
    )
    if queue is not None and queue["estimated_start"] is not None:
        queue = {**queue, "estimated_start": queue["estimated_start"].isoformat()}
    return JSONResponse(
        {"id": sub.id, "status": view["status"], "progress": view["progress"], "runs": runs, "queue": queue},
        headers={"Cache-Control": "no-store"},
    )


@router.get("/submissions/{submission_id}/episodes/{episode_id}/replay", response_class=HTMLResponse)
def replay_page(
    request: Request,
    submission_id: Annotated[int, Path(ge=1, le=2**62)],
    episode_id: Annotated[int, Path(ge=1, le=2**62)],
    session: SessionDep,
) -> HTMLResponse:
    sub = _submission(session, submission_id)
    ep = queries.get_episode(session, submission_id, episode_id) if sub is not None else None
    if sub is None or ep is None or sub.track != "public" or ep.trace is None:
        # One answer for missing and hidden alike (a private-track episode, one without a trace): a distinct
        # one mapped episode ids to tracks.
        return not_found(
            request,
            f"There is no replay of episode {episode_id} in submission {submission_id}. "
            "Only public-track episodes have one.",
        )
    summary = queries.episode_summary(ep)
    owner = _is_owner(viewer(request), sub)
    if not owner:  # a public replay shows how the episode ended, not the policy's own words
        summary["termination_detail"] = ""
    raw = {
        **ep.trace,
        **{
            k: summary[k]
            for k in (
                "dataset",
                "split",
                "setting",
                "group",
                "boxes_total",
                "boxes_placed",
                "termination",
                "termination_detail",
                "metrics",
            )
        },
        "episode_id": str(ep.id),
        "policy": sub.name,
    }
    try:
        payload = viewer_payload(raw)
    except TraceError as exc:
        return render(
            request,
            "error.html",
            500,
            title="Replay unavailable",
            nav="",
            message=f"This episode's trace cannot be drawn: {exc}",
        )
    base = root(request)
    heading = f"{sub.name} · {ep.dataset} · {ep.setting} · group {ep.group}"
    if ep.protocol != CLOSED:  # the Math Pack actions replayed
        heading += " · paper protocol"
    crumbs = [("Leaderboard", f"{base}/")]
    if owner or sub.participant.is_builtin:
        crumbs.append((f"Submission {sub.id}", f"{base}/submissions/{sub.id}"))
    return render(
        request, "replay.html", title=heading, heading=heading, episodes=[payload], nav="", crumbs=crumbs
    )


@router.get("/reproduction", response_class=HTMLResponse)
async def reproduction_page(
    request: Request, settings: SettingsDep, track: BoardTrack = "private"
) -> HTMLResponse:
    from robobpp.paper import paper_tables
    from robobpp.policies import TITLES
    from robobpp.server.services.reproduction import reproduction

    def build(_cache: BoardCache) -> HTMLResponse:
        with state_of(request.app).runtime.read_session() as session:
            data = reproduction(session, track)
        titles = {**paper_tables().methods, **TITLES}
        return render(
            request,
            "reproduction.html",
            title="Reproduction",
            nav="reproduction",
            track=track,
            data=data,
            tables=tables.reproduction_tables(data, titles),
            scores=tables.reproduction_scores(data, titles),
            docs_url=settings.docs_url,
            titles=titles,
            table_captions=paper_tables().tables,
        )

    # the baselines' runs change only when their boards do: rendered once per publication of the track
    return await _shared(request, track, None, ("reproduction-page", root(request), track), build)


@router.get("/datasets", response_class=HTMLResponse)
async def datasets_page(request: Request) -> HTMLResponse:
    return await _static(request, ("datasets",), lambda: _datasets_page(request))


def _datasets_page(request: Request) -> HTMLResponse:
    from robobpp.web import dataset_stats as ds

    cards = []
    for name, spec in DATASETS.items():
        summary = ds.dataset_summary(name)
        plot = None
        if summary is not None:
            colors = {"length": "#93c5fd", "width": "#86efac", "height": "#fcd34d"}
            plot = ds.boxplot_svg(
                [(dim.capitalize(), summary["dims"][dim], colors[dim]) for dim in ds.DIMENSIONS], "cm"
            )
        cards.append({"spec": spec, "summary": summary, "plot": plot})
    return render(
        request,
        "datasets.html",
        title="Datasets",
        nav="datasets",
        cards=cards,
        available=ds.data_available(),
        groups=ds.SAMPLE_GROUPS,
    )


@router.get("/protocol", response_class=HTMLResponse)
async def protocol_page(request: Request, settings: SettingsDep) -> HTMLResponse:
    return await _static(
        request,
        ("protocol",),
        lambda: render(
            request,
            "protocol.html",
            title="Take part",
            nav="protocol",
            reasons=TERMINATION_REASONS,
            datasets=DATASETS,
            settings_offered=settings.enabled_settings,
            quota_day=settings.quota_submissions_per_day,
            quota_concurrent=settings.quota_concurrent,
        ),
    )
