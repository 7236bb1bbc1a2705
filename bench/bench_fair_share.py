"""Cost of a fair-share claim and of a queued submission's place under a backlog (docs/server.md, "Evaluation").

    python bench/bench_fair_share.py                      # SQLite in a temporary directory
    python bench/bench_fair_share.py postgresql+psycopg://postgres@127.0.0.1:5432/EMPTY_DB

500 queued submissions of 200 participants (3 datasets × Math and Physics × 30 groups each), 20 episodes claimed
first, then the mean of 10 claims and of 10 looks at the newest submission's place.
"""

from __future__ import annotations

import sys
import tempfile
import time

from sqlalchemy import select

from robobpp.db import waiting, work
from robobpp.db.migrate import upgrade
from robobpp.db.models import Participant, Submission
from robobpp.db.session import make_engine, make_session_factory

SUBMISSIONS, PARTICIPANTS = 500, 200


def main() -> None:
    url = sys.argv[1] if len(sys.argv) > 1 else f"sqlite:///{tempfile.mkdtemp()}/fair.sqlite3"
    upgrade(url)
    factory = make_session_factory(make_engine(url))
    with factory() as s, s.begin():
        people = [Participant(name=f"p{i}") for i in range(PARTICIPANTS)]
        s.add_all(people)
        s.flush()
        for i in range(SUBMISSIONS):
            work.create_submission(
                s,
                people[i % PARTICIPANTS],
                name=f"s{i}",
                policy_url="builtin:dbl",
                datasets=["diverse", "repetitive", "longboard"],
                settings=["math", "physics"],
                groups=30,
            )
    with factory() as s, s.begin():
        for _ in range(20):
            work.claim_episode(s, "bench", lease_s=60, max_attempts=3, max_running_per_participant=4)
    t0 = time.perf_counter()
    for _ in range(10):
        with factory() as s, s.begin():
            work.claim_episode(s, "bench", lease_s=60, max_attempts=3, max_running_per_participant=4)
    print(f"claim: {(time.perf_counter() - t0) * 100:.1f} ms")
    with factory() as s:
        newest = s.execute(select(Submission).order_by(Submission.id.desc()).limit(1)).scalar_one()
        t0 = time.perf_counter()
        for _ in range(10):
            place = waiting.queue_place(s, newest)
        print(f"queue place: {(time.perf_counter() - t0) * 100:.1f} ms ({place})")


if __name__ == "__main__":
    main()
