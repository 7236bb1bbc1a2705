"""A flood of slow-drip submissions does not take the API down (issue: one participant froze the service).

A real drip policy server process (tests/server/dripserver.py) and a real ``robobpp serve`` process: 120
submissions from 30 participants, all pointing at the drip server, while a poller keeps asking
``/healthz`` and a leaderboard. Their latency during the flood is compared with a baseline measured in
the same test; the probes the drip server saw are counted against the configured bounds.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest

from tests.server.conftest import ADMIN_TOKEN, free_port, new_participant

DRIP = Path(__file__).with_name("dripserver.py")
PROBE_TIMEOUT_S = 2.0
CONCURRENCY = 6
PARTICIPANTS = 30
PER_PARTICIPANT = 4  # 120 submissions


@pytest.fixture
def drip_server() -> Iterator[str]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, str(DRIP), str(port), "--interval", "0.5"])
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                httpx.get(url + "/stats", timeout=1)
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise RuntimeError("the drip server did not start") from None
                time.sleep(0.1)
        yield url
    finally:
        proc.kill()
        proc.wait(10)


def _latencies(base: str, stop: threading.Event | None, rounds: int = 0) -> list[float]:
    """Time /healthz and a leaderboard alternately: ``rounds`` times, or until ``stop`` is set."""
    seen: list[float] = []
    with httpx.Client(base_url=base, timeout=60) as client:
        i = 0
        while (stop is None and i < rounds) or (stop is not None and not stop.is_set()):
            path = "/healthz" if i % 2 == 0 else "/api/v1/leaderboards/repetitive/math"
            started = time.perf_counter()
            r = client.get(path)
            seen.append(time.perf_counter() - started)
            assert r.status_code == 200, (path, r.status_code, r.text[:200])
            i += 1
            time.sleep(0.02)
    return seen


def test_slow_drip_flood_keeps_health_and_leaderboard_responsive(
    make_server, drip_server: str, tmp_path
) -> None:
    server = make_server(
        f"sqlite:///{tmp_path / 'flood.sqlite3'}",
        ROBOBPP_WORKERS="0",
        ROBOBPP_PROBE_TIMEOUT_S=str(PROBE_TIMEOUT_S),
        ROBOBPP_PROBE_CONCURRENCY=str(CONCURRENCY),
        ROBOBPP_QUOTA_SUBMISSIONS_PER_DAY="1000",
    )
    with server.client(ADMIN_TOKEN) as admin:
        tokens = [new_participant(admin, f"flooder{i}") for i in range(PARTICIPANTS)]
    baseline = _latencies(server.url, None, rounds=40)

    def submit(token: str) -> tuple[int, str, float]:
        started = time.perf_counter()
        with httpx.Client(
            base_url=server.url + "/api/v1", timeout=120, headers={"Authorization": f"Bearer {token}"}
        ) as c:
            r = c.post("/submissions", json={"name": "drip", "policy_url": drip_server})
        return r.status_code, r.json().get("type", ""), time.perf_counter() - started

    stop = threading.Event()
    with ThreadPoolExecutor(max_workers=1) as poll_pool:
        polling = poll_pool.submit(_latencies, server.url, stop)
        time.sleep(0.2)
        with ThreadPoolExecutor(max_workers=PARTICIPANTS * PER_PARTICIPANT) as pool:
            answers = list(pool.map(submit, [t for t in tokens for _ in range(PER_PARTICIPANT)]))
        stop.set()
        during = polling.result()
    stats = httpx.get(drip_server + "/stats", timeout=5).json()

    codes = [code for code, _kind, _t in answers]
    kinds = {kind.rsplit("/", 1)[-1] for _code, kind, _t in answers}
    # Every submission got a clear answer: refused after its bounded probe (422) or turned away (429).
    assert set(codes) <= {422, 429}, codes
    assert kinds <= {"policy-unreachable", "probe-busy"}, kinds
    assert codes.count(422) >= CONCURRENCY  # the drip server really was probed ...
    assert stats["max_open"] <= CONCURRENCY, (
        stats
    )  # ... never more than the overall bound at once  # ... never more than the overall bound at once
    # Every submission was answered within a few probe deadlines (slot wait + probe), not after the drip's
    # 8 hours or the client's timeout: generous, the machine may be loaded.
    assert max(t for *_x, t in answers) < 10 * PROBE_TIMEOUT_S
    # The API kept its usual latency (generous bound): its median stays within 10x the baseline's, and at
    # most one call in 20 takes as long as one probe deadline (a request pool blocked behind the probes
    # would make nearly every call wait that long; a single spike on a loaded machine is tolerated).
    assert len(during) >= 10
    assert statistics.median(during) <= 10 * statistics.median(baseline), (baseline, during)
    slow = sum(t >= PROBE_TIMEOUT_S for t in during)
    assert slow <= len(during) / 20, (max(baseline), sorted(during)[-5:])


def test_over_quota_causes_no_outbound_call_and_info_is_strict(
    make_server, drip_server: str, tmp_path
) -> None:
    server = make_server(
        f"sqlite:///{tmp_path / 'quota.sqlite3'}", ROBOBPP_WORKERS="0", ROBOBPP_QUOTA_SUBMISSIONS_PER_DAY="0"
    )
    with server.client(ADMIN_TOKEN) as admin:
        token = new_participant(admin, "over")
    with server.client(token) as c:
        r = c.post("/submissions", json={"name": "drip", "policy_url": drip_server})
        unauthenticated = httpx.post(
            server.url + "/api/v1/submissions", json={"name": "x", "policy_url": drip_server}
        )
    assert r.status_code == 429 and r.json()["type"].endswith("quota-exceeded"), r.text
    assert unauthenticated.status_code == 401
    assert httpx.get(drip_server + "/stats", timeout=5).json()["total"] == 0

    # The submit check is the conformance check's: /info must declare robobpp/1, and answers be signed.
    from tests.client.hostile import HostileServer

    secret = "submit-secret-123"
    with HostileServer(secret=secret) as hostile, server.client(ADMIN_TOKEN) as admin:
        answers = {
            mode: admin.post(
                "/submissions", json={"name": mode, "policy_url": f"{hostile.url}/{mode}", "secret": secret}
            )
            for mode in ("empty_info", "unsigned", "good")
        }
    assert (
        answers["empty_info"].status_code == 422 and "missing field 'protocol'" in answers["empty_info"].text
    )
    assert (
        answers["unsigned"].status_code == 422 and "missing X-Robobpp-Timestamp" in answers["unsigned"].text
    )
    assert answers["good"].status_code == 201, answers["good"].text
