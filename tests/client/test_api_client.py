"""The participant's side, end to end: a real ``robobpp serve`` subprocess (offline episodes), policies served
with the SDK, and the API client and ``robobpp submit`` / ``submissions`` / ``leaderboard`` against them."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from robobpp import __version__ as robobpp_version
from robobpp.client.api import ServerClient, ServerError, Standing
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.policies.dbl import DBL
from robobpp.schemas import SubmissionPublic
from tests.server.conftest import (
    ADMIN_TOKEN,
    ServerProcess,
    SlowDBL,
    free_port,
    new_participant,
    server_env,
    wait_for,
)
from tests.server.test_board import NaNPolicy

SECRET = "policy-secret-123"
#: A board's line in the results: "math/diverse  score 0.812 [0.790, 0.835] · rank 2 (1–3) of 9 · stable …".
RANK = re.compile(
    r"math/diverse\s+score \d\.\d{3} \[\d\.\d{3}, \d\.\d{3}\] · rank (\d+)(?: \(\d+–\d+\))? of (\d+) · "
    r"stable \d\.\d{3} \[\d\.\d{3}, \d\.\d{3}\]"
)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """One server for the module (starting one costs seconds): Math only, 2 groups, DBL baseline."""
    state = tmp_path_factory.mktemp("server")
    env = server_env(
        state,
        f"sqlite:///{state / 'api.sqlite3'}",
        ROBOBPP_QUOTA_CONCURRENT="10",
        ROBOBPP_QUOTA_SUBMISSIONS_PER_DAY="50",
    )
    proc = ServerProcess(env, state).start()
    yield proc
    proc.crash()


@pytest.fixture(scope="module")
def fast() -> Iterator[BackgroundServer]:
    with BackgroundServer(create_policy_app(DBL, SECRET)) as srv:
        yield srv


@pytest.fixture(scope="module")
def slow() -> Iterator[BackgroundServer]:
    with BackgroundServer(create_policy_app(SlowDBL, SECRET)) as srv:
        yield srv


@pytest.fixture(scope="module")
def token(server: ServerProcess) -> str:
    with server.client() as admin:
        return new_participant(admin, "alice")


@pytest.fixture
def api(server: ServerProcess, token: str) -> Iterator[ServerClient]:
    with ServerClient(server.url, token, timeout=30) as client:
        yield client


@pytest.fixture(scope="module")
def cli() -> CliRunner:
    from robobpp.cli import register_commands

    register_commands()
    return CliRunner()


def run_cli(cli: CliRunner, server: ServerProcess | str, token: str | None, *args: str) -> Result:
    """``robobpp ARGS`` in-process (fast); the server is still the real subprocess, over HTTP."""
    from robobpp.cli import app

    url = server if isinstance(server, str) else server.url
    env = {"ROBOBPP_SERVER": url, "ROBOBPP_TOKEN": token or "", "ROBOBPP_POLICY_SECRET": ""}
    return cli.invoke(app, list(args), env=env)


def cli_env(server: ServerProcess, token: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROBOBPP_")}
    return {**env, "ROBOBPP_SERVER": server.url, "ROBOBPP_TOKEN": token, "COLUMNS": "200"}


def board_line(s: Standing) -> str:
    """What the results say of a ranked standing, written out here from the board's figures."""
    assert s.score is not None and s.stable is not None and s.score_low is not None
    rank = str(s.rank) if s.rank_low == s.rank_high == s.rank else f"{s.rank} ({s.rank_low}–{s.rank_high})"
    return (
        f"{s.board}  score {s.score:.3f} [{s.score_low:.3f}, {s.score_high:.3f}] · rank {rank} of {s.entries}"
        f" · stable {s.stable:.3f} [{s.stable_low:.3f}, {s.stable_high:.3f}]"
    )


def robobpp(*args: str) -> list[str]:
    """The real command line (entry point, exit code), not an in-process call."""
    return [sys.executable, "-m", "robobpp.cli", *args]


def test_submit_wait_prints_the_results_with_rank_per_board(
    server: ServerProcess, fast: BackgroundServer, token: str, api: ServerClient
) -> None:
    # the baseline first: participants are served before baselines, so it could finish after this one and
    # move its rank between the printed table and the check below
    baseline = wait_for(
        lambda: next((e for e in api.leaderboard("diverse", "math").entries if e.baseline), None), 120
    )
    args = robobpp(
        "submit", fast.url, "--secret", SECRET, "--name", "cli dbl", "--dataset", "diverse", "--wait"
    )
    env = cli_env(server, token)
    done = subprocess.run([*args, "--poll", "0.3"], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr + done.stdout
    assert "Traceback" not in done.stderr
    sub = next(s for s in api.submissions() if s.name == "cli dbl")
    assert sub.status == "completed" and sub.progress.episodes_done == sub.progress.episodes_total == 2
    assert f"submitted #{sub.id} cli dbl: 2 episodes on 1 board" in done.stderr
    assert "2/2" in done.stderr  # the progress bar reached the end
    match = RANK.search(done.stdout)
    assert match, done.stdout
    (standing,) = api.standings(sub)
    assert standing.board == "math/diverse" and standing.rank is not None
    assert (int(match[1]), int(match[2])) == (standing.rank, standing.entries)
    # every figure with the board's own interval: the standing's are the published board entry's
    entry = next(
        e for e in api.leaderboard("diverse", "math", view="all").entries if e.submission_id == sub.id
    )
    assert (standing.score_low, standing.score_high, standing.stable_low, standing.stable_high) == (
        entry.score_low,
        entry.score_high,
        entry.stable_low,
        entry.stable_high,
    )
    assert (standing.rank_low, standing.rank_high, standing.intervals) == (
        entry.rank_low,
        entry.rank_high,
        entry.intervals,
    )
    assert (standing.groups, standing.resamples, standing.confidence) == (2, 1000, 0.95)
    # the score, the rank and the stable score (alone on a board the relative score is 0, and the stable one
    # says how well it did), each with its interval, in one line
    assert board_line(standing) in done.stdout.splitlines(), done.stdout
    for key, value in standing.metrics.items():  # each metric, its interval under it
        low, high = standing.intervals[key] or (None, None)
        assert f"{value:.4f}" in done.stdout and f"[{low:.4f}, {high:.4f}]" in done.stdout, key
    words = " ".join(done.stdout.split())
    assert (
        "[low, high]: the bootstrap 95 % interval over the board's 2 groups (1000 seeded resamples" in words
    )
    assert "2 to 5 in 95 % of resamples" in words and "are not clearly apart" in words
    assert "stable: against fixed anchors" in words
    # the DBL baseline ran in-process on the same episodes: same geometry as the remote DBL
    assert baseline.metrics["space_utilization"] == pytest.approx(standing.metrics["space_utilization"])


def test_submit_wait_and_connect_show_the_rank_the_board_gets_a_moment_later(
    tmp_path_factory: pytest.TempPathFactory, fast: BackgroundServer
) -> None:
    """Boards are recomputed a moment after a submission finishes (here: the version is re-read every 4 s,
    and someone reads the board all along), so the result table printed score — and rank — every time; the
    headline now waits, bounded, for the board that includes the submission."""
    state = tmp_path_factory.mktemp("lagging")
    env = server_env(state, f"sqlite:///{state / 'lag.sqlite3'}", ROBOBPP_BOARD_REFRESH_S="4")
    server = ServerProcess(env, state).start()
    try:
        with server.client() as admin:
            token = new_participant(admin, "bob")
            # the baseline first: participants are served before baselines, so it could finish after ours
            wait_for(lambda: admin.get("/leaderboards/diverse/math").json()["total"] >= 1, 120)
        runs = {
            "submit": robobpp(
                "submit",
                fast.url,
                "--secret",
                SECRET,
                "--name",
                "lag push",
                "--dataset",
                "diverse",
                "--wait",
                "--poll",
                "0.3",
            ),
            "connect": robobpp("connect", "dbl", "--name", "lag pull", "--dataset", "diverse"),
        }
        with ServerClient(server.url, token, timeout=30) as reader:
            for label, args in runs.items():
                proc = subprocess.Popen(
                    args,
                    env=cli_env(server, token),
                    stdout=subprocess.PIPE,
                    stderr=subprocess.PIPE,
                    text=True,
                )
                try:
                    while proc.poll() is None:  # a page open on the board keeps its version fresh in cache
                        reader.leaderboard("diverse", "math")
                        time.sleep(0.2)
                    out, errs = proc.communicate(timeout=60)
                finally:
                    if proc.poll() is None:
                        proc.kill()
                assert proc.returncode == 0, (label, errs + out)
                match = RANK.search(
                    out
                )  # the score, rank and stable score with intervals, off a terminal too
                assert match, (label, out)
                assert int(match[1]) >= 1 and int(match[2]) >= 2, (label, out)  # the baseline and this one
                assert "bootstrap 95 % interval" in out, (label, out)
                assert "did not include" not in errs, (label, errs)
                assert f"provenance: robobpp {robobpp_version}" in errs and "math_rules" in errs, (
                    label,
                    errs,
                )
    finally:
        server.crash()


def test_client_submit_wait_episodes_boards_and_grid(api: ServerClient, fast: BackgroundServer) -> None:
    me = api.me()
    assert me.participant is not None and me.participant.name == "alice" and not me.admin
    sub = api.submit(fast.url, SECRET, None, ["longboard"], ["math"], "public")
    assert sub.name == "dbl" and sub.status == "queued" and sub.track == "public"
    seen: list[tuple[str, int, int]] = []

    def note(s: SubmissionPublic) -> None:
        seen.append((s.status, s.progress.episodes_done, s.progress.episodes_total))

    final = api.wait(sub.id, on_progress=note, poll_s=0.2)
    assert final.status == "completed" and seen[-1] == ("completed", 2, 2)
    assert [d for _, d, _ in seen] == sorted(d for _, d, _ in seen)  # progress never goes back
    episodes = api.episodes(sub.id)
    assert [e.status for e in episodes] == ["done", "done"] and all(e.termination for e in episodes)
    assert api.episode(sub.id, episodes[0].id).trace is not None  # public track keeps the replay
    board = api.leaderboard("longboard", "math", track="public")
    entry = next(e for e in board.entries if e.submission_id == sub.id)
    assert final.runs[0].metrics is not None
    assert entry.metrics["space_utilization"] == final.runs[0].metrics["space_utilization"]
    grid = api.grid("public")
    assert sub.id in {row.submission_id for row in grid.rows + grid.apart}  # one board of several: apart
    assert sub.id not in {row.submission_id for row in api.grid("private").rows}
    assert sub.id in [s.id for s in api.submissions()]


def test_cancel_list_and_episodes_through_the_cli(
    server: ServerProcess, slow: BackgroundServer, token: str, api: ServerClient, cli: CliRunner
) -> None:
    """A waiting ``submit --wait`` exits non-zero when its submission ends other than completed."""
    args = robobpp(
        "submit", slow.url, "--secret", SECRET, "--name", "slow one", "--dataset", "repetitive,diverse"
    )
    waiting = subprocess.Popen(
        [*args, "--wait", "--poll", "0.3"],
        env=cli_env(server, token),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        sub = wait_for(lambda: next((s for s in api.submissions() if s.name == "slow one"), None), 60)
        wait_for(lambda: api.submission(sub.id).progress.episodes_running, 60)
        r = run_cli(cli, server, token, "submissions", "cancel", str(sub.id))
        assert r.exit_code == 0, r.output
        assert f"submission {sub.id} cancelled (4 episodes cancelled)" in r.stdout
        out, errs = waiting.communicate(timeout=60)
    finally:
        waiting.kill()
    assert waiting.returncode == 1, errs
    assert f"error: submission {sub.id} cancelled" in errs and "Traceback" not in errs
    # the results were still printed, saying why there is no score (each run ended with the cancellation)
    assert re.search(r"math/diverse\s+no result — it was cancelled, so no score, rank or interval", out), out
    assert "[low, high]" not in out  # no interval shown: none explained

    listed = run_cli(cli, server, token, "submissions", "list")
    assert listed.exit_code == 0 and re.search(rf"\b{sub.id}\b.*slow one.*cancelled", listed.stdout)
    episodes = run_cli(cli, server, token, "submissions", "episodes", str(sub.id))
    assert episodes.exit_code == 0 and episodes.stdout.count("cancelled") == 4
    again = run_cli(cli, server, token, "submissions", "cancel", str(sub.id))
    assert again.exit_code == 1 and again.stderr.startswith("error: 409: Already finished:")


def test_a_failed_submission_says_why_it_has_no_score_rank_or_interval(
    server: ServerProcess, token: str, api: ServerClient, cli: CliRunner
) -> None:
    """A policy that answers NaN fails every episode: its run is listed apart on the board, and the results
    say so in the board's words rather than show a blank rank."""
    with BackgroundServer(create_policy_app(NaNPolicy, None)) as nan:
        args = robobpp(
            "submit", nan.url, "--name", "nan one", "--dataset", "diverse", "--wait", "--poll", "0.3"
        )
        done = subprocess.run(args, env=cli_env(server, token), capture_output=True, text=True, timeout=120)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    sub = next(s for s in api.submissions() if s.name == "nan one")
    (apart,) = api.leaderboard("diverse", "math", view="all", submission=sub.id).unranked
    (standing,) = api.standings(sub)
    assert (standing.board_status, standing.reason, standing.rank) == ("failed", apart.reason, None)
    line = f"math/diverse  not ranked — failed: {apart.reason}; a failed or partial entry gets no score, rank or interval"
    assert line in done.stdout.splitlines(), done.stdout
    assert "[low, high]" not in done.stdout  # no interval shown: none explained
    shown = run_cli(cli, server, token, "submissions", "show", str(sub.id))
    assert shown.exit_code == 0 and line in shown.stdout.splitlines(), shown.output


def test_a_rank_without_its_interval_yet_says_when_it_comes() -> None:
    """On a large board a new entry's all-entries rank interval waits for the board's next full computation
    (docs/server.md): the line says so rather than pass the rank alone off as certain."""
    from robobpp.cli.submit import standing_line

    common: dict[str, Any] = dict(
        dataset="diverse", setting="math", status="completed", metrics={}, metric_keys=[], entries=14
    )
    figures: dict[str, Any] = dict(
        score=0.5, score_low=0.4, score_high=0.6, stable=0.7, stable_low=0.65, stable_high=0.75
    )
    waiting = standing_line(Standing(**common, **figures, rank=3, board_status="ranked"))
    assert "rank 3 of 14 [dim](its rank interval comes with the board's next full computation)[/]" in waiting
    known = standing_line(Standing(**common, **figures, rank=3, rank_low=2, rank_high=5))
    assert "rank 3 [dim](2–5)[/] of 14 · " in known and "full computation" not in known


def test_leaderboard_command_shows_boards_and_the_grid(
    server: ServerProcess, fast: BackgroundServer, token: str, api: ServerClient, cli: CliRunner
) -> None:
    sub = api.wait(api.submit(fast.url, SECRET, "for board", ["diverse"]).id, poll_s=0.2)
    board = run_cli(
        cli, server, None, "leaderboard", "--dataset", "diverse", "--setting", "math", "--view", "all"
    )
    assert board.exit_code == 0, board.output
    assert "Space Utilization (0.6)" in board.stdout and f"#{sub.id} for board" in board.stdout
    grid = run_cli(cli, server, None, "leaderboard", "--view", "all")
    assert grid.exit_code == 0 and "math/diverse" in grid.stdout and f"#{sub.id} for board" in grid.stdout
    as_json = run_cli(cli, server, None, "leaderboard", "--dataset", "diverse", "--setting", "math", "--json")
    assert '"entries"' in as_json.stdout
    shown = run_cli(cli, server, token, "submissions", "show", str(sub.id))
    assert shown.exit_code == 0, shown.output
    (standing,) = api.standings(sub)
    assert board_line(standing) in shown.stdout.splitlines(), shown.stdout
    assert "bootstrap 95 % interval" in shown.stdout
    bad = run_cli(cli, server, None, "leaderboard", "--dataset", "diverse")
    assert bad.exit_code == 2 and "both --dataset and --setting" in bad.stderr


def test_errors_are_one_line_with_the_status(
    server: ServerProcess, fast: BackgroundServer, token: str, cli: CliRunner
) -> None:
    cases: list[tuple[tuple[str | None, *tuple[str, ...]], int, str]] = [
        ((None, "submissions", "list"), 2, "error: no API token: pass --token or set ROBOBPP_TOKEN"),
        (("nope", "submissions", "list"), 1, "error: 401: Unauthorized: the API token is not valid"),
        ((token, "submissions", "show", "999999"), 1, "error: 404: Not found: no submission 999999"),
        ((token, "submit", f"http://127.0.0.1:{free_port()}"), 1, "error: 422: Policy unreachable:"),
        ((token, "submit", fast.url, "--secret", "not-the-secret"), 1, "error: 422: Signature mismatch:"),
        ((token, "submit", fast.url, "--dataset", "moon"), 2, "error: unknown dataset moon"),
        ((token, "submit", fast.url, "--track", "secret"), 2, "error: unknown track 'secret'"),
    ]
    for (tok, *args), code, start in cases:
        r = run_cli(cli, server, tok, *args)
        assert r.exit_code == code, (args, r.output)
        assert r.stderr.startswith(start), (args, r.stderr)
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.output, (args, r.stderr)
    down = f"http://127.0.0.1:{free_port()}"
    r = run_cli(cli, down, token, "submissions", "list")
    assert r.exit_code == 1 and r.stderr.startswith(f"error: cannot reach the server at {down}")


def test_client_errors_carry_status_kind_and_plain_words(
    server: ServerProcess, fast: BackgroundServer, token: str
) -> None:
    with ServerClient(server.url + "/api/v1/", "wrong") as bad:
        with pytest.raises(ServerError) as info:
            bad.me()
        assert (info.value.status, info.value.kind) == (401, "unauthorized")
        assert str(info.value).startswith("401: Unauthorized: ")
        assert bad.leaderboard("diverse", "math").dataset == "diverse"  # boards are public
    with ServerClient(server.url, token) as api:
        with pytest.raises(ServerError) as info:
            api.submit(fast.url, "short", "x")  # secrets have at least 8 characters
        assert info.value.status == 422 and info.value.kind == "validation-error"
        assert "secret" in info.value.detail and info.value.errors
        with pytest.raises(ServerError, match="^422: "):
            api.leaderboard("moon", "math")
    # a server that is not the evaluation service: status and the start of its body, in one line
    with ServerClient(fast.url, token) as wrong, pytest.raises(ServerError) as info:
        wrong.me()
    assert info.value.status == 404 and "not an API answer" in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ServerError, match="not an http"):
        ServerClient("ftp://example.org", token)


def test_revoked_token_stops_working_for_the_client(server: ServerProcess) -> None:
    with server.client() as admin:
        fresh = new_participant(admin, "revoker")
    with ServerClient(server.url, fresh) as api:
        (mine,) = api.tokens()
        assert fresh.startswith(mine.prefix) and mine.revoked_at is None
        assert api.revoke_token(mine.id).revoked_at is not None
        with pytest.raises(ServerError, match=r"^401: .*revoked"):
            api.me()


def test_operator_creates_a_participant_whose_token_submits_and_can_be_revoked(
    server: ServerProcess, cli: CliRunner, fast: BackgroundServer
) -> None:
    created = run_cli(cli, server, ADMIN_TOKEN, "participants", "create", "carol")
    assert created.exit_code == 0, created.output
    new = created.stdout.strip().splitlines()[-1]  # the token alone on its line, for `$(...)`
    with ServerClient(server.url, new) as api:
        me = api.me()
        assert me.participant is not None and me.participant.name == "carol"
        api.submit(fast.url, SECRET, name="carol dbl", datasets=["diverse"], settings=["math"])
    listed = run_cli(cli, server, new, "tokens", "list")
    assert listed.exit_code == 0 and new[:10] in listed.stdout
    (mine,) = ServerClient(server.url, new).tokens()
    assert run_cli(cli, server, new, "tokens", "revoke", str(mine.id)).exit_code == 0
    assert run_cli(cli, server, new, "tokens", "list").exit_code == 1  # revoked: 401
    taken = run_cli(cli, server, ADMIN_TOKEN, "participants", "create", "carol")
    assert taken.exit_code == 1 and "409" in taken.output
    not_admin = run_cli(cli, server, new, "participants", "new-token", "1")
    assert not_admin.exit_code == 1 and "401" in not_admin.output


def test_wait_gives_up_on_an_unreachable_server_after_its_patience() -> None:
    """``wait`` keeps polling while the server cannot be reached (a restart), but not for ever."""
    with ServerClient(f"http://127.0.0.1:{free_port()}", "t") as api:
        started = time.monotonic()
        with pytest.raises(ServerError, match="cannot reach"):
            api.wait(1, poll_s=0.05, patience_s=0.3)
        assert time.monotonic() - started >= 0.3


@pytest.mark.parametrize(
    ("url", "warn"),
    [
        ("http://127.0.0.1:8000", False),
        ("http://localhost:8000", False),
        ("http://[::1]:8000", False),
        ("https://bench.example.org", False),
        ("http://bench.example.org", True),
        ("http://10.0.0.5:80", True),
    ],
)
def test_plain_http_to_another_machine_is_flagged(url: str, warn: bool) -> None:
    from robobpp.cli.submit import plain_http_elsewhere

    assert plain_http_elsewhere(url) is warn
