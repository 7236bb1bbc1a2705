"""What an app keeps for its lifetime (``app.state``), typed, and every part of it made when the app is built.

:func:`robobpp.server.app.create_app` makes an :class:`AppState` and sets each attribute before the app serves
(the lifespan replaces the board cache when it starts a board worker); routes, pages and
services read it through :func:`state_of`, so a name misspelt or a part never made fails mypy, not a request.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

from starlette.datastructures import State

if TYPE_CHECKING:  # types only: each part is made by create_app, which imports its module
    from prometheus_client import CollectorRegistry
    from starlette.applications import Starlette

    from robobpp.boards.reader import BoardCache
    from robobpp.boards.worker import BoardWorker, WorkerProcess
    from robobpp.server.config import Settings
    from robobpp.server.probes import ProbeGate
    from robobpp.server.ratelimit import AuthLimits
    from robobpp.server.relay_hub import PullHub
    from robobpp.server.runtime import Runtime
    from robobpp.server.services.submissions import FinishedViews


class AppState(State):
    """``app.state`` of a robobpp app. Starlette's :class:`~starlette.datastructures.State` keeps the values;
    this class only declares them."""

    settings: Settings
    #: The database and the executor of this process.
    runtime: Runtime
    #: Submit-time ``GET /info`` checks at once (server/probes.py).
    probe_gate: ProbeGate
    #: Wrong tokens per client address and token prefix (server/ratelimit.py).
    auth_limit: AuthLimits
    #: Finished submissions' views, kept while they cannot change (services/submissions.py).
    finished_views: FinishedViews
    #: The operator page's participant rows and the version of the data they were read at.
    operator_rows: tuple[tuple[Any, ...], tuple[Any, ...]] | None
    #: The pull relay's hub (its bus is started by the first client connection).
    pull_hub: PullHub
    #: The reader of the published boards (services/boards.py).
    board_cache: BoardCache
    #: This process's candidate board worker, when it runs one (set by the lifespan).
    board_worker: BoardWorker | WorkerProcess | None
    #: The ``/metrics`` collectors of this app (server/prometheus.py).
    metrics_registry: CollectorRegistry
    #: Pages that change only with the deployment (server/pages.py), rendered once per key.
    static_pages: dict[tuple[Any, ...], bytes]


def state_of(app: Starlette) -> AppState:
    """``app.state``, typed (create_app made it an :class:`AppState`)."""
    return cast(AppState, app.state)
