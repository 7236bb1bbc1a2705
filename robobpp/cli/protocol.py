"""``robobpp policy serve`` and ``robobpp protocol check|schema``: the participant's side of robobpp/1."""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from robobpp.cli.common import fail, import_from_cwd

policy_app = typer.Typer(no_args_is_help=True, help="Serve a packing policy over protocol robobpp/1.")
protocol_app = typer.Typer(no_args_is_help=True, help="Step protocol robobpp/1: conformance check, schema.")
console = Console()

_SECRET_ENV = "ROBOBPP_POLICY_SECRET"


def register(root: typer.Typer) -> None:
    root.add_typer(policy_app, name="policy")
    root.add_typer(protocol_app, name="protocol")


@policy_app.command("serve")
def serve_command(
    policy: Annotated[
        str, typer.Argument(help="module:Class of your policy, or a built-in name (dbl, ...).")
    ],
    host: Annotated[str, typer.Option(help="Address to bind; 0.0.0.0 accepts other machines.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=1, max=65535, help="TCP port to listen on.")] = 9000,
    secret: Annotated[
        str | None, typer.Option(help="Refuse requests not signed with this secret.", envvar=_SECRET_ENV)
    ] = None,
    name: Annotated[str | None, typer.Option(help="Name shown by /info.")] = None,
) -> None:
    """Serve a policy so that `robobpp evaluate --policy http://HOST:PORT` or the server can drive it."""
    from robobpp.client.loading import PolicyLoadError, load_policy
    from robobpp.client.serve import serve

    if policy.startswith(("http://", "https://")):
        fail("give the policy as module:Class (or a built-in name), not a URL")
    import_from_cwd(policy)
    try:
        agent = load_policy(policy)
    except PolicyLoadError as exc:
        fail(str(exc))
    serve(agent, host=host, port=port, secret=secret, name=name)  # prints where it listens once it does


@protocol_app.command("check")
def check_command(
    url: Annotated[str, typer.Argument(help="Base URL of the policy server, e.g. http://127.0.0.1:9000.")],
    secret: Annotated[
        str | None,
        typer.Option(help="The secret the server expects; enables the signature checks.", envvar=_SECRET_ENV),
    ] = None,
    boxes: Annotated[int, typer.Option(min=1, max=80, help="Boxes in the test episode.")] = 8,
    timeout: Annotated[float, typer.Option(min=0.01, help="Per-request time limit, seconds.")] = 10.0,
    dataset: Annotated[
        str | None,
        typer.Option(help="Run the episode on this dataset's container and boxes (its first train group)."),
    ] = None,
    setting: Annotated[str, typer.Option(help="math, physics or execution: the episode's setting.")] = "math",
) -> None:
    """Run a short episode against a policy server and report every protocol violation."""
    from robobpp.client.check import check_policy_server, dataset_check_spec
    from robobpp.datasets import DATASETS, DatasetError
    from robobpp.sim import require_setting
    from robobpp.vocabulary import SETTINGS

    if setting not in SETTINGS:
        fail(f"unknown setting {setting!r}; expected one of {', '.join(SETTINGS)}")
    require_setting(setting)  # a missing extra is one line naming the pip install
    spec = None
    if dataset is not None:
        if dataset not in DATASETS:
            fail(f"unknown dataset {dataset!r}; expected one of {', '.join(DATASETS)}")
        try:
            spec = dataset_check_spec(dataset, boxes)
        except DatasetError as exc:
            fail(str(exc))
    try:
        report = check_policy_server(
            url, secret, boxes=boxes, step_timeout_s=timeout, spec=spec, setting=setting
        )
    except ValueError as exc:  # a malformed URL
        fail(str(exc))
    where = f"{dataset or 'Diverse container, fixed boxes'} · {setting}"
    table = Table(title=f"robobpp/1 conformance of {url} ({where})", show_lines=False)
    table.add_column("", width=2)
    table.add_column("check", style="bold")
    table.add_column("finding")
    marks = {"ok": "[green]✓[/]", "warning": "[yellow]![/]", "violation": "[red]✗[/]"}
    for finding in report.findings:
        # Server-sent text is printed as plain text: a hostile answer must not inject console markup.
        table.add_row(marks[finding.level], finding.check, _plain(finding.message))
    console.print(table)
    if report.latencies_s:
        p50 = statistics.median(report.latencies_s) * 1000
        worst = max(report.latencies_s) * 1000
        console.print(f"{report.steps} steps, round trip p50 {p50:.1f} ms, max {worst:.1f} ms")
    if report.ok:
        console.print("[green]no violations[/]")
        return
    console.print(f"[red]{len(report.violations)} violation(s)[/]")
    raise typer.Exit(1)


@protocol_app.command("schema")
def schema_command(
    out: Annotated[Path | None, typer.Option(help="Write the JSON Schema here instead of stdout.")] = None,
) -> None:
    """Print the JSON Schema of every robobpp/1 message."""
    from robobpp.protocol import json_schema

    text = json.dumps(json_schema(), indent=2)
    if out is None:
        typer.echo(text)
    else:
        out.write_text(text + "\n", encoding="utf-8")


def _plain(text: str) -> str:
    from rich.markup import escape

    return escape(text)
