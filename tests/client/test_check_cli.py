"""`robobpp protocol check` and `robobpp policy serve`, and the shipped example policy server."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

from typer.testing import CliRunner

from robobpp.cli import app, register_commands
from robobpp.client.check import check_policy_server
from robobpp.client.loading import load_policy
from robobpp.client.remote import RemotePolicy
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.episode import run_episode
from robobpp.policies.dbl import DBL
from tests.client.hostile import HostileServer

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "policy_server.py"
runner = CliRunner()
register_commands()


def _cli(*args: str):
    return runner.invoke(app, list(args), catch_exceptions=False)


def test_check_passes_a_conforming_signed_server() -> None:
    with BackgroundServer(create_policy_app(DBL(), "s3cret")) as server:
        result = _cli("protocol", "check", server.url, "--secret", "s3cret")
    assert result.exit_code == 0, result.output
    assert "no violations" in result.output
    assert "stale timestamp refused with HTTP 401" in result.output


def test_check_reports_every_violation_and_fails() -> None:
    with HostileServer(secret="s3cret") as server:
        report = check_policy_server(f"{server.url}/extra", "s3cret", step_timeout_s=2)
        result = _cli("protocol", "check", f"{server.url}/nan", "--timeout", "2")
    problems = [f.message for f in report.violations]
    # The hostile server accepts anything: each signature probe is its own violation, then the bad answer.
    assert sum("must be refused with 401" in m for m in problems) == 3
    assert any("unknown field 'z'" in m for m in problems)
    assert result.exit_code == 1
    assert "input should be a finite number" in result.output and "violation(s)" in result.output


def test_check_of_an_unreachable_server_fails_cleanly() -> None:
    with HostileServer() as server:
        url = server.url
    result = _cli("protocol", "check", url, "--timeout", "1")
    assert result.exit_code == 1
    assert "cannot connect" in result.output


def test_schema_command_prints_every_message(tmp_path: Path) -> None:
    out = tmp_path / "schema.json"
    assert _cli("protocol", "schema", "--out", str(out)).exit_code == 0
    assert {"ActRequest", "ActResponse", "ResetRequest", "CloseRequest", "InfoResponse"} <= set(
        json.loads(out.read_text())["$defs"]
    )


def test_policy_serve_refuses_a_url_and_unknown_policies() -> None:
    assert "not a URL" in _cli("policy", "serve", "http://x").output
    assert "unknown policy" in _cli("policy", "serve", "nope").output


def test_load_policy_turns_a_url_into_a_remote_policy(small_spec) -> None:
    with BackgroundServer(create_policy_app(DBL())) as server:
        policy = load_policy(server.url)
        assert isinstance(policy, RemotePolicy)
        result = run_episode(small_spec, policy, "math")
    assert result.termination == "completed"


def test_example_policy_server_passes_the_check(random_spec) -> None:
    spec = importlib.util.spec_from_file_location("example_policy_server", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    with BackgroundServer(create_policy_app(module.LowestFirst())) as server:
        assert check_policy_server(server.url).ok
        result = run_episode(random_spec, RemotePolicy(server.url), "math")
    assert result.boxes_placed > 10


class _RepetitiveOnly(DBL):
    """A policy built for one container and setting, as a trained agent is (its input has that shape)."""

    def reset(self, info) -> None:
        if (info.container.length, info.container.width) != (134, 125) or info.setting != "physics":
            raise ValueError(f"trained on Repetitive · physics, got {info.dataset} · {info.setting}")


def test_check_runs_the_dataset_and_setting_asked_for(real_data) -> None:
    """`--dataset`/`--setting` check the episode the policy will play; the default Diverse/Math one fails a
    policy built for another container (the project's PPO example did)."""
    with BackgroundServer(create_policy_app(_RepetitiveOnly())) as server:
        default = _cli("protocol", "check", server.url, "--timeout", "30")
        asked = _cli(
            "protocol",
            "check",
            server.url,
            "--dataset",
            "repetitive",
            "--setting",
            "physics",
            "--boxes",
            "4",
            "--timeout",
            "30",
        )
    assert default.exit_code == 1 and "trained on Repetitive" in default.output
    assert asked.exit_code == 0, asked.output
    assert "repetitive · physics" in asked.output and "no violations" in asked.output
    unknown = _cli("protocol", "check", "http://127.0.0.1:9", "--dataset", "nope")
    assert unknown.exit_code == 2 and "unknown dataset 'nope'" in unknown.output
    assert "unknown setting" in _cli("protocol", "check", "http://127.0.0.1:9", "--setting", "x").output
