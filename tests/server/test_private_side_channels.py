"""What a participant can read of a private evaluation tells nothing that draws its groups (docs/datasets.md,
"Private groups nobody can look up"): no API answer or page holds a group's seed (with the public pools, a seed
is its group) or a trace of its boxes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from robobpp.worker.specs import offline_spec
from tests.server.conftest import ADMIN_TOKEN, new_participant, wait_for


def test_nothing_a_participant_reads_holds_a_private_group_seed(
    make_server, policy_server, tmp_path: Path
) -> None:
    server = make_server(f"sqlite:///{tmp_path / 'side.sqlite3'}", ROBOBPP_DATASETS='["diverse"]')
    policy = policy_server()
    # The server's groups here come from the offline provider; their seeds stand for the private files' ones.
    seeds = {
        str(offline_spec("diverse", split, g, 2).seed) for split in ("test", "holdout") for g in range(2)
    }
    with server.client(ADMIN_TOKEN) as admin:
        token = new_participant(admin, "alice")
        with server.client(token) as alice:
            sid = alice.post(
                "/submissions", json={"name": "mine", "policy_url": policy.url, "secret": "policy-secret-123"}
            ).json()["id"]

            def done() -> dict[str, Any] | None:
                sub = alice.get(f"/submissions/{sid}").json()
                return sub if sub["status"] == "completed" else None

            sub = wait_for(done, 120)
            assert sub["track"] == "private"
            episodes = alice.get(f"/submissions/{sid}/episodes").json()
            details = [alice.get(f"/submissions/{sid}/episodes/{e['id']}").json() for e in episodes]
            read = [
                alice.get(path).text
                for path in (
                    f"/submissions/{sid}",
                    f"/submissions/{sid}/episodes",
                    "/submissions",
                    "/leaderboards",
                    "/leaderboards/diverse/math?view=all",
                )
            ]
            read += [str(d) for d in details]
            read += [
                alice.get(server.url + path, headers={"Accept": "text/html"}).text
                for path in (f"/submissions/{sid}", f"/submissions/{sid}/status.json", "/boards/diverse/math")
            ]
    assert episodes and all(d["trace"] is None for d in details)
    leaked = [seed for seed in seeds for text in read if seed in text]
    assert not leaked, leaked
