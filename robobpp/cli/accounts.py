"""`robobpp participants` and `robobpp tokens`: accounts on the evaluation server, from a shell.

Creating participants and issuing tokens needs the admin token (``ROBOBPP_ADMIN_TOKEN`` on the server, or the
``admin_token`` file in its state folder in dev); listing and revoking work with a participant's own token.
"""

from __future__ import annotations

from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from robobpp.cli.common import table_console
from robobpp.cli.submit import JsonOpt, ServerOpt, TokenOpt, api_client, err

participants_app = typer.Typer(no_args_is_help=True, help="Participants of the evaluation server (admin).")
tokens_app = typer.Typer(no_args_is_help=True, help="API tokens: list and revoke.")
SERVER = "http://127.0.0.1:8000"


def register(root: typer.Typer) -> None:
    root.add_typer(participants_app, name="participants")
    root.add_typer(tokens_app, name="tokens")


def _show_new_token(created: object, as_json: bool) -> None:
    from robobpp.schemas import TokenCreated

    assert isinstance(created, TokenCreated)
    if as_json:
        print(created.model_dump_json(indent=2))
        return
    err.print(
        f"participant #{created.participant.id} {escape(created.participant.name)} · token #{created.id}"
    )
    err.print("[yellow]the token is shown once; store it now (the server keeps only its hash):[/]")
    print(created.token)  # alone on stdout, so `TOKEN=$(robobpp participants create alice)` works


@participants_app.command("create")
def create_command(
    name: Annotated[str, typer.Argument(help="The participant's public name (shown on the leaderboard).")],
    as_json: JsonOpt = False,
    server: ServerOpt = SERVER,
    token: TokenOpt = None,
) -> None:
    """Create a participant and print its first API token (admin token needed)."""
    with api_client(server, token) as client:
        created = client.create_participant(name)
    _show_new_token(created, as_json)


@participants_app.command("new-token")
def new_token_command(
    participant_id: Annotated[int, typer.Argument(min=1, max=2**31 - 1, help="Participant id.")],
    as_json: JsonOpt = False,
    server: ServerOpt = SERVER,
    token: TokenOpt = None,
) -> None:
    """Issue another API token for a participant (admin token needed)."""
    with api_client(server, token) as client:
        created = client.issue_token(participant_id)
    _show_new_token(created, as_json)


@tokens_app.command("list")
def list_command(as_json: JsonOpt = False, server: ServerOpt = SERVER, token: TokenOpt = None) -> None:
    """Your tokens (the admin sees every participant's): prefix, created, revoked."""
    with api_client(server, token) as client:
        rows = client.tokens()
    if as_json:
        print("[" + ",".join(r.model_dump_json() for r in rows) + "]")
        return
    table = Table(title="API tokens")
    for column in ("id", "participant", "prefix", "created", "revoked"):
        table.add_column(column, justify="right" if column in ("id", "participant") else "left")
    for r in rows:
        revoked = f"{r.revoked_at:%Y-%m-%d %H:%M}" if r.revoked_at else "—"
        table.add_row(
            str(r.id), str(r.participant_id), f"{r.prefix}…", f"{r.created_at:%Y-%m-%d %H:%M}", revoked
        )
    table_console().print(table)


@tokens_app.command("revoke")
def revoke_command(
    token_id: Annotated[
        int, typer.Argument(min=1, max=2**31 - 1, help="Token id (see `robobpp tokens list`).")
    ],
    server: ServerOpt = SERVER,
    token: TokenOpt = None,
) -> None:
    """Revoke a token: it stops working at once."""
    with api_client(server, token) as client:
        row = client.revoke_token(token_id)
    print(f"token {row.id} ({row.prefix}…) revoked")
