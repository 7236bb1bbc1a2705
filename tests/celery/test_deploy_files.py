"""docker-compose.yml and the Dockerfile agree with the code, read without Docker (tests/deploy runs them).

Each check is one way a deployment breaks on first start: a command the CLI does not know, an environment
variable the settings object silently ignores (``extra="ignore"``), a worker that cannot be scaled, a value
that fails validation, an image that runs as root or ships the private split.
"""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import typer.main
import yaml
from sqlalchemy.engine import make_url

from robobpp.cli import app as cli_app
from robobpp.cli import main as _cli_main  # noqa: F401 - the module registers commands in main()
from robobpp.server.config import Settings
from robobpp.worker.celery_app import check_broker_url

ROOT = Path(__file__).resolve().parents[2]
PLACEHOLDER = re.compile(r"\$\{([A-Z0-9_]+)(?::?[-?][^}]*)?\}")


def _compose() -> dict[str, Any]:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def _substitute(value: str) -> str:
    """Fill compose ``${VAR...}`` placeholders as an operator would (strong secrets, the defaults)."""

    def fill(m: re.Match[str]) -> str:
        name, rest = m.group(1), m.group(0)
        if ":-" in rest:
            return rest.split(":-", 1)[1].rstrip("}")
        return "x" * 8 + name.lower().replace("_", "")[:24] + "0123456789abcdef"

    return PLACEHOLDER.sub(fill, value)


def _cli_group() -> Any:
    """The click group typer builds (typer vendors its own click, so no isinstance check)."""
    from robobpp.cli import register_commands

    register_commands()
    return typer.main.get_command(cli_app)


def _parse_cli(argv: list[str]) -> Any:
    """Parse a container command with the real CLI (no invocation); unknown options fail here."""
    assert argv[0] == "robobpp", f"container command must run the robobpp entry point: {argv}"
    group = _cli_group()
    cmd = group.commands.get(argv[1])
    assert cmd is not None, f"unknown command {argv[1]!r} (known: {sorted(group.commands)})"
    cmd.make_context(argv[1], list(argv[2:]))
    return cmd


def _env(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment") or {}
    if isinstance(env, list):
        env = dict(item.split("=", 1) for item in env)
    return {k: _substitute(str(v)) for k, v in env.items()}


def _settings_fields() -> set[str]:
    # ROBOBPP_DATA_DIR is the datasets cache (robobpp.datasets.cache), read outside the server settings.
    return {f"ROBOBPP_{name.upper()}" for name in Settings.model_fields} | {"ROBOBPP_DATA_DIR"}


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    return _compose()


def test_compose_has_the_four_services_and_named_volumes(compose: dict[str, Any]) -> None:
    services = compose["services"]
    assert {"postgres", "redis", "server", "worker"} <= set(services)
    for svc in services.values():
        for mount in svc.get("volumes", []):
            source = str(mount).split(":", 1)[0]
            if not source.startswith((".", "/")):
                assert source in compose["volumes"], f"volume {source!r} is not declared"


def test_worker_service_can_be_scaled(compose: dict[str, Any]) -> None:
    worker = compose["services"]["worker"]
    # `docker compose up --scale worker=N` refuses fixed names and host ports.
    assert "container_name" not in worker
    assert "ports" not in worker


@pytest.mark.parametrize("service", ["server", "worker"])
def test_every_robobpp_variable_is_a_setting(compose: dict[str, Any], service: str) -> None:
    env = _env(compose["services"][service])
    unknown = {k for k in env if k.startswith("ROBOBPP_")} - _settings_fields()
    assert not unknown, f"{service}: variables the settings object would ignore: {sorted(unknown)}"


@pytest.mark.parametrize("service", ["server", "worker"])
def test_service_environment_validates_as_production_settings(
    compose: dict[str, Any], service: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    for key in list(__import__("os").environ):
        if key.startswith("ROBOBPP_"):
            monkeypatch.delenv(key)
    for key, value in _env(compose["services"][service]).items():
        monkeypatch.setenv(key, value)
    from robobpp.cli.worker import worker_settings

    settings = Settings() if service == "server" else worker_settings()
    assert settings.env == "prod"
    assert not settings.allow_private_policy_urls
    url = make_url(settings.database_url)
    assert url.get_backend_name() == "postgresql"
    assert url.host == "postgres", "the database URL must name the compose service"
    url.get_dialect()  # the driver named in the URL is importable
    check_broker_url(settings.broker_url)
    assert settings.broker_url.split("@")[-1].startswith("redis:"), "broker host must be the redis service"
    assert str(settings.private_dir) in {
        str(m).split(":")[1] for m in compose["services"][service]["volumes"]
    }, "the private split directory must be a volume"


def test_only_the_server_holds_the_admin_token(compose: dict[str, Any]) -> None:
    assert "ROBOBPP_ADMIN_TOKEN" in _env(compose["services"]["server"])
    assert "ROBOBPP_ADMIN_TOKEN" not in _env(compose["services"]["worker"])


def test_workers_reach_the_servers_pull_relay(compose: dict[str, Any]) -> None:
    relay = urlsplit(_env(compose["services"]["worker"])["ROBOBPP_PULL_RELAY_URL"])
    assert (relay.hostname, relay.port) == ("server", 8000), "pull episodes must reach the server's relay"
    assert "--port" in compose["services"]["server"]["command"]
    assert compose["services"]["server"]["command"][-1] == "8000"


def test_server_runs_no_local_workers_when_a_broker_is_set(compose: dict[str, Any]) -> None:
    env = _env(compose["services"]["server"])
    assert env.get("ROBOBPP_BROKER_URL")
    assert env.get("ROBOBPP_WORKERS") == "0"


@pytest.mark.parametrize("service", ["server", "worker"])
def test_service_command_exists_in_the_cli(compose: dict[str, Any], service: str) -> None:
    command = [_substitute(str(part)) for part in compose["services"][service]["command"]]
    cmd = _parse_cli(command)
    expected = {"server": "serve", "worker": "worker"}[service]
    assert cmd.name == expected


def test_worker_depends_on_healthy_database_and_broker(compose: dict[str, Any]) -> None:
    for service in ("server", "worker"):
        deps = compose["services"][service]["depends_on"]
        assert deps["postgres"]["condition"] == "service_healthy"
        assert deps["redis"]["condition"] == "service_healthy"


# --- Dockerfile -----------------------------------------------------------------------------------------


def _dockerfile() -> list[tuple[str, str]]:
    """(instruction, argument) pairs with continuation lines joined and comments dropped."""
    text = (ROOT / "Dockerfile").read_text()
    text = re.sub(r"\\\n", " ", text)
    out = []
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        instr, _, arg = line.partition(" ")
        out.append((instr.upper(), arg.strip()))
    return out


def test_dockerfile_python_matches_the_package() -> None:
    base = next(arg for instr, arg in _dockerfile() if instr == "FROM")
    version = re.search(r"python:(\d+)\.(\d+)", base)
    assert version, f"base image is not a python image: {base}"
    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    minimum = tuple(int(p) for p in requires.lstrip(">=").split("."))
    assert (int(version.group(1)), int(version.group(2))) >= minimum


def test_dockerfile_copies_paths_that_exist_and_installs_the_package() -> None:
    steps = _dockerfile()
    for instr, arg in steps:
        if instr == "COPY" and not arg.startswith("--from"):
            for src in shlex.split(arg)[:-1]:
                assert (ROOT / src).exists(), f"COPY source {src} does not exist"
    # the whole service: the image runs the server and the workers, every setting
    # editable: migrations/ is found next to the package only when the code runs from the copied tree
    assert any(instr == "RUN" and 'pip install -e ".[all]"' in arg for instr, arg in steps)


def test_dockerfile_runs_unprivileged_and_its_command_exists() -> None:
    steps = _dockerfile()
    users = [arg for instr, arg in steps if instr == "USER"]
    assert users and users[-1] not in ("root", "0")
    cmd = next(arg for instr, arg in reversed(steps) if instr == "CMD")
    import json

    assert _parse_cli(json.loads(cmd)).name == "serve"
    for instr, arg in steps:
        if instr == "ENV":
            for name in re.findall(r"(ROBOBPP_[A-Z0-9_]+)=", arg):
                assert name in _settings_fields(), f"Dockerfile sets unknown {name}"


def test_dockerfile_health_check_targets_a_real_route() -> None:
    check = next(arg for instr, arg in _dockerfile() if instr == "HEALTHCHECK")
    path = re.search(r"http://127\.0\.0\.1:8000(/\S*)", check)
    assert path
    from robobpp.server.app import create_app

    paths = create_app(Settings(), start_workers=False).openapi()["paths"]
    assert "get" in paths.get(path.group(1), {}), f"no GET {path.group(1)} in the API"


def test_dockerignore_keeps_secrets_and_private_data_out_of_the_image() -> None:
    ignored = {line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines()}
    assert {".env", "datasets_private", ".git"} <= ignored
