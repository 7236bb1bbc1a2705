"""Participant pages: sign in with an API token, submit a policy, follow and cancel your submissions.

Every action calls the service the JSON API's route calls (``admission.submit``, ``access.cancel``,
``accounts.revoke_token``), so the page and ``POST /api/v1/...`` share one code path: the same URL check,
quota, ownership and errors.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Form, Path, Query, Request
from fastapi.responses import HTMLResponse, Response
from markupsafe import Markup
from pydantic import ValidationError
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from robobpp.datasets import DATASETS
from robobpp.db import queries
from robobpp.db.models import Participant
from robobpp.schemas import SubmissionCreate, SubmissionPublic
from robobpp.server.principal import Principal, auth_refused_for, principal_for_token
from robobpp.server.problems import ProblemError
from robobpp.server.services import access, accounts, admission
from robobpp.server.services.submissions import listed_forms
from robobpp.server.site import session as web_session
from robobpp.server.site.render import CSRF_SLOT, not_found, redirect, refused, render, root
from robobpp.server.site.session import Viewer, load_viewer, resolved_in_handler, viewer
from robobpp.server.state import state_of
from robobpp.web import environment

router = APIRouter(include_in_schema=False, dependencies=[Depends(load_viewer)])
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]
#: Form fields are read with generous caps; the API's own models then apply the real limits.
Text = Annotated[str, Form(max_length=4096)]
BAD_CSRF = "This form has expired or did not come from this site. Reload the page and try again."
#: Pull mode (the policy connects out to the server) is offered once the API's submission model has it.
PULL_OFFERED = "mode" in SubmissionCreate.model_fields


def principal_of(request: Request, who: Viewer, session: Session | None = None) -> Principal | None:
    """The API's principal for a signed-in viewer (a fresh participant row), or None when signed out.
    ``session``: the caller's transaction (else one of its own)."""
    if who.admin:
        return Principal(None, admin=True)
    if who.participant_id is None:
        return None
    with web_session.reading(request, session) as s:
        participant = s.get(Participant, who.participant_id)
    return None if participant is None else Principal(participant, token_id=who.token_id)


def problem_text(exc: ProblemError | ValidationError) -> str:
    """One readable line per problem; text that came from a policy is cut like everywhere else."""
    if isinstance(exc, ValidationError):
        lines = [f"{'.'.join(str(p) for p in e['loc']) or 'form'}: {e['msg']}" for e in exc.errors()]
        return queries.shown_text("; ".join(lines)) or ""
    return queries.shown_text(f"{exc.title}: {exc.detail}") or ""


def problem_page(request: Request, exc: ProblemError) -> Response:
    """The error page for an API problem raised under a form's POST."""
    return render(request, "error.html", exc.status, title=exc.title, nav="", message=problem_text(exc))


# ---- sign in / out ---------------------------------------------------------------------------------------


@router.get("/sign-in", response_class=HTMLResponse)
def sign_in_page(request: Request) -> Response:
    who = viewer(request)
    if who.signed_in:
        return redirect(request, "/operator" if who.admin else "/account")
    return render(request, "sign_in.html", title="Sign in", nav="account", form=True, error=None)


@router.post("/sign-in", response_class=HTMLResponse)
def sign_in(request: Request, token: Text = "", csrf: Text = "") -> Response:
    if not web_session.csrf_ok(request, csrf):
        return render(request, "sign_in.html", 403, title="Sign in", nav="account", form=True, error=BAD_CSRF)
    wait = auth_refused_for(request, token.strip())
    if wait:
        page = render(
            request,
            "sign_in.html",
            429,
            title="Sign in",
            nav="account",
            form=True,
            error=f"Too many wrong tokens from your address or for this token; try again in {wait:.0f} s.",
        )
        page.headers["Retry-After"] = str(max(1, round(wait)))
        return page
    principal = principal_for_token(request, token.strip())
    if principal is None or (principal.participant is not None and principal.participant.is_builtin):
        return render(
            request,
            "sign_in.html",
            401,
            title="Sign in",
            nav="account",
            form=True,
            error="That token is not valid (unknown or revoked). Ask the operator for a new one.",
        )
    response = redirect(request, "/operator" if principal.admin else "/account")
    web_session.start(request, response, token_id=principal.token_id, admin=principal.admin)
    return response


@router.post("/sign-out")
def sign_out(request: Request, csrf: Text = "") -> Response:
    if not web_session.csrf_ok(request, csrf):
        return refused(request, BAD_CSRF)
    response = redirect(request, "/")
    web_session.end(request, response)
    return response


def _need_sign_in(request: Request) -> Response:
    return redirect(request, "/sign-in")


# ---- your submissions ------------------------------------------------------------------------------------


def submission_rows(
    request: Request, session: Session, owner: int | None, page: int, *, show_participant: bool
) -> tuple[Markup, bool]:
    """A page of submissions (newest first; ``owner``'s, or everyone's) as the rows of the submissions table,
    and whether an older page exists. Each row is kept as HTML with its submission's other served forms
    (services/submissions.py) and its CSRF nonce put in for this viewer: a page renders only the rows whose
    submission changed, not fifty (a third of the page's CPU before)."""
    base = root(request)
    row = environment().get_template("_submissions.html").module.submission_row  # type: ignore[attr-defined]

    def build(view: dict[str, Any]) -> str:
        return str(row(SubmissionPublic.model_validate(view), base, CSRF_SLOT, show_participant))

    # one more than a page: whether an older page exists, without counting every submission
    rows = listed_forms(
        state_of(request.app).finished_views,
        session,
        owner,
        ACCOUNT_PAGE_SIZE + 1,
        (page - 1) * ACCOUNT_PAGE_SIZE,
        ("row-html", base, show_participant),
        build,
    )
    html = "".join(rows[:ACCOUNT_PAGE_SIZE]).replace(CSRF_SLOT, viewer(request).nonce)
    return Markup(html), len(rows) > ACCOUNT_PAGE_SIZE


#: Submissions per page of the account page and an operator's participant page (newest first).
ACCOUNT_PAGE_SIZE = 50
Page = Annotated[int, Query(ge=1, le=10**5)]


@router.get("/account", response_class=HTMLResponse)
@resolved_in_handler
def account_page(request: Request, page: Page = 1) -> Response:
    settings = state_of(request.app).settings
    with state_of(request.app).runtime.read_session() as session:
        who = viewer(request, session)
        principal = principal_of(request, who, session)
        if principal is None:
            return _need_sign_in(request)
        me = accounts.me_of(session, principal, settings)
        # one more than a page: whether a next page exists, without counting every submission
        rows, more = submission_rows(
            request, session, principal.participant_id, page, show_participant=who.admin
        )
        tokens = accounts.list_tokens(session, principal) if not who.admin else []
    return render(
        request,
        "account.html",
        title="Your submissions" if not who.admin else "All submissions",
        nav="account",
        me=me,
        rows=rows,
        tokens=tokens,
        page=page,
        more=more,
    )


@router.post("/account/tokens/{token_id}/revoke")
def revoke_own_token(request: Request, token_id: Id, csrf: Text = "") -> Response:
    who = viewer(request)
    principal = principal_of(request, who)
    if principal is None:
        return _need_sign_in(request)
    if not web_session.csrf_ok(request, csrf):
        return refused(request, BAD_CSRF)
    try:
        with state_of(request.app).runtime.session() as session:
            accounts.revoke_token(session, principal, token_id)
    except ProblemError as exc:
        return problem_page(request, exc)
    # Revoking the token this browser signed in with ends the session: the next page asks to sign in.
    return redirect(request, "/account")


# ---- submit ----------------------------------------------------------------------------------------------


def _form_defaults(request: Request) -> dict[str, Any]:
    settings = state_of(request.app).settings
    return {
        "name": "",
        "mode": "push",
        "policy_url": "",
        "datasets": list(settings.datasets),
        "settings": list(settings.enabled_settings),
        "track": "private",
        "lookahead": 0,
    }


def _submit_page(
    request: Request, values: dict[str, Any], error: str | None, status_code: int = 200
) -> Response:
    settings = state_of(request.app).settings
    return render(
        request,
        "submit.html",
        status_code,
        title="Submit a policy",
        nav="submit",
        values=values,
        error=error,
        datasets_offered=[DATASETS[d] for d in settings.datasets],
        settings_offered=settings.enabled_settings,
        quota_day=settings.quota_submissions_per_day,
        quota_concurrent=settings.quota_concurrent,
        min_secret=8,
        pull_offered=PULL_OFFERED,
    )


@router.get("/submit", response_class=HTMLResponse)
def submit_page(request: Request) -> Response:
    if principal_of(request, viewer(request)) is None:
        return _need_sign_in(request)
    return _submit_page(request, _form_defaults(request), None)


@router.post("/submit", response_class=HTMLResponse)
async def submit(
    request: Request,
    name: Text = "",
    mode: Text = "push",
    policy_url: Text = "",
    secret: Text = "",
    datasets: Annotated[list[str], Form(max_length=8)] = [],  # noqa: B006 - FastAPI copies form defaults
    settings: Annotated[list[str], Form(max_length=8)] = [],  # noqa: B006
    track: Text = "private",
    lookahead: Text = "0",
    csrf: Text = "",
) -> Response:
    # async like the API handler it awaits (its policy check runs on its own bounded pool); the short
    # database reads go to the thread pool.
    principal = await run_in_threadpool(principal_of, request, viewer(request))
    if principal is None:
        return _need_sign_in(request)
    # The secret is never echoed back into the form.
    values = {
        "name": name,
        "mode": mode,
        "policy_url": policy_url,
        "datasets": datasets,
        "settings": settings,
        "track": track,
        "lookahead": lookahead,
    }
    if not web_session.csrf_ok(request, csrf):
        return _submit_page(request, values, BAD_CSRF, 403)
    try:
        fields = {
            "name": name,
            "policy_url": policy_url or None,
            "secret": secret or None,
            "datasets": datasets or None,
            "settings": settings or None,
            "track": track,
            "lookahead": int(lookahead) if lookahead.strip().isdigit() else lookahead,
        }
        if PULL_OFFERED:
            fields["mode"] = mode
            if mode == "pull":
                fields["policy_url"] = None  # a URL left in the hidden push field is not an error
        body = SubmissionCreate.model_validate(fields)
        state = state_of(request.app)
        created = await admission.submit(state.runtime, state.probe_gate, body, principal, state.settings)
    except (ProblemError, ValidationError) as exc:
        status = exc.status if isinstance(exc, ProblemError) else 422
        return _submit_page(request, values, problem_text(exc), status)
    return redirect(request, f"/submissions/{created.id}")


@router.post("/submissions/{submission_id}/cancel")
def cancel(request: Request, submission_id: Id, csrf: Text = "") -> Response:
    principal = principal_of(request, viewer(request))
    if principal is None:
        return not_found(request, f"There is no submission {submission_id}.")
    if not web_session.csrf_ok(request, csrf):
        return refused(request, BAD_CSRF)
    try:
        with state_of(request.app).runtime.session() as session:
            access.cancel(session, principal, submission_id)
    except ProblemError as exc:
        if exc.status == 404:
            return not_found(request, f"There is no submission {submission_id}.")
        if exc.status != 409:  # already finished: the page shows how it ended
            raise
    return redirect(request, f"/submissions/{submission_id}")
