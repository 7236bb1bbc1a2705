"""``robobpp view TRACE.json``: look at episodes in 3D on your own machine, no evaluation server needed."""

from __future__ import annotations

import socket
import threading
import webbrowser
from pathlib import Path
from typing import Annotated, Any

import typer

app = typer.Typer(no_args_is_help=True)


def register(root: typer.Typer) -> None:
    root.command("view")(view)


def view(
    trace: Annotated[
        Path, typer.Argument(help="A trace file from `robobpp evaluate --trace`, or one episode's JSON.")
    ],
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Write one self-contained HTML file here instead of serving."),
    ] = None,
    host: Annotated[str, typer.Option(help="Address to serve on (loopback by default).")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="Port to serve on; 0 picks a free one.")] = 0,
    open_browser: Annotated[
        bool, typer.Option("--open/--no-open", help="Open the page in a browser.")
    ] = True,
) -> None:
    """Replay the episodes of a trace file in a 3D viewer (served locally, or written to one HTML file)."""
    from robobpp.web.trace import TraceError, read_trace

    try:
        episodes = read_trace(trace)
    except TraceError as exc:
        typer.secho(f"error: {exc}", err=True, fg=typer.colors.RED)
        raise typer.Exit(2) from None
    if output is not None:
        from robobpp.web.viewer import render_standalone

        try:
            output.write_text(render_standalone(episodes, source=trace.name), encoding="utf-8")
        except OSError as exc:
            typer.secho(f"error: cannot write {output}: {exc.strerror or exc}", err=True, fg=typer.colors.RED)
            raise typer.Exit(2) from None
        url = output.resolve().as_uri()
        typer.echo(f"wrote {len(episodes)} episode(s) to {output}: {url}")
        if open_browser:
            webbrowser.open(url)
        return
    _serve(episodes, trace.name, host, port, open_browser)


def _serve(episodes: list[dict[str, Any]], source: str, host: str, port: int, open_browser: bool) -> None:
    import uvicorn

    from robobpp.web.viewer import view_app

    if port == 0:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind((host, 0))
            port = s.getsockname()[1]
    url = f"http://{host}:{port}/"
    typer.echo(f"serving {len(episodes)} episode(s) from {source} at {url} (Ctrl+C to stop)")
    if open_browser:
        # Opened a moment later, from a thread: uvicorn.run blocks, and the page needs the server up.
        threading.Timer(0.8, webbrowser.open, args=(url,)).start()
    uvicorn.run(view_app(episodes, source), host=host, port=port, log_level="warning")
