"""The ``robobpp`` command. Each area registers its commands from its own module in this package."""

from __future__ import annotations

from typing import Annotated

import typer

app = typer.Typer(
    name="robobpp",
    help="Closed-loop benchmark and evaluation service for robotic online 3D bin packing.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _show_version(value: bool) -> None:
    if value:
        from robobpp.provenance import version_line

        typer.echo(version_line())
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option(
            "--version",
            callback=_show_version,
            is_eager=True,
            help="Print robobpp's version (and git commit when run from a checkout) and exit.",
        ),
    ] = False,
) -> None:
    """Closed-loop benchmark and evaluation service for robotic online 3D bin packing."""


def register_commands() -> None:
    """Add every area's commands to :data:`app` (``main`` does; so do tests that drive the whole CLI)."""
    # Imported here so `robobpp --help` stays fast and each area owns its own module.
    from robobpp.cli import (
        accounts,
        compare,
        connect,
        datasets,
        evaluate,
        export,
        protocol,
        reproduce,
        server,
        submit,
        view,
        worker,
    )

    app.add_typer(datasets.app, name="datasets")
    evaluate.register(app)
    compare.register(app)
    export.register(app)
    protocol.register(app)
    reproduce.register(app)
    server.register(app)
    submit.register(app)
    connect.register(app)
    accounts.register(app)
    view.register(app)
    worker.register(app)


def main() -> None:
    from robobpp.extras import MissingExtraError, missing_extra

    register_commands()
    try:
        app()
    except MissingExtraError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise SystemExit(2) from None
    except ModuleNotFoundError as exc:  # a command reached a package only an extra installs
        known = missing_extra(exc)
        if known is None:
            raise
        typer.echo(f"error: {known}", err=True)
        raise SystemExit(2) from None
