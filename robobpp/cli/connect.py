"""``robobpp connect``: pull mode — the policy connects out to the server, so it needs no public URL."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from robobpp.cli.common import fail, import_from_cwd
from robobpp.cli.submit import (
    BoardDatasetsOpt,
    BoardSettingsOpt,
    LookaheadOpt,
    ServerOpt,
    TokenOpt,
    TrackOpt,
    err,
    parse_names,
    parse_track,
)
from robobpp.vocabulary import DATASETS, SETTINGS

if TYPE_CHECKING:
    from robobpp.schemas import SubmissionPublic


def connect_command(
    policy: Annotated[
        str, typer.Argument(help="module:Class of your policy, or a built-in name (dbl, ...).")
    ],
    submission: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=2**31 - 1,
            help="Join this pull submission (e.g. after a restart) instead of creating one.",
        ),
    ] = None,
    parallel: Annotated[int, typer.Option(min=1, max=64, help="Episodes served at once (connections).")] = 1,
    secret: Annotated[
        str | None,
        typer.Option(envvar="ROBOBPP_POLICY_SECRET", help="Refuse requests not signed with this secret."),
    ] = None,
    name: Annotated[str | None, typer.Option(help="Name on the leaderboard (default: the policy's).")] = None,
    dataset: BoardDatasetsOpt = None,
    setting: BoardSettingsOpt = None,
    track: TrackOpt = "private",
    lookahead: LookaheadOpt = 0,
    server: ServerOpt = "http://127.0.0.1:8000",
    token: TokenOpt = None,
) -> None:
    """Evaluate a policy in pull mode: open outbound connections to the server and serve its episodes
    through them until the submission finishes (works behind NAT and firewalls; no port to open)."""
    from robobpp.cli.progress import LineProgress
    from robobpp.cli.submit import exit_unless_completed, print_results, progress_task
    from robobpp.client.api import ServerClient, ServerError
    from robobpp.client.connect import connect
    from robobpp.policies import PolicyLoadError, load_policy

    if not (token or "").strip():
        fail("no API token: pass --token or set ROBOBPP_TOKEN", code=2)
    if policy.startswith(("http://", "https://")):
        fail("give the policy as module:Class (or a built-in name): pull mode runs it here, not at a URL")
    import_from_cwd(policy)
    try:
        load_policy(policy)  # fail here, in plain words, rather than in every connection
    except PolicyLoadError as exc:
        fail(str(exc))
    datasets = parse_names(dataset, DATASETS, "dataset")
    settings = parse_names(setting, SETTINGS, "setting")

    def factory() -> object:  # one instance per connection: --parallel episodes run side by side
        return load_policy(policy)

    progress = LineProgress(err)  # plain lines off a terminal too, as submit --wait prints them
    tasks: list[Callable[[SubmissionPublic], None]] = []

    def show(sub: SubmissionPublic) -> None:
        if not tasks:
            tasks.append(progress_task(progress, sub))
        tasks[0](sub)

    try:
        with progress:
            final = connect(
                factory,
                server,
                token or "",
                submission=submission,
                secret=secret,
                name=name,
                datasets=datasets,
                settings=settings,
                track=parse_track(track),
                lookahead=lookahead,
                parallel=parallel,
                on_event=lambda m: progress.console.print(escape(m), soft_wrap=True),
                on_progress=show,
            )
        with ServerClient(server, token) as client:
            print_results(client, final)
    except ServerError as exc:
        fail(escape(str(exc)), code=1)
    except KeyboardInterrupt:
        err.print(
            "stopped; the episodes in flight wait for the client to come back (robobpp connect --submission)"
        )
        raise typer.Exit(130) from None
    exit_unless_completed(final)


def register(root: typer.Typer) -> None:
    root.command("connect")(connect_command)
