"""The episode replay outside the server: a self-contained HTML file, or a tiny local web app.

Both use the same template fragment and ``static/js/replay.js`` as the server's replay page, so what a
participant sees offline after ``robobpp evaluate --trace`` is what the leaderboard shows.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

from markupsafe import Markup

from robobpp.web import STATIC_DIR, environment


def heading_for(episodes: list[dict[str, Any]], source: str) -> str:
    if len(episodes) == 1:
        ep = episodes[0]
        return f"{ep['policy'] or 'policy'} · {ep['dataset']} · {ep['setting']} · group {ep['group']}"
    return f"{len(episodes)} episodes from {source}"


def _data_url(path: Path) -> str:
    return "data:text/javascript;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def render_standalone(episodes: list[dict[str, Any]], source: str = "trace") -> str:
    """One HTML file holding the viewer, three.js and the trace; opens from disk (``file://``)."""
    vendor = STATIC_DIR / "vendor" / "three"
    return (
        environment()
        .get_template("view_standalone.html")
        .render(
            heading=heading_for(episodes, source),
            source=source,
            episodes=episodes,
            # Our own static files, not user data: inlined as-is (HTML-escaping would corrupt them).
            css=Markup((STATIC_DIR / "css" / "robobpp.css").read_text(encoding="utf-8")),
            replay_js=Markup((STATIC_DIR / "js" / "replay.js").read_text(encoding="utf-8")),
            three_url=_data_url(vendor / "three.module.min.js"),
            controls_url=_data_url(vendor / "OrbitControls.js"),
            robot_url=_data_url(STATIC_DIR / "js" / "robot.js"),
            info_url=_data_url(STATIC_DIR / "js" / "replay_info.js"),
        )
    )


def render_replay_page(
    episodes: list[dict[str, Any]],
    *,
    heading: str,
    static: str = "/static",
    root: str = "",
    crumbs: list[tuple[str, str]] | None = None,
    show_nav: bool = True,
) -> str:
    """The replay page with the site's layout (server, and ``robobpp view``'s local server)."""
    return (
        environment()
        .get_template("replay.html")
        .render(
            title=heading,
            heading=heading,
            episodes=episodes,
            static=static,
            root=root,
            crumbs=crumbs or [],
            show_nav=show_nav,
            nav="",
        )
    )


def view_app(episodes: list[dict[str, Any]], source: str) -> Any:
    """A one-page FastAPI app serving the viewer for ``robobpp view`` (imported lazily: CLI stays light)."""
    from fastapi import FastAPI
    from fastapi.responses import HTMLResponse
    from fastapi.staticfiles import StaticFiles

    app = FastAPI(title="robobpp view", docs_url=None, redoc_url=None, openapi_url=None)
    page = render_replay_page(episodes, heading=heading_for(episodes, source), show_nav=False)

    @app.get("/", response_class=HTMLResponse)
    def index() -> str:
        return page

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    return app
