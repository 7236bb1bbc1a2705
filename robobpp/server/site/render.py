"""Rendering a page: the template, the viewer (for the navigation and the forms' CSRF token), caching."""

from __future__ import annotations

from typing import Any

from fastapi import Request, Response
from fastapi.responses import HTMLResponse, RedirectResponse

from robobpp.server.site.session import ensure_nonce, viewer
from robobpp.web import SETTING_TITLES, environment


def root(request: Request) -> str:
    return str(request.scope.get("root_path", "")).rstrip("/")


#: Stands for the viewer's CSRF nonce in a page kept for every viewer of the same kind (``csrf_slot=True``);
#: :func:`with_csrf` puts the nonce in when serving it (a nonce is URL-safe base64: no escaping to mind).
CSRF_SLOT = "robobpp-csrf-nonce-of-the-viewer"


def render(
    request: Request,
    template: str,
    status_code: int = 200,
    *,
    form: bool = False,
    csrf_slot: bool = False,
    **context: Any,
) -> HTMLResponse:
    """``form=True`` for a page with a form an anonymous visitor may post (the sign-in): it gets a
    session nonce first, so the form can carry it. ``csrf_slot=True``: the page's forms carry
    :data:`CSRF_SLOT`, to be kept and served through :func:`with_csrf`."""
    pending: Response | None = None
    who = viewer(request)
    if form and not who.nonce:
        pending = Response()
        ensure_nonce(request, pending)
        who = viewer(request)
    base = root(request)
    html = (
        environment()
        .get_template(template)
        .render(
            root=base,
            static=f"{base}/static",
            SETTING_TITLES=SETTING_TITLES,
            viewer=who,
            csrf=CSRF_SLOT if csrf_slot else who.nonce,
            **context,
        )
    )
    response = HTMLResponse(html, status_code=status_code)
    if pending is not None:
        response.raw_headers.extend((k, v) for k, v in pending.raw_headers if k == b"set-cookie")
    if who.signed_in or form:
        _private(response)
    return response


def with_csrf(request: Request, body: bytes) -> HTMLResponse:
    """A kept page (rendered with ``csrf_slot=True``) for this request's viewer."""
    who = viewer(request)
    response = HTMLResponse(body.replace(CSRF_SLOT.encode(), who.nonce.encode()))
    if who.signed_in:
        _private(response)
    return response


def _private(response: Response) -> None:
    # A page naming its viewer (or carrying its CSRF token) must not be stored by a shared cache.
    response.headers["Cache-Control"] = "private, no-store"


def not_found(request: Request, what: str) -> HTMLResponse:
    return render(request, "error.html", 404, title="Not found", nav="", message=what)


def refused(request: Request, message: str, status_code: int = 403) -> HTMLResponse:
    return render(request, "error.html", status_code, title="Refused", nav="", message=message)


def redirect(request: Request, path: str) -> RedirectResponse:
    """After a POST: 303 so the browser follows with a GET (reloading never re-posts)."""
    return RedirectResponse(root(request) + path, status_code=303)
