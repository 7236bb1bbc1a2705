"""The participant's and the operator's pages in a real Chromium: sign in, create a participant, submit a
policy through the form, follow it live, cancel, read the result and the failure reasons, sign out."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from robobpp.core import Action, Observation
from robobpp.policies.dbl import DBL
from tests.web.conftest import ADMIN_TOKEN, PageProbe, Server, sign_in
from tests.web.test_pages import GatedPolicy

pytestmark = pytest.mark.browser
SECRET = "web-flow-secret-123"


class Broken(DBL):
    """Fails at its first decision with text the page must show as text, cut short."""

    def act(self, obs: Observation) -> Action | None:
        raise RuntimeError("<b>boom</b> " + "x" * 2000)


def _create_participant(probe: PageProbe, server: Server, name: str) -> str:
    page = probe.page
    sign_in(page, server, ADMIN_TOKEN)
    assert page.url.endswith("/operator")
    page.fill("#create-participant #name", name)
    page.click("#create-participant button[type=submit]")
    token = page.locator("[data-role=token]").inner_text().strip()
    assert token.startswith("rbp_")
    assert name in page.locator("#participants").inner_text()
    probe.shot("operator")
    page.locator("#participants a", has_text=name).click()
    page.wait_for_selector("#issue-token")
    probe.shot("operator-participant")
    page.click("form.inline button.link")  # sign out
    page.wait_for_url(server.url + "/")
    assert page.locator("[data-role=who]").count() == 0
    return token


def _submit(page: Any, server: Server, name: str, url: str) -> int:
    page.goto(server.url + "/submit")
    page.fill("#name", name)
    page.fill("#policy_url", url)
    page.fill("#secret", SECRET)
    for box in page.locator("input[name=datasets]").all():
        box.set_checked(box.get_attribute("value") == "repetitive")
    for box in page.locator("input[name=settings]").all():
        box.set_checked(box.get_attribute("value") == "math")
    page.check("input[name=track][value=public]")  # keeps the private boards other tests count unchanged
    page.click("#submit-form button[type=submit]")
    page.wait_for_url("**/submissions/*")
    return int(page.url.rsplit("/", 1)[1])


def test_sign_in_submit_follow_and_result(server: Server, probe: PageProbe) -> None:
    from robobpp.client.serve import BackgroundServer, create_policy_app

    token = _create_participant(probe, server, "web-flow")
    page = probe.page
    page.goto(server.url + "/sign-in")
    probe.shot("sign-in")
    page.fill("#token", "rbp_not-a-token")
    page.click("#sign-in button[type=submit]")
    assert "not valid" in page.locator("[data-role=error]").inner_text()
    probe.errors.clear()  # the refused sign-in answered 401 on purpose
    sign_in(page, server, token)
    assert page.url.endswith("/account") and page.locator("[data-role=who]").inner_text() == "web-flow"
    cookie = next(c for c in page.context.cookies() if c["name"] == "robobpp_session")
    assert cookie["httpOnly"] and cookie["sameSite"] == "Lax" and token not in cookie["value"]

    page.goto(server.url + "/submit")
    probe.shot("submit")
    gate = threading.Event()
    with BackgroundServer(create_policy_app(GatedPolicy(gate), SECRET, name="gated")) as policy:
        sid = _submit(page, server, "web-flow-gated", policy.url)
        try:
            assert page.locator("[data-role=status]").inner_text() in ("queued", "running")
            assert page.locator("[data-role=live]").is_visible()
            page.wait_for_function(
                "() => document.querySelector('[data-role=progress-text]').textContent.includes('running')"
            )
            probe.shot("submission-live")
            gate.set()
            page.wait_for_function(
                "() => document.querySelector('[data-role=status]').textContent === 'completed'"
                " && !document.querySelector('[data-role=live]')",
                timeout=120_000,
            )
        finally:
            gate.set()
    assert "2 of 2 episodes finished" in page.locator("[data-role=progress-text]").inner_text()
    assert page.locator("#episodes tbody tr").count() == 2
    assert policy.url in page.locator("[data-role=policy-url]").inner_text()  # the owner sees their URL
    probe.shot("submission-owner")
    page.goto(server.url + "/account")
    row = page.locator(f"#submissions tr[data-id='{sid}']")
    assert "completed" in row.inner_text() and "2 / 2" in row.inner_text()
    probe.shot("account")
    probe.assert_clean()


def test_cancel_and_failure_reasons(server: Server, probe: PageProbe, browser: Any) -> None:
    from robobpp.client.serve import BackgroundServer, create_policy_app

    token = _create_participant(probe, server, "web-cancel")
    page = probe.page
    sign_in(page, server, token)
    gate = threading.Event()
    with BackgroundServer(create_policy_app(GatedPolicy(gate), SECRET, name="gated")) as policy:
        sid = _submit(page, server, "web-cancel-me", policy.url)
        try:
            page.click("#cancel-form button")
            page.wait_for_function(
                "() => document.querySelector('[data-role=status]').textContent === 'cancelled'"
            )
            assert page.locator("#cancel-form").count() == 0
        finally:
            gate.set()
    with BackgroundServer(create_policy_app(Broken(), SECRET, name="broken")) as policy:
        failed = _submit(page, server, "web-broken", policy.url)
        page.wait_for_function(
            "() => document.querySelector('[data-role=status]').textContent !== 'running'"
            " && !document.querySelector('[data-role=live]')",
            timeout=120_000,
        )
    detail = page.locator("[data-role=detail]").first.inner_text()
    assert "<b>boom</b>" in detail and len(detail) <= 500  # text, not markup; cut short
    assert page.locator("#episodes b").count() == 0
    # Another browser, not signed in, gets the 404 a missing submission gets.
    other = browser.new_context()
    try:
        for s in (sid, failed):
            r = other.new_page().goto(f"{server.url}/submissions/{s}")
            assert r is not None and r.status == 404
    finally:
        other.close()
    probe.assert_clean()
