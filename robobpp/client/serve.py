"""The SDK's policy server: a participant writes ``act`` (optionally ``reset``/``close``), this does the rest.

Requests arrive as ``robobpp/1`` JSON; the server checks the signature (when a secret is set), validates
the message strictly, rebuilds the very :class:`~robobpp.core.Observation` the policy would get
in-process (heightmap from ``placed``) and answers the policy's :class:`~robobpp.core.Action`.

The handlers are ``async`` and call the policy directly, so the policy sees one request at a time, in
arrival order: a stateful policy needs no locks. (It also means a slow ``act`` delays every other
request; run one server per concurrent evaluation if that matters.)
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Protocol

from fastapi import FastAPI, Request
from fastapi.openapi.utils import get_openapi
from fastapi.responses import Response
from pydantic import BaseModel, ValidationError

from robobpp import protocol as P
from robobpp.client.remote import describe_validation
from robobpp.core import Action, ContainerSpec, Observation
from robobpp.policies.base import Policy

#: Episodes whose container the server remembers (for callers that omit it from /act).
_EPISODE_MEMORY = 1024


def _json(data: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode()
    return Response(body, status_code=status, media_type="application/json", headers=headers)


_EMPTY = Response(b"{}", media_type="application/json")


def _error(status: int, error: str, detail: str) -> Response:
    return _json({"error": error, "detail": detail}, status)


def _request_doc(model: type[BaseModel]) -> dict[str, Any]:
    ref = {"$ref": f"#/components/schemas/{model.__name__}"}
    return {"requestBody": {"required": True, "content": {"application/json": {"schema": ref}}}}


def _responses(model: type[BaseModel]) -> dict[int | str, dict[str, Any]]:
    return {
        200: {"model": model, "description": "success"},
        401: {"model": P.ErrorResponse, "description": "missing, wrong or stale signature"},
        422: {"model": P.ErrorResponse, "description": "the request breaks robobpp/1"},
        500: {"model": P.ErrorResponse, "description": "the policy raised an error"},
    }


class Acting(Protocol):
    """What the server needs of a policy: ``act``; ``reset`` and ``close`` are called when present."""

    def act(self, obs: Observation) -> Action | None: ...


def create_policy_app(
    policy: Policy | Acting | type,
    secret: str | None = None,
    *,
    name: str | None = None,
    version: str | None = None,
    replay_window_s: float = P.DEFAULT_REPLAY_WINDOW_S,
) -> FastAPI:
    """A FastAPI app serving ``policy`` over ``robobpp/1`` (a class is instantiated without arguments).

    ``/info`` names it ``name`` (default: the policy's ``name`` attribute, else its class) at ``version``
    (default: the policy's ``version`` attribute, else "0"): what ``robobpp evaluate`` and ``compare`` label
    its results with."""
    served: Policy | Acting = policy() if isinstance(policy, type) else policy
    if not callable(getattr(served, "act", None)):
        raise TypeError(f"{type(served).__name__} has no act(observation) method")
    shown_name = str(name or getattr(served, "name", None) or type(served).__name__)[: P.MAX_TEXT]
    version = str(version or getattr(served, "version", None) or P.UNREPORTED_VERSION)[: P.MAX_TEXT]
    info = {"protocol": P.PROTOCOL, "name": shown_name, "version": version}
    # Per episode: its container (from /reset) and its last observation (for the incremental heightmap).
    episodes: OrderedDict[str, tuple[ContainerSpec, Observation | None]] = OrderedDict()

    def remember(episode_id: str, container: ContainerSpec, obs: Observation | None) -> None:
        episodes[episode_id] = (container, obs)
        episodes.move_to_end(episode_id)
        while len(episodes) > _EPISODE_MEMORY:
            episodes.popitem(last=False)

    app = FastAPI(
        title=f"robobpp policy server ({shown_name})",
        version=version,
        description=f"Serves a packing policy over protocol {P.PROTOCOL}.",
    )

    async def read(request: Request, model: type[P.Message]) -> P.Message | Response:
        body = await request.body()
        if secret is not None:
            try:
                P.verify(secret, request.headers, body, window_s=replay_window_s)
            except P.SignatureError as exc:
                return _error(401, "unauthorized", str(exc))
        if model is P.EmptyResponse:  # GET /info carries no body
            return P.EmptyResponse()
        try:
            return model.model_validate_json(body)
        except ValidationError as exc:
            return _error(422, "invalid_request", describe_validation(exc))

    def answer(
        request: Request, data: dict[str, Any], episode_id: str = "", step: int | None = None
    ) -> Response:
        """A 200 answer; with a secret, signed for the request it answers (episode, step, its signature)."""
        if secret is None:
            return _json(data)
        body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode()
        headers = P.sign_answer(
            secret,
            episode_id=episode_id,
            step=step,
            body=body,
            request_signature=request.headers.get(P.SIGNATURE_HEADER, ""),
        )
        return Response(body, media_type="application/json", headers=headers)

    def call_hook(hook: str, *args: object) -> Response | None:
        method = getattr(served, hook, None)
        if not callable(method):
            return None
        try:
            method(*args)
        except Exception as exc:  # noqa: BLE001 - report the policy's failure to the caller
            return _error(500, "policy_error", f"{hook} raised {type(exc).__name__}: {exc}")
        return None

    @app.get("/info", responses=_responses(P.InfoResponse), openapi_extra={})
    async def get_info(request: Request) -> Response:
        checked = await read(request, P.EmptyResponse)
        return checked if isinstance(checked, Response) else answer(request, info)

    @app.post("/reset", responses=_responses(P.EmptyResponse), openapi_extra=_request_doc(P.ResetRequest))
    async def reset(request: Request) -> Response:
        req = await read(request, P.ResetRequest)
        if isinstance(req, Response):
            return req
        assert isinstance(req, P.ResetRequest)
        episode = P.info_from_reset(req)
        remember(req.episode_id, episode.container, None)
        return call_hook("reset", episode) or answer(request, {}, req.episode_id)

    @app.post("/act", responses=_responses(P.ActResponse), openapi_extra=_request_doc(P.ActRequest))
    async def act(request: Request) -> Response:
        req = await read(request, P.ActRequest)
        if isinstance(req, Response):
            return req
        assert isinstance(req, P.ActRequest)
        container, previous = episodes.get(req.episode_id, (None, None))
        try:
            obs = P.observation_from_act(req, container, previous)
        except ValueError as exc:
            return _error(422, "invalid_request", str(exc))
        remember(req.episode_id, obs.container, obs)
        started = time.perf_counter()
        try:
            action = served.act(obs)
        except Exception as exc:  # noqa: BLE001
            return _error(500, "policy_error", f"act raised {type(exc).__name__}: {exc}")
        elapsed = time.perf_counter() - started
        if action is not None and not isinstance(action, Action):
            return _error(
                500, "policy_error", f"act returned {type(action).__name__}, expected Action or None"
            )
        try:
            return answer(request, P.response_from_action(action, elapsed), req.episode_id, req.step)
        except (TypeError, ValueError) as exc:  # NaN or a non-number in the policy's own action
            return _error(500, "policy_error", f"act returned an action that is not finite numbers: {exc}")

    @app.post("/echo", responses={200: {"model": P.EmptyResponse, "description": "at once"}})
    async def echo() -> Response:
        """The evaluator's network probe: answered at once, body unread (docs/protocol.md, Decision time)."""
        return _EMPTY

    @app.post("/close", responses=_responses(P.EmptyResponse), openapi_extra=_request_doc(P.CloseRequest))
    async def close(request: Request) -> Response:
        req = await read(request, P.CloseRequest)
        if isinstance(req, Response):
            return req
        assert isinstance(req, P.CloseRequest)
        episodes.pop(req.episode_id, None)
        return call_hook("close", req.reason) or answer(request, {}, req.episode_id)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = get_openapi(
                title=app.title, version=app.version, description=app.description, routes=app.routes
            )
            defs = P.json_schema(ref_template="#/components/schemas/{model}")["$defs"]
            schema.setdefault("components", {}).setdefault("schemas", {}).update(defs)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    return app


def run_server(app: Any, host: str, port: int, on_ready: Callable[[str], None], **config: Any) -> None:
    """Serve ``app`` with uvicorn in this thread until interrupted; ``on_ready(url)`` is called once the
    socket accepts connections (after the app's start-up), with the port actually bound (``port=0``: a free one).

    Saying "serving on" earlier sends a reader who connects at once to a refused connection.
    """
    import uvicorn

    class _Announcing(uvicorn.Server):
        async def startup(self, sockets: list[socket.socket] | None = None) -> None:
            await super().startup(sockets=sockets)
            if self.started:
                bound = self.servers[0].sockets[0].getsockname()[1]
                on_ready(f"http://{f'[{host}]' if ':' in host else host}:{bound}")

    _Announcing(uvicorn.Config(app, host=host, port=port, **config)).run()


def serve(
    policy: Policy | Acting | type,
    host: str = "127.0.0.1",
    port: int = 9000,
    secret: str | None = None,
    *,
    name: str | None = None,
    version: str | None = None,
    log_level: str = "warning",
) -> None:
    """Serve ``policy`` until interrupted (Ctrl-C). Bind ``host="0.0.0.0"`` to accept other machines.

    Prints one line on stdout once it accepts connections: the policy's name and the URL to give
    ``robobpp evaluate --policy``, ``robobpp protocol check`` or ``robobpp submit``. ``/info`` carries the
    policy's ``name`` and ``version`` attributes unless ``name``/``version`` are given.
    """
    app = create_policy_app(policy, secret, name=name, version=version)
    label = name or getattr(policy, "name", None) or getattr(policy, "__name__", "policy")
    signed = "signed requests only" if secret else "no secret: anyone who can reach it may call it"

    def ready(url: str) -> None:
        print(f"robobpp: serving policy {label!r} on {url} ({signed}); Ctrl-C stops", flush=True)

    run_server(app, host, port, ready, log_level=log_level, access_log=False)


class BackgroundServer:
    """An ASGI app served by uvicorn in a thread on a free loopback port (tests, benchmarks, ``check``).

    Use as a context manager; :attr:`url` is the base URL. Leaving the block stops the server and
    closes its connections.
    """

    def __init__(self, app: Any, host: str = "127.0.0.1", port: int = 0, **config: Any) -> None:
        import uvicorn

        self._sock = socket.socket(
            socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP
        )  # asyncio sets TCP_NODELAY only then
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind((host, port))
        self.host, self.port = self._sock.getsockname()[:2]
        self.url = f"http://{self.host}:{self.port}"
        self.server = uvicorn.Server(
            uvicorn.Config(
                app,
                log_level="warning",
                access_log=False,
                lifespan="off",
                timeout_graceful_shutdown=2,
                **config,
            )
        )
        self._thread = threading.Thread(target=self._run, name="robobpp-policy-server", daemon=True)

    def _run(self) -> None:
        self.server.run(sockets=[self._sock])

    def start(self) -> BackgroundServer:
        self._thread.start()
        deadline = time.monotonic() + 10
        while not self.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError("the policy server did not start")
            time.sleep(0.01)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        self._thread.join(timeout=10)
        self._sock.close()

    def __enter__(self) -> BackgroundServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
