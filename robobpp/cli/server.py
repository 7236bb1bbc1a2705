"""``robobpp serve`` (the evaluation service) and ``robobpp db upgrade`` (apply migrations)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

db_app = typer.Typer(no_args_is_help=True, help="Database schema (Alembic migrations).")

#: Groups per dataset of the demo's boards (the real leaderboard has 30).
DEMO_GROUPS = 2
#: Boxes of each demo episode: the first ones of the group (the physical episodes of a full group take minutes).
DEMO_BOXES = 40
#: The demo's settings, those of them whose simulator imports: Execution Pack (a robot arm's motion planning)
#: would take most of the demo's time (BENCHMARKS.md, "The demo's first minutes").
DEMO_SETTINGS = ("math", "physics")


def demo_overrides(state_dir: Path) -> dict[str, Any]:
    """Two groups per dataset and their first boxes, the private track only, Math and Physics Pack, private URLs
    allowed: every baseline is ranked within minutes (BENCHMARKS.md, "The demo's first minutes")."""
    from robobpp.server.config import Settings

    available = Settings(settings=()).enabled_settings
    return {
        "demo": True,
        "groups": DEMO_GROUPS,
        "max_boxes": DEMO_BOXES,
        "settings": tuple(s for s in available if s in DEMO_SETTINGS),
        "public_baselines": False,
        "allow_private_policy_urls": True,
        "private_dir": state_dir / "private-demo",
    }


def serve(
    demo: Annotated[
        bool,
        typer.Option(
            "--demo",
            help="A demo board: 2 groups, 40 boxes, Math and Physics: every baseline ranked in minutes",
        ),
    ] = False,
    host: Annotated[str, typer.Option(help="Interface to bind (0.0.0.0 for other machines)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port")] = 8000,
    workers: Annotated[
        int | None, typer.Option(help="Local worker processes (default: ROBOBPP_WORKERS or 2)")
    ] = None,
    state_dir: Annotated[
        Path | None, typer.Option(help="Where the SQLite file lives (ROBOBPP_STATE_DIR)")
    ] = None,
    server_workers: Annotated[
        int,
        typer.Option(
            min=1,
            max=256,
            help="API processes on the port (more than 1 needs Redis for pull mode: docs/deploy.md)",
        ),
    ] = 1,
) -> None:
    """Run the evaluation service: API, pages, migrations at start, baselines, local workers."""
    from robobpp.extras import require

    for package in (
        "sqlalchemy",
        "alembic",
        "pydantic_settings",
        "prometheus_client",
        "multipart",
        "itsdangerous",
    ):
        require(package, "server", "robobpp serve")
    from pydantic import ValidationError

    from robobpp import logs
    from robobpp.cli.common import fail, settings_problem
    from robobpp.client.serve import run_server
    from robobpp.server.app import create_app
    from robobpp.server.config import Settings

    logs.configure()
    overrides: dict[str, Any] = {}
    if state_dir is not None:
        overrides["state_dir"] = state_dir
    if workers is not None:
        overrides["workers"] = workers
    try:
        base = Settings(**overrides)
        if demo:
            overrides.update(demo_overrides(base.state_dir))
        if not base.pull_relay_url:  # the local workers reach the pull relay on this very server
            overrides["pull_relay_url"] = (
                f"http://{'127.0.0.1' if host in ('0.0.0.0', '::', '') else host}:{port}"
            )
        settings = Settings(**overrides)
    except (ValidationError, ValueError) as exc:
        fail(f"invalid settings: {settings_problem(exc)}")
    where = "ROBOBPP_ADMIN_TOKEN" if settings.admin_token else str(settings.state_dir / "admin_token")

    def ready(url: str) -> None:  # after migrations, baselines and workers: a reader may connect at once
        processes = f" from {server_workers} API processes" if server_workers > 1 else ""
        typer.echo(f"robobpp: serving on {url}{processes} (API docs {url}/docs); admin token: {where}")

    if server_workers > 1:
        from robobpp.server.processes import StartFailed, refusal, serve_processes

        problem = refusal(settings, server_workers)
        if problem:
            fail(problem)
        settings.effective_admin_token  # noqa: B018 - dev: the generated token is written once, here
        try:
            serve_processes(settings, overrides, host, port, server_workers, ready)
        except (StartFailed, OSError) as exc:  # OSError: the port is taken, or the host is not ours
            fail(str(exc))
        return
    app = create_app(settings)
    from robobpp.server.connections import server_config

    run_server(
        app,
        host,
        port,
        ready,
        log_level="info",
        log_config=logs.uvicorn_log_config(),
        access_log=False,
        **server_config(settings),
    )


@db_app.command("upgrade")
def db_upgrade(revision: Annotated[str, typer.Argument(help="Target revision")] = "head") -> None:
    """Apply migrations to ROBOBPP_DATABASE_URL (or the embedded SQLite file)."""
    from pydantic import ValidationError

    from robobpp.cli.common import fail, settings_problem
    from robobpp.db.migrate import upgrade
    from robobpp.db.session import make_engine
    from robobpp.server.config import Settings

    try:
        settings = Settings()
    except (ValidationError, ValueError) as exc:
        fail(f"invalid settings: {settings_problem(exc)}")
    if not settings.database_url:
        settings.state_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.sqlalchemy_url)
    try:
        upgrade(settings.sqlalchemy_url, revision, engine=engine)
    finally:
        engine.dispose()
    typer.echo(f"database at {engine.url.render_as_string(hide_password=True)} is at revision {revision}")


@db_app.command("refresh-boards")
def db_refresh_boards(
    track: Annotated[str | None, typer.Option(help="Only this track (private or public)")] = None,
) -> None:
    """Ask the board worker to recompute the boards although no submission finished (the published boards
    stay served until it has)."""
    from pydantic import ValidationError

    from robobpp.boards.worker import request_recompute
    from robobpp.cli.common import fail, settings_problem
    from robobpp.db.session import make_engine, make_session_factory, transaction
    from robobpp.server.config import Settings

    try:
        settings = Settings()
    except (ValidationError, ValueError) as exc:
        fail(f"invalid settings: {settings_problem(exc)}")
    engine = make_engine(settings.sqlalchemy_url)
    try:
        with transaction(make_session_factory(engine)) as session:
            marked = request_recompute(session, track)
    finally:
        engine.dispose()
    typer.echo(f"asked the board worker to recompute {marked} track(s)")


def register(root: typer.Typer) -> None:
    root.command("serve")(serve)
    root.add_typer(db_app, name="db")
