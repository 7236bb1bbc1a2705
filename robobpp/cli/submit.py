"""`robobpp submit`, `submissions` and `leaderboard`: the evaluation server from a shell.

Thin layers over :class:`robobpp.client.api.ServerClient`. Every server failure ends in one line
(``error: 401: Unauthorized: ...``) and exit code 1; argument mistakes exit 2 (typer's convention).
Tables go to stdout, progress and notes to stderr, so ``--json`` output and tables pipe cleanly.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from robobpp.cli.common import fail, table_console
from robobpp.cli.export import WideOpt
from robobpp.vocabulary import BOARD_TRACKS, CLOSED, DATASETS, PAPER, SETTINGS, BoardTrack, has_boards

if TYPE_CHECKING:
    from rich.progress import Progress

    from robobpp.client.api import ServerClient, Standing
    from robobpp.schemas import EpisodePublic, Leaderboard, OverallGrid, SubmissionPublic

err = Console(stderr=True)

ServerOpt = Annotated[
    str, typer.Option("--server", envvar="ROBOBPP_SERVER", help="Evaluation server root URL.")
]
TokenOpt = Annotated[
    str | None,
    typer.Option("--token", envvar="ROBOBPP_TOKEN", help="API token (shown once when it was created)."),
]
TrackOpt = Annotated[str, typer.Option("--track", help="private (test split) or public (train split).")]
#: The boards a submission is evaluated on (submit and connect share them).
BoardDatasetsOpt = Annotated[
    list[str] | None, typer.Option("--dataset", help="repetitive, diverse, longboard (repeat or comma).")
]
BoardSettingsOpt = Annotated[
    list[str] | None, typer.Option("--setting", help="math, physics, execution (repeat or comma).")
]
LookaheadOpt = Annotated[int, typer.Option(min=0, max=10, help="Next boxes shown to the policy.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the API's JSON instead of a table.")]
IdArg = Annotated[int, typer.Argument(min=1, max=2**31 - 1, help="Submission id.")]

submissions_app = typer.Typer(no_args_is_help=True, help="Your submissions on the evaluation server.")


def register(root: typer.Typer) -> None:
    root.command("submit")(submit)
    root.command("leaderboard")(leaderboard)
    root.add_typer(submissions_app, name="submissions")


@contextlib.contextmanager
def api_client(server: str, token: str | None, *, need_token: bool = True) -> Iterator[ServerClient]:
    """A client whose every failure becomes one line and exit code 1 (no tracebacks)."""
    from robobpp.client.api import ServerClient, ServerError

    if need_token and not (token or "").strip():
        fail("no API token: pass --token or set ROBOBPP_TOKEN", code=2)
    if (token or "").strip() and plain_http_elsewhere(server):
        err.print(
            "[yellow]warning:[/] the API token goes over plain http to another machine; use https",
            soft_wrap=True,
        )
    try:
        with ServerClient(server, token) as client:
            yield client
    except ServerError as exc:
        fail(escape(str(exc)), code=1)


def plain_http_elsewhere(server: str) -> bool:
    """Whether the token would cross a network unencrypted (loopback is fine: dev servers, tests)."""
    import ipaddress
    from urllib.parse import urlsplit

    parts = urlsplit(server.strip())
    if parts.scheme != "http" or not parts.hostname:
        return False
    if parts.hostname == "localhost":
        return False
    try:
        return not ipaddress.ip_address(parts.hostname).is_loopback
    except ValueError:
        return True


def parse_track(value: str) -> BoardTrack:
    """``--track``: a track with boards, else one line and exit code 1."""
    for track in BOARD_TRACKS:
        if value == track:
            return track
    fail(f"unknown track {value!r}; expected {' or '.join(BOARD_TRACKS)}")


def parse_names(values: list[str] | None, allowed: tuple[str, ...], what: str) -> list[str] | None:
    """Repeated options and comma lists both work: ``--dataset diverse,longboard`` or twice ``--dataset``."""
    if not values:
        return None
    names = [n.strip().lower() for v in values for n in v.split(",") if n.strip()]
    if any(n == "all" for n in names):
        return None  # the server's own list
    unknown = [n for n in names if n not in allowed]
    if unknown or not names:
        fail(f"unknown {what} {', '.join(unknown) or repr(values)}; expected {', '.join(allowed)} or all")
    return list(dict.fromkeys(names))


def _fmt(value: float | None, digits: int = 4) -> str:
    return "—" if value is None else f"{value:.{digits}g}" if abs(value) >= 1000 else f"{value:.{digits}f}"


def _label(key: str) -> str:
    from robobpp.scoring.metrics import METRIC_BY_KEY

    metric = METRIC_BY_KEY.get(key)
    return metric.label if metric else key


# -- submit -------------------------------------------------------------------------------------------
def submit(
    policy_url: Annotated[str, typer.Argument(help="Base URL of your policy server (robobpp/1).")],
    secret: Annotated[
        str | None,
        typer.Option(envvar="ROBOBPP_POLICY_SECRET", help="HMAC secret the workers sign requests with."),
    ] = None,
    name: Annotated[
        str | None,
        typer.Option(help="Name on the leaderboard (default: the policy's /info name and version)."),
    ] = None,
    dataset: BoardDatasetsOpt = None,
    setting: BoardSettingsOpt = None,
    track: TrackOpt = "private",
    lookahead: LookaheadOpt = 0,
    wait: Annotated[
        bool, typer.Option("--wait", help="Follow the evaluation, then print the results.")
    ] = False,
    poll: Annotated[float, typer.Option(min=0.1, max=600, help="Seconds between polls with --wait.")] = 2.0,
    server: ServerOpt = "http://127.0.0.1:8000",
    token: TokenOpt = None,
) -> None:
    """Submit a policy server for evaluation (the server checks it answers /info first)."""
    datasets = parse_names(dataset, DATASETS, "dataset")
    settings = parse_names(setting, SETTINGS, "setting")
    with api_client(server, token) as client:
        sub = client.submit(
            policy_url,
            secret=secret,
            name=name,
            datasets=datasets,
            settings=settings,
            track=parse_track(track),
            lookahead=lookahead,
        )
        boards = len(sub.runs)
        err.print(
            f"submitted [bold]#{sub.id}[/] {escape(sub.name)}: {sub.progress.episodes_total} episodes "
            f"on {boards} board{'s' * (boards != 1)} ({sub.track} track)"
        )
        if not wait:
            print(sub.id)
            return
        final = _follow(client, sub, poll)
        print_results(client, final)
    exit_unless_completed(final)


#: How long ``submit --wait`` and ``connect`` wait for the boards to include a finished submission.
BOARD_WAIT_S = 30.0


def print_results(client: ServerClient, sub: SubmissionPublic, wait_s: float = BOARD_WAIT_S) -> None:
    """The finished submission's table with its score and rank: boards are recomputed in the background a
    moment after a submission finishes, so wait (bounded) until they include it, and say so if they do not."""
    standings = client.standings(sub, wait_s=wait_s)
    _print_standings(sub, standings)
    _print_provenance(sub)
    late = [s.board for s in standings if s.status == "completed" and s.board_status is None]
    if late and sub.status in ("completed", "failed"):
        err.print(
            f"the board{'s' * (len(late) > 1)} {', '.join(late)} did not include #{sub.id} within "
            f"{wait_s:g} s (boards are recomputed in the background); `robobpp submissions show {sub.id}` "
            "shows its score and rank once they do",
            soft_wrap=True,
        )


def _print_provenance(sub: SubmissionPublic) -> None:
    """The submission's provenance in one line under its table (docs/benchmark.md, "Provenance")."""
    from robobpp.provenance import one_line

    if sub.provenance:
        err.print(f"[dim]provenance: {escape(one_line(sub.provenance))}[/]", soft_wrap=True)


def progress_task(progress: Progress, sub: SubmissionPublic) -> Callable[[SubmissionPublic], None]:
    """A task on ``progress`` for ``sub`` and the function that shows each polled state of it (episodes
    finished / total, current phase): ``submit --wait`` and ``connect`` (whose ``LineProgress`` also prints
    plain lines off a terminal)."""
    task = progress.add_task(f"#{sub.id} {sub.status}", total=sub.progress.episodes_total or None)

    def show(s: SubmissionPublic) -> None:
        p = s.progress
        phase = f" · {p.phase}" if p.phase and s.status == "running" else ""
        failed = f" · {p.episodes_failed} failed" if p.episodes_failed else ""
        progress.update(
            task,
            total=p.episodes_total or None,
            completed=p.episodes_done,
            description=f"#{s.id} {s.status}{phase}{failed}{_queued(s)}",
        )

    return show


def _follow(client: ServerClient, sub: SubmissionPublic, poll_s: float) -> SubmissionPublic:
    """Poll with a progress bar (episodes finished / total, current phase) until the submission ends."""
    from robobpp.cli.progress import LineProgress

    with LineProgress(err) as progress:
        show = progress_task(progress, sub)
        try:
            return client.wait(sub.id, on_progress=show, poll_s=poll_s)
        except KeyboardInterrupt:
            progress.stop()
            err.print(f"stopped waiting; the evaluation goes on (robobpp submissions show {sub.id})")
            raise typer.Exit(130) from None


def _queued(sub: SubmissionPublic) -> str:
    """A queued submission's place and estimated start, for the progress line ("" once it runs)."""
    from robobpp.schemas import start_estimate_text

    q = sub.queue
    if q is None or q.position is None:
        return ""
    eta = "" if q.estimated_start_s is None else f" · {start_estimate_text(q.estimated_start_s)} (estimate)"
    return f" · position {q.position}{eta}"


def exit_unless_completed(sub: SubmissionPublic) -> None:
    """Exit 0 only for a completed evaluation: scripts and CI can gate on ``submit --wait``."""
    if sub.status == "completed":
        return
    why = f": {sub.error}" if sub.error else ""
    fail(escape(f"submission {sub.id} {sub.status}{why}"), code=1)


def _print_standings(sub: SubmissionPublic, standings: list[Standing]) -> None:
    """A submission's results as its boards show them: per board one line with the score, rank and stable
    score, each with the board's 95 % interval (or why it has none), then the metrics with theirs, then what
    the intervals mean. All on stdout, whole lines also off a terminal (a log, a pipe)."""
    out = table_console()
    out.print(f"#{sub.id} {escape(sub.name)} · {sub.status} · {sub.track} track", soft_wrap=True)
    width = max((len(s.board) for s in standings), default=0)
    for s in standings:
        style = "bold green" if s.rank == 1 else None
        out.print(f"{s.board:<{width}}  {standing_line(s)}", style=style, soft_wrap=True)
    if any(s.metrics for s in standings):
        out.print(_metrics_table(standings))
    for line in _legend(standings):
        out.print(line, soft_wrap=True)


#: Why a run that did not complete has no result.
RUN_ENDINGS = {
    "failed": "the service could not evaluate all of its episodes",
    "cancelled": "it was cancelled",
}


def standing_line(s: Standing) -> str:
    """A board's line: its score, rank and stable score with the board's intervals ("score 0.812 [0.790,
    0.835] · rank 2 (1–3) of 9 · stable 0.640 [0.612, 0.668]"), or why it has none."""
    if s.rank is not None:
        rank = f"rank {_rank(s.rank, s.rank_low, s.rank_high)} of {s.entries}"
        if s.rank_low is None:  # a large board between two full computations (docs/server.md)
            rank += " [dim](its rank interval comes with the board's next full computation)[/]"
        return (
            f"score {_fmt(s.score, 3)}{_ci(s.score_low, s.score_high)} · {rank} · "
            f"stable {_fmt(s.stable, 3)}{_ci(s.stable_low, s.stable_high)}"
        )
    if s.board_status in ("failed", "partial"):
        return (
            f"not ranked — {s.board_status}: {escape(s.reason or '')}; a failed or partial entry gets no "
            "score, rank or interval"
        )
    if s.status != "completed":
        why = RUN_ENDINGS.get(s.status, "it has not finished")
        return f"no result — {why}, so no score, rank or interval"
    return "not on its board yet (boards are recomputed in the background)"


def _metrics_table(standings: list[Standing]) -> Table:
    """Each board's metrics (means over its groups), the board's 95 % interval under each."""
    keys: list[str] = []
    for s in standings:
        keys += [k for k in s.metric_keys or list(s.metrics) if k not in keys]
    table = Table(title="metrics: mean over groups, 95 % interval under it")
    table.add_column("board")
    for k in keys:
        table.add_column(_label(k), justify="right")
    for s in standings:
        cells = []
        for k in keys:
            if k not in s.metrics:
                cells.append("")
                continue
            low, high = s.intervals.get(k) or (None, None)
            interval = _ci(low, high, digits=4).strip()
            cells.append(_fmt(s.metrics[k]) + (f"\n{interval}" if interval else ""))
        table.add_row(s.board, *cells)
    return table


def _legend(standings: list[Standing]) -> list[str]:
    """What the intervals and the two scores mean, in the boards' words (board page, docs/benchmark.md)."""
    ranked = [s for s in standings if s.rank is not None]
    if not ranked:
        return []
    groups = sorted({s.groups for s in ranked})
    over = f"the board's {groups[0]} groups" if len(groups) == 1 else "each board's groups"
    few = "; with few groups a figure can sit at an end of its interval" if groups[0] < 10 else ""
    level = f"{ranked[0].confidence * 100:.0f} %"
    return [
        escape(
            f"[low, high]: the bootstrap {level} interval over {over} ({ranked[0].resamples} seeded resamples"
            f"{few}). A rank “3 (2–5) of 14” is rank 3 of 14 ranked entries, and 2 to 5 in {level} of "
            f"resamples (a rank alone: that rank in {level} of them); entries whose rank intervals overlap "
            "are not clearly apart."
        ),
        "score: relative to the board's other entries (0 when alone on it); stable: against fixed anchors, "
        "it never moves when others arrive",
    ]


# -- submissions --------------------------------------------------------------------------------------
@submissions_app.command("list")
def list_command(
    limit: Annotated[int, typer.Option(min=1, max=200, help="How many, newest first.")] = 20,
    as_json: JsonOpt = False,
    server: ServerOpt = "http://127.0.0.1:8000",
    token: TokenOpt = None,
) -> None:
    """Your submissions, newest first."""
    with api_client(server, token) as client:
        subs = client.submissions(limit=limit)
    if as_json:
        print("[" + ",".join(s.model_dump_json() for s in subs) + "]")
        return
    table = Table(title="submissions")
    for col, justify in (
        ("id", "right"),
        ("name", "left"),
        ("status", "left"),
        ("track", "left"),
        ("boards", "left"),
        ("episodes", "right"),
        ("created", "left"),
    ):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for s in subs:
        boards = ", ".join(f"{r.setting}/{r.dataset}" for r in s.runs)
        done = f"{s.progress.episodes_done} / {s.progress.episodes_total}"
        table.add_row(
            str(s.id), escape(s.name), s.status, s.track, boards, done, f"{s.created_at:%Y-%m-%d %H:%M}"
        )
    table_console().print(table if subs else "no submissions yet")


@submissions_app.command("show")
def show_command(
    submission_id: IdArg,
    as_json: JsonOpt = False,
    server: ServerOpt = "http://127.0.0.1:8000",
    token: TokenOpt = None,
) -> None:
    """One submission: status, progress, and each board's metrics, score and rank."""
    with api_client(server, token) as client:
        sub = client.submission(submission_id)
        if as_json:
            print(sub.model_dump_json(indent=2))
            return
        standings = client.standings(sub)
    p = sub.progress
    err.print(
        f"#{sub.id} {escape(sub.name)} · {sub.status} · {p.episodes_done} / {p.episodes_total} episodes"
        + (f" · phase {p.phase}" if p.phase else "")
        + f" · {escape(sub.policy_url)}"
    )
    if sub.error:
        err.print(f"[red]{escape(sub.error)}[/]")
    _print_standings(sub, standings)
    _print_provenance(sub)


@submissions_app.command("cancel")
def cancel_command(
    submission_id: IdArg, server: ServerOpt = "http://127.0.0.1:8000", token: TokenOpt = None
) -> None:
    """Cancel an evaluation: its unfinished episodes are dropped."""
    with api_client(server, token) as client:
        sub = client.cancel(submission_id)
    print(f"submission {sub.id} {sub.status} ({sub.progress.episodes_cancelled} episodes cancelled)")


@submissions_app.command("episodes")
def episodes_command(
    submission_id: IdArg,
    as_json: JsonOpt = False,
    server: ServerOpt = "http://127.0.0.1:8000",
    token: TokenOpt = None,
) -> None:
    """Per-episode results and termination reasons."""
    with api_client(server, token) as client:
        rows = client.episodes(submission_id)
    if as_json:
        print("[" + ",".join(e.model_dump_json() for e in rows) + "]")
        return
    table_console().print(_episodes_table(submission_id, rows))


def _episodes_table(submission_id: int, rows: list[EpisodePublic]) -> Table:
    table = Table(title=f"episodes of #{submission_id}")
    for col in ("id", "board", "group", "status", "boxes", "Space Utilization", "termination", "detail"):
        table.add_column(
            col, justify="right" if col in ("id", "group", "boxes", "Space Utilization") else "left"
        )
    for e in rows:
        placed = "—" if e.boxes_placed is None else e.boxes_placed  # a running episode has its total only
        boxes = f"{placed} / {e.boxes_total}" if e.boxes_total is not None else "—"
        su = (e.metrics or {}).get("space_utilization")
        detail = escape((e.termination_detail or "")[:80])
        table.add_row(
            str(e.id),
            f"{e.setting}/{e.dataset}",
            str(e.group),
            e.status,
            boxes,
            _fmt(su),
            e.termination or "—",
            detail,
        )
    return table


# -- leaderboard --------------------------------------------------------------------------------------
def leaderboard(
    dataset: Annotated[
        str | None, typer.Option(help="repetitive, diverse or longboard (with --setting).")
    ] = None,
    setting: Annotated[str | None, typer.Option(help="math, physics or execution (with --dataset).")] = None,
    track: TrackOpt = "private",
    as_json: JsonOpt = False,
    view: Annotated[
        str, typer.Option(help="best: each participant's best entry; all: every entry.")
    ] = "best",
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format", help="csv (per entry, interval ends in columns), md or latex: a board or the grid."
        ),
    ] = None,
    out: Annotated[Path | None, typer.Option(help="With --format: write here instead of stdout.")] = None,
    wide: WideOpt = False,
    protocol: Annotated[
        str,
        typer.Option(
            help="Physics/Execution as closed (closed loop, the benchmark) or paper (the paper's "
            "protocol: the Math Pack actions replayed)."
        ),
    ] = CLOSED,
    lookahead: Annotated[
        int,
        typer.Option(
            min=0,
            max=10,
            help="The boards of submissions that saw this many next boxes (0: the leaderboard); "
            "each lookahead ranks apart, closed loop only.",
        ),
    ] = 0,
    server: ServerOpt = "http://127.0.0.1:8000",
    token: TokenOpt = None,
) -> None:
    """One leaderboard (metrics, score, rank), or the overall grid when no board is given."""
    from robobpp.vocabulary import LOOPS

    if protocol not in LOOPS:
        fail(f"unknown protocol {protocol!r}; expected one of {', '.join(LOOPS)}")
    if (dataset is None) != (setting is None):
        fail("give both --dataset and --setting for one board, or neither for the overall grid")
    if fmt is not None:
        from robobpp.export import FORMATS

        if fmt not in FORMATS:
            fail(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if view not in ("best", "all"):
        fail(f"unknown view {view!r}; expected best or all")
    if not has_boards(protocol, lookahead, setting):
        fail("the paper-protocol boards are lookahead 0 only; a lookahead K > 0 has closed-loop boards")
    if dataset is not None and dataset not in DATASETS:
        fail(f"unknown dataset {dataset!r}; expected one of {', '.join(DATASETS)}")
    if setting is not None and setting not in SETTINGS:
        fail(f"unknown setting {setting!r}; expected one of {', '.join(SETTINGS)}")
    with api_client(server, token, need_token=False) as client:
        data = (
            client.leaderboard(
                dataset, setting, parse_track(track), view=view, protocol=protocol, lookahead=lookahead
            )
            if dataset and setting
            else client.grid(parse_track(track), view=view, protocol=protocol, lookahead=lookahead)
        )
    if as_json:
        print(data.model_dump_json(indent=2))
        return
    from robobpp.schemas import Leaderboard

    if fmt is not None:
        from robobpp.cli.export import write
        from robobpp.export import render_board, render_grid

        render = render_board if isinstance(data, Leaderboard) else render_grid
        # the caption names the server and today's date: a relative score is only quotable with its board
        write(render(data.model_dump(mode="json"), fmt, server=server, wide=wide), out)
        return

    table_console().print(_board_table(data) if isinstance(data, Leaderboard) else _grid_table(data))
    if others := [k for k in data.lookaheads if k != data.lookahead]:  # each lookahead ranks apart
        listed = ", ".join(f"--lookahead {k}" for k in others)
        err.print(
            f"[dim]lookahead {data.lookahead} board; entries with another lookahead rank apart: {listed}[/]"
        )


def _who(name: str, participant: str, baseline: bool) -> str:
    return f"{escape(name)} [dim]({escape(participant)}{', baseline' if baseline else ''})[/]"


def _ci(low: float | None, high: float | None, digits: int = 3) -> str:
    """A 95 % interval after its figure: " [0.790, 0.835]" (dimmed); empty when the board has none."""
    return "" if low is None or high is None else f" [dim][{_fmt(low, digits)}, {_fmt(high, digits)}][/]"


def _rank(rank: int | None, low: int | None, high: int | None) -> str:
    if rank is None:
        return "—"
    return str(rank) if low is None or low == high == rank else f"{rank} [dim]({low}–{high})[/]"


def _board_table(board: Leaderboard) -> Table:
    """Ranks with their 95 % rank interval, scores with their bootstrap interval, failed/partial apart."""
    protocol = " · paper protocol" if board.protocol == PAPER else ""
    protocol += f" · lookahead {board.lookahead}" if board.lookahead else ""
    table = Table(
        title=f"{board.setting}/{board.dataset}{protocol} · {board.track} track · {board.view} "
        f"({board.total} ranked, by the {board.ranked_by} score)"
    )
    table.add_column("rank", justify="right")
    table.add_column("submission")
    for k in board.metrics:
        table.add_column(f"{_label(k)} ({board.weights.get(k, 0):g})", justify="right")
    pph = any("pph" in e.extras for e in board.entries)
    if pph:
        table.add_column("PPH", justify="right")
    table.add_column("score [95 % CI]", justify="right")
    table.add_column("stable", justify="right")
    for e in board.entries:
        cells = [_fmt(e.metrics.get(k)) for k in board.metrics]
        if pph:
            cells.append(_fmt(e.extras.get("pph"), 1))
        of = (
            f" [dim]({'best' if e.best else 'one'} of {e.entries_submitted})[/]"
            if e.entries_submitted > 1
            else ""
        )
        table.add_row(
            _rank(e.rank, e.rank_low, e.rank_high),
            f"#{e.submission_id} " + _who(e.name, e.participant, e.baseline) + of,
            *cells,
            _fmt(e.score, 3) + _ci(e.score_low, e.score_high),
            _fmt(e.stable, 3),
            style="bold green" if e.rank == 1 else None,
        )
    for u in board.unranked:
        table.add_row(
            u.status,
            f"#{u.submission_id} " + _who(u.name, u.participant, u.baseline),
            *[_fmt(u.metrics.get(k)) for k in board.metrics],
            *([""] if pph else []),
            "—",
            "—",
            style="dim",
        )
    if not board.entries:
        table.caption = "no completed submissions on this board yet"
    elif board.total > len(board.entries):
        table.caption = (
            f"first {len(board.entries)} of {board.total}; use --json or the API's offset for more"
        )
    return table


def _grid_table(grid: OverallGrid) -> Table:
    """Score (rank) per board and the Mean with intervals; partial or failed submissions after, unranked."""
    protocol = " · Physics/Execution under the paper protocol" if grid.protocol == PAPER else ""
    protocol += f" · lookahead {grid.lookahead}" if grid.lookahead else ""
    table = Table(title=f"overall{protocol} · {grid.track} track · {grid.view}")
    table.add_column("rank", justify="right")
    table.add_column("submission")
    boards = [f"{s}/{d}" for s in grid.settings for d in grid.datasets]
    for b in boards:
        table.add_column(b, justify="right")
    table.add_column("mean [95 % CI]", justify="right")
    for row in [*grid.rows, *grid.apart]:
        cells = []
        for b in boards:
            c = row.cells.get(b)
            text = row.unranked.get(b, "—") if c is None else f"{c.score:.3f} ({c.rank})"
            cells.append(f"[bold]{text}[/]" if c is not None and c.rank <= 4 else text)
        mean = row.status if row.mean is None else f"{row.mean:.3f}" + _ci(row.mean_low, row.mean_high)
        table.add_row(
            _rank(row.rank, row.rank_low, row.rank_high),
            f"#{row.submission_id} " + _who(row.name, row.participant, row.baseline),
            *cells,
            mean,
        )
    if not grid.rows and not grid.apart:
        table.caption = "no completed submissions yet"
    return table
