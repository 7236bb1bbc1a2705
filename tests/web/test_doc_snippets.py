"""Every shell and Python snippet in README.md and docs/*.md runs as written, or says why not.

Each ```bash / ```python block is preceded by ``<!-- snippet: run ... -->`` or ``<!-- snippet: not run
(reason) -->``. Every block is checked: it parses (``bash -n``, ``compile``), every ``robobpp`` command in
it is parsed by the real CLI (unknown options, bad values and missing arguments fail), and every
``--secret`` meets the server's minimum. Blocks marked ``run`` are executed: a Python block marked plainly
``run`` in a fresh interpreter with the real datasets (the README's Gymnasium example, the docs' import
examples), the protocol curl session (against the policy server it names, each answer compared with the
comment under it) and the ``ServerClient`` example (against the tests' evaluation server).
"""

from __future__ import annotations

import functools
import json
import os
import re
import runpy
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import typer

# Recent Typer ships its own copy of click: the CLI's errors are that copy's.
from typer._click.exceptions import ClickException

from robobpp.schemas import SubmissionCreate
from tests.web.conftest import Server

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
CODE_LANGS = {"bash", "sh", "shell", "python"}
MARKER = re.compile(r"<!-- snippet: (run|not run)\b(.*?)-->")


@dataclass(frozen=True)
class Snippet:
    path: Path
    line: int
    lang: str
    marker: str  # "run", "not run", or "" (missing)
    note: str
    code: str

    def __str__(self) -> str:
        return f"{self.path.name}:{self.line}"


def snippets(path: Path) -> list[Snippet]:
    lines = path.read_text().splitlines()
    found, i = [], 0
    while i < len(lines):
        fence = re.match(r"^```(\w*)\s*$", lines[i])
        if not fence:
            i += 1
            continue
        start, lang = i, fence.group(1)
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        code = "\n".join(lines[start + 1 : end])
        before = next((lines[j] for j in range(start - 1, -1, -1) if lines[j].strip()), "")
        m = MARKER.search(before)
        if lang in CODE_LANGS or re.search(r"^(robobpp|python|curl) ", code, re.M):
            found.append(
                Snippet(path, start + 1, lang, m.group(1) if m else "", m.group(2).strip() if m else "", code)
            )
        i = end + 1
    return found


ALL = [s for p in DOCS for s in snippets(p)]


def _min_secret() -> int:
    meta = SubmissionCreate.model_fields["secret"].metadata or []
    constraint = SubmissionCreate.model_fields["secret"].annotation.__args__[0].__metadata__[0]  # type: ignore[union-attr]
    return next((m.min_length for m in meta if getattr(m, "min_length", None)), constraint.min_length)


def _commands(code: str) -> list[list[str]]:
    """The ``robobpp`` command lines of a shell snippet, as argument lists (env assignments dropped)."""
    out = []
    for raw in code.replace("\\\n", " ").splitlines():
        try:
            words = shlex.split(raw, comments=True)
        except ValueError:
            continue
        cmd: list[str] = []
        for w in [*words, ";"]:
            if w in ("&&", "||", ";", "|"):
                while cmd and re.match(r"^[A-Z_]+=", cmd[0]):
                    cmd.pop(0)
                if cmd and cmd[0] == "export":
                    cmd = []
                if cmd and cmd[0] == "robobpp":
                    out.append(cmd[1:])
                cmd = []
            else:
                cmd.append(w)
    return out


@functools.cache
def _cli() -> Any:
    from robobpp.cli import app, register_commands

    register_commands()
    return typer.main.get_command(app)


def _parse_cli(args: list[str]) -> None:
    """Parse (never run) a command line with robobpp's own CLI: raises click's error on a bad line."""
    command = _cli()
    ctx = command.context_class(command, info_name="robobpp")
    rest = list(args)
    while hasattr(command, "get_command"):  # a group: walk down to the command
        assert rest, "a command group with no command"
        if rest[0].startswith("-"):  # the root's own options (--version): eager, they end the command
            assert any(rest[0] in p.opts for p in command.params), f"no option {rest[0]!r}"
            return
        name, rest = rest[0], rest[1:]
        sub = command.get_command(ctx, name)
        assert sub is not None, f"no command {name!r}"
        command = sub
        ctx = command.context_class(command, info_name=name, parent=ctx)
    command.make_context(ctx.info_name, rest, parent=ctx.parent)


def test_the_docs_have_snippets() -> None:
    assert len(ALL) >= 8 and any(s.marker == "run" for s in ALL)


@pytest.mark.parametrize("snippet", ALL, ids=str)
def test_every_snippet_is_marked_and_parses(snippet: Snippet) -> None:
    assert snippet.lang in CODE_LANGS, f"{snippet}: give the block a language (```bash or ```python)"
    assert snippet.marker, (
        f"{snippet}: precede it with <!-- snippet: run --> or <!-- snippet: not run (why) -->"
    )
    if snippet.marker == "not run":
        assert len(snippet.note) > 10, f"{snippet}: say why it is not run"
    if snippet.lang == "python":
        compile(snippet.code, str(snippet), "exec")
        return
    check = subprocess.run(["bash", "-n"], input=snippet.code, text=True, capture_output=True)
    assert check.returncode == 0, f"{snippet}: {check.stderr}"
    for args in _commands(snippet.code):
        try:
            _parse_cli(args)
        except ClickException as exc:
            raise AssertionError(f"{snippet}: `robobpp {shlex.join(args)}`: {exc.format_message()}") from None
        if "--secret" in args:
            secret = args[args.index("--secret") + 1]
            assert len(secret) >= _min_secret(), (
                f"{snippet}: the server refuses the secret {secret!r} (too short)"
            )


def test_the_cli_check_catches_a_broken_line() -> None:
    """The checks above can fail: a wrong option, a bad value and a short secret are all caught."""
    for bad in (
        ["evaluate", "--policy", "dbl", "--no-such-option"],
        ["evaluate", "--policy", "dbl", "--groups", "x"],
    ):
        with pytest.raises(ClickException):
            _parse_cli(bad)
    _parse_cli(["evaluate", "--policy", "dbl", "--groups", "3"])
    assert _commands("ROBOBPP_TOKEN=x robobpp submit http://h:9000 --secret s3cret --wait  # c") == [
        ["submit", "http://h:9000", "--secret", "s3cret", "--wait"]
    ]
    assert _min_secret() == 8


def _only(marker_note: str) -> Snippet:
    found = [s for s in ALL if s.marker == "run" and marker_note in s.note]
    assert len(found) == 1, f"no single run snippet marked {marker_note!r}"
    return found[0]


PLAIN_RUN = [s for s in ALL if s.marker == "run" and not s.note and s.lang == "python"]


def test_every_doc_is_covered() -> None:
    """Every page under docs/ is read (a new page is picked up without editing this file)."""
    assert {p.name for p in DOCS} >= {"README.md", "benchmark.md", "protocol.md", "server.md", "datasets.md"}
    assert any(s.path.name == "README.md" for s in PLAIN_RUN) and len({s.path for s in PLAIN_RUN}) >= 3


@pytest.mark.parametrize("snippet", PLAIN_RUN, ids=str)
def test_python_snippet_runs(snippet: Snippet, real_data_root: Path) -> None:
    env = {**os.environ, "ROBOBPP_DATA_DIR": str(real_data_root), "PYTHONPATH": str(ROOT)}
    code = snippet.code + "\nprint('SNIPPET-DONE')\n"
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, text=True, capture_output=True, timeout=300, cwd=ROOT
    )
    assert done.returncode == 0, f"{snippet}: {done.stderr[-2000:]}"
    assert "SNIPPET-DONE" in done.stdout


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_protocol_curl_session_replays_as_recorded() -> None:
    snippet = _only("against robobpp policy serve dbl")
    recorded = re.search(r"policy serve (dbl --port (\d+) --secret (\S+))\)", snippet.note)
    assert recorded is not None, snippet.note
    port = _free_port()
    server = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from robobpp.cli import main; main()",
            "policy",
            "serve",
            "dbl",
            "--port",
            str(port),
            "--secret",
            recorded.group(3),
        ],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                httpx.get(f"http://127.0.0.1:{port}/info", timeout=1)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline and server.poll() is None, (
                    "the policy server did not start"
                )
                time.sleep(0.2)
        # Run each command, print a separator after the ones that have a recorded answer under them.
        script, expected = [], []
        for line in snippet.code.replace(f"localhost:{recorded.group(2)}", f"localhost:{port}").splitlines():
            answer = re.match(r"^# (\{.*\})", line)
            if answer:
                script.append("echo; echo @@@")
                expected.append(json.loads(answer.group(1)))
            elif not line.startswith("#"):
                script.append(line)
        done = subprocess.run(
            ["bash", "-euo", "pipefail", "-c", "\n".join(script)], text=True, capture_output=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
        answers = [json.loads(a) for a in done.stdout.split("@@@")[:-1]]
        assert len(answers) == len(expected) >= 5
        for got, want in zip(answers, expected, strict=True):
            got.pop("compute_time", None), want.pop("compute_time", None)
            assert got == want
    finally:
        server.terminate()
        server.wait(10)


def test_server_client_snippet_runs_against_a_server(server: Server) -> None:
    from robobpp.client.serve import BackgroundServer, create_policy_app

    snippet = _only("ServerClient") if any("ServerClient" in s.note for s in ALL) else _only("test server")
    r = server.client.post("/api/v1/participants", json={"name": "snippet-runner"})
    assert r.status_code == 201, r.text
    token = r.json()["token"]
    LowestFirst = runpy.run_path(str(ROOT / "examples" / "policy_server.py"))["LowestFirst"]
    found = re.search(r'secret="([^"]+)"', snippet.code)
    assert found is not None, snippet.code
    secret = found.group(1)
    with BackgroundServer(create_policy_app(LowestFirst(), secret)) as policy:
        code = snippet.code.replace("http://127.0.0.1:8000", server.url).replace(
            "http://my-host:9000", policy.url
        )
        code = code.replace('track="private"', 'track="public"')  # keeps the private boards other tests count
        printed: list[str] = []
        namespace = {"token": token, "print": lambda *a: printed.append(" ".join(map(str, a)))}
        exec(compile(code, str(snippet), "exec"), namespace)
    sub = namespace["sub"]
    assert sub.status == "completed", sub
    assert printed and any(line.startswith("math/diverse") or "diverse" in line for line in printed), printed
