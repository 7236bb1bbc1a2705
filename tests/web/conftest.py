"""A real evaluation server (uvicorn subprocess, temp SQLite, local workers) and a real Chromium.

The server evaluates real baselines on small offline episodes (``robobpp.worker.specs:offline_spec``) so the
pages show real figures; a public-track submission adds replayable traces, and a participant with a
hostile name is written straight into the database (the API refuses such names — the pages must be safe
even so). Chromium is Debian's, driven by Playwright; it is never downloaded by the test tool.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests._orphans import with_parent_death

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]
ADMIN_TOKEN = "web-tests-admin-token-0123456789"
LOOKAHEAD_SUBMISSION = "DBL seeing 10 boxes ahead"
HOSTILE_PARTICIPANT = "<script>alert(1)</script>"
HOSTILE_SUBMISSION = '<img src=x onerror="alert(2)">'
#: Where the tests' screenshots go: a temporary folder, so a test run leaves the working tree as it was;
#: ``ROBOBPP_UPDATE_SCREENSHOTS=1`` writes them over the documentation's own (docs/screenshots, CONTRIBUTING.md).
DOC_SCREENSHOTS = Path(__file__).resolve().parents[2] / "docs" / "screenshots"
SCREENSHOTS = (
    DOC_SCREENSHOTS
    if os.environ.get("ROBOBPP_UPDATE_SCREENSHOTS") == "1"
    else Path(tempfile.gettempdir()) / f"robobpp-test-screenshots-{os.getpid()}"
)
#: Bounds on waiting for the workers (generous: the machine may be busy); not a speed test.
WAIT_S = 240.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    def __init__(self, url: str, data_dir: Path) -> None:
        self.url = url
        self.data_dir = data_dir
        self.client = httpx.Client(
            base_url=url, timeout=30.0, headers={"Authorization": f"Bearer {ADMIN_TOKEN}"}
        )
        self.ids: dict[str, int] = {}
        self.datasets_visible = False

    def get(self, path: str, **kw: Any) -> httpx.Response:
        return self.client.get(path, **kw)

    def wait_until(self, check: Any, what: str) -> Any:
        deadline = time.monotonic() + WAIT_S
        while True:
            value = check()
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"server: {what} did not happen within {WAIT_S:.0f} s")
            time.sleep(0.5)

    def submission(self, sid: int) -> dict[str, Any]:
        r = self.get(f"/api/v1/submissions/{sid}")
        r.raise_for_status()
        return r.json()

    def all_finished(self) -> bool:
        subs = self.get("/api/v1/submissions", params={"limit": 200}).json()
        return bool(subs) and all(s["status"] not in ("queued", "running") for s in subs)


def _seed_hostile(database_url: str) -> int:
    """A participant whose name is a script tag, with a real (built-in) policy evaluated by the workers."""
    return _seed(
        database_url, HOSTILE_PARTICIPANT, HOSTILE_SUBMISSION, "builtin:onlinebph", ["math", "physics"]
    )


def _seed(
    database_url: str, participant: str, name: str, policy_url: str, settings: list[str], lookahead: int = 0
) -> int:
    """A private submission of a built-in policy on every dataset, written into the server's database (its
    workers evaluate it); the participant is new."""
    from robobpp.db import work
    from robobpp.db.models import Participant
    from robobpp.db.session import make_engine, make_session_factory

    engine = make_engine(database_url)
    try:
        factory = make_session_factory(engine)
        with factory() as session, session.begin():
            who = Participant(name=participant)
            session.add(who)
            session.flush()
            sub = work.create_submission(
                session,
                who,
                name=name,
                policy_url=policy_url,
                datasets=["repetitive", "diverse", "longboard"],
                settings=settings,
                groups=2,
                lookahead=lookahead,
            )
            session.flush()
            return sub.id
    finally:
        engine.dispose()


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    from robobpp.datasets.cache import data_dir as datasets_cache
    from robobpp.web.dataset_stats import data_available

    data_dir = tmp_path_factory.mktemp("server")
    port = _free_port()
    cache = datasets_cache()
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")},
        "ROBOBPP_ENV": "dev",
        # The server keeps its state under ./robobpp-data (cwd = the temp dir) and reads the datasets cache
        # this test process reads, so the datasets page sees the same data.
        "ROBOBPP_DATA_DIR": str(cache),
        "ROBOBPP_DATABASE_URL": "",
        "ROBOBPP_ADMIN_TOKEN": ADMIN_TOKEN,
        "ROBOBPP_SPEC_PROVIDER": "robobpp.worker.specs:offline_spec",
        "ROBOBPP_BOARD_REFRESH_S": "0",  # pages follow a finishing submission at once
        "ROBOBPP_GROUPS": "2",
        "ROBOBPP_SETTINGS": json.dumps(["math", "physics"]),
        "ROBOBPP_BASELINES": json.dumps(["dbl", "hm", "lsah", "onlinebph", "random"]),
        "ROBOBPP_PUBLIC_BASELINES": "false",  # CI time; the public-track DBL stays alone on its boards
        "ROBOBPP_WORKERS": "1",
        "ROBOBPP_ALLOW_PRIVATE_POLICY_URLS": "true",
    }
    log = (data_dir / "server.log").open("wb")
    proc = subprocess.Popen(
        with_parent_death(
            [
                sys.executable,
                "-m",
                "uvicorn",
                "robobpp.server.app:create_app",
                "--factory",
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--log-level",
                "warning",
            ]
        ),
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=data_dir,
    )
    srv = Server(f"http://127.0.0.1:{port}", data_dir)
    srv.datasets_visible = data_available()
    try:

        def healthy() -> bool:
            if proc.poll() is not None:
                raise AssertionError(f"server exited: {(data_dir / 'server.log').read_text()[-3000:]}")
            try:
                return srv.get("/healthz").status_code == 200
            except httpx.TransportError:
                return False

        srv.wait_until(healthy, "start")
        database_url = f"sqlite:///{(data_dir / 'robobpp-data' / 'robobpp.sqlite3').resolve()}"
        srv.ids["hostile"] = _seed_hostile(database_url)
        # a policy shown the next 10 boxes: on boards of its own (Math Pack only, to keep the start short)
        srv.ids["lookahead"] = _seed(database_url, "seer", LOOKAHEAD_SUBMISSION, "builtin:dbl", ["math"], 10)
        r = srv.client.post(
            "/api/v1/submissions", json={"name": "DBL public", "policy_url": "builtin:dbl", "track": "public"}
        )
        assert r.status_code == 201, r.text
        srv.ids["public"] = r.json()["id"]
        srv.wait_until(srv.all_finished, "every submission finishing")
        yield srv
    finally:
        srv.client.close()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
        log.close()


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    if not CHROMIUM.exists():
        pytest.skip("Debian's Chromium is not installed (apt-get install -y chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


class PageProbe:
    """A page plus everything the browser complained about while it was open."""

    def __init__(self, page: Any) -> None:
        self.page = page
        self.errors: list[str] = []
        self.dialogs: list[str] = []
        page.on(
            "console",
            lambda m: self.errors.append(f"console.{m.type}: {m.text}") if m.type == "error" else None,
        )
        page.on("pageerror", lambda e: self.errors.append(f"page error: {e}"))
        page.on("requestfailed", lambda r: self.errors.append(f"request failed: {r.url} {r.failure}"))
        page.on(
            "response", lambda r: self.errors.append(f"HTTP {r.status}: {r.url}") if r.status >= 400 else None
        )

        def on_dialog(d: Any) -> None:
            self.dialogs.append(d.message)
            d.dismiss()

        page.on("dialog", on_dialog)

    def assert_clean(self) -> None:
        assert not self.dialogs, f"a script opened dialogs: {self.dialogs}"
        assert not self.errors, "\n".join(self.errors)

    def shot(self, name: str) -> Path:
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        path = SCREENSHOTS / f"{name}.png"
        self.page.screenshot(path=str(path), full_page=True)
        return path


def sign_in(page: Any, server: Server, token: str) -> None:
    """Sign in through the sign-in form, as a person would."""
    page.goto(server.url + "/sign-in")
    page.fill("#token", token)
    page.click("#sign-in button[type=submit]")
    page.wait_for_selector("[data-role=who]")


@pytest.fixture
def probe(browser: Any) -> Iterator[PageProbe]:
    context = browser.new_context(viewport={"width": 1360, "height": 900}, device_scale_factor=1)
    page = context.new_page()
    yield PageProbe(page)
    context.close()
