"""Pull mode end to end: a real ``robobpp serve`` (uvicorn + worker processes), a policy that connects out
with ``robobpp connect`` from a process that listens on no port, a submission evaluated and ranked; and a
client that drops mid-episode and comes back without the episode being lost or counted twice."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from robobpp.client.connect import connect
from tests.server.conftest import SlowDBL, new_participant, wait_for

ROOT = Path(__file__).resolve().parents[2]


def listening_ports(pid: int) -> set[int]:
    """TCP ports a process listens on (Linux /proc: its socket inodes in the LISTEN state)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # 0A = LISTEN
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads /proc to prove nothing listens")
def test_a_policy_connected_in_pull_mode_is_evaluated_and_ranked(make_server, tmp_path: Path) -> None:
    server = make_server(f"sqlite:///{tmp_path / 'pull.sqlite3'}")
    admin = server.client()
    token = new_participant(admin, "natted")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "ROBOBPP_TOKEN": token, "ROBOBPP_SERVER": server.url}
    client = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from robobpp.cli import main; main()",
            "connect",
            "dbl",
            "--name",
            "behind-nat",
            "--dataset",
            "diverse",
            "--setting",
            "math",
            "--parallel",
            "2",
            "--secret",
            "pull-secret-123",
        ],
        env=env,
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen_listening: set[int] = set()
    try:
        while client.poll() is None:  # the whole time it is connected: no listening socket at all
            seen_listening |= listening_ports(client.pid)
            time.sleep(0.2)
        out, err = client.communicate(timeout=10)
    finally:
        if client.poll() is None:
            client.kill()
    assert client.returncode == 0, err[-3000:]
    assert seen_listening == set()
    assert "in pull mode" in err and "behind-nat" in out

    subs = server.client(token).get("/submissions").json()
    assert [(s["name"], s["mode"], s["status"], s["policy_url"]) for s in subs] == [
        ("behind-nat", "pull", "completed", "pull:")
    ]
    episodes = server.client(token).get(f"/submissions/{subs[0]['id']}/episodes").json()
    assert len(episodes) == 2 and all(e["status"] == "done" and e["attempts"] == 1 for e in episodes)
    assert all(e["boxes_placed"] > 5 and e["termination"] != "policy_error" for e in episodes)
    # The evaluator's own network estimate sits beside the decision time it corrected.
    for e in episodes:
        m = e["metrics"]
        assert 0 < m["network_estimate"] <= m["round_trip"]
        assert m["decision_time"] == pytest.approx(m["round_trip"] - m["network_estimate"], abs=2e-3)
    board = admin.get("/leaderboards/diverse/math").json()
    mine = next(e for e in board["entries"] if e["submission_id"] == subs[0]["id"])
    assert mine["rank"] >= 1 and mine["metrics"]["space_utilization"] > 0


def test_a_dropped_client_resumes_its_episode_without_loss_or_double_count(
    make_server, tmp_path: Path
) -> None:
    server = make_server(
        f"sqlite:///{tmp_path / 'drop.sqlite3'}",
        ROBOBPP_EVALUATE_BASELINES="0",
        ROBOBPP_GROUPS="1",
        ROBOBPP_PULL_RECONNECT_S="20",
    )
    token = new_participant(server.client(), "flaky")
    stop = threading.Event()
    events: list[str] = []
    result: dict[str, object] = {}

    def run() -> None:
        result["sub"] = connect(
            SlowDBL(),
            server.url,
            token,
            name="flaky",
            datasets=["repetitive"],
            settings=["math"],
            stop=stop,
            on_event=events.append,
            poll_s=0.3,
        )

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    api = server.client(token)
    sub_id = wait_for(lambda: next((s["id"] for s in api.get("/submissions").json()), None), timeout_s=30)
    # Wait until an episode is under way (a few steps done), then cut every socket of this client.
    wait_for(
        lambda: any(e["step"] >= 3 for e in api.get(f"/submissions/{sub_id}/episodes").json()), timeout_s=60
    )
    cut = _cut_client_sockets(server.port)
    assert cut > 0
    thread.join(timeout=120)
    assert not thread.is_alive()
    sub = result["sub"]
    assert sub.status == "completed", events  # type: ignore[attr-defined]
    assert any("connection lost" in e for e in events)
    (episode,) = api.get(f"/submissions/{sub_id}/episodes").json()
    assert episode["status"] == "done" and episode["attempts"] == 1
    assert episode["termination"] == "completed", episode["termination_detail"]
    assert episode["step"] == episode["boxes_total"] == episode["boxes_placed"]


def _cut_client_sockets(port: int) -> int:
    """Shut down the client's WebSocket connections to the server (what a NAT timeout or a Wi-Fi drop does)."""
    import gc
    import socket

    from websockets.sync.client import ClientConnection

    cut = 0
    # type(), not isinstance(): isinstance reads __class__, which wakes lazy module attributes (a torch warning)
    for conn in [o for o in gc.get_objects() if issubclass(type(o), ClientConnection)]:
        try:
            if conn.socket.getpeername()[1] == port:
                conn.socket.shutdown(socket.SHUT_RDWR)
                cut += 1
        except OSError:
            continue
    return cut
