"""Progress off a terminal: rich's bar draws nothing there until it stops, so `submit --wait` or a long
`evaluate` run in a batch job or redirected to a log printed nothing for the whole run."""

import io

import pytest
from rich.console import Console
from typer.testing import CliRunner

from robobpp.cli import progress as progress_module
from robobpp.cli.progress import LineProgress


def test_off_a_terminal_it_prints_plain_lines_at_most_every_interval():
    out = io.StringIO()
    with LineProgress(Console(file=out, force_terminal=False), every_s=0) as bar:
        task = bar.add_task("dbl · diverse", total=3)
        bar.advance(task)
        bar.update(task, description="dbl · longboard", completed=2)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("dbl · diverse: 1/3 · ") and lines[0].endswith(" s")
    assert lines[1].startswith("dbl · longboard: 2/3 · ")

    quiet = io.StringIO()
    with LineProgress(Console(file=quiet, force_terminal=False), every_s=3600) as bar:
        task = bar.add_task("dbl", total=3)
        bar.advance(task)
    assert ": 1/3 · " not in quiet.getvalue()  # within the interval: only the bar rich prints at the end


def test_on_a_terminal_only_the_bar_is_drawn():
    out = io.StringIO()
    with LineProgress(Console(file=out, force_terminal=True, width=100), every_s=0) as bar:
        task = bar.add_task("dbl", total=2)
        bar.advance(task)
    assert "dbl: 1/2 · " not in out.getvalue()


@pytest.mark.network
def test_evaluate_redirected_to_a_log_prints_progress_lines(real_data, monkeypatch):
    from robobpp.cli import app, register_commands

    monkeypatch.setattr(progress_module, "PROGRESS_LINE_S", 0.0)
    register_commands()
    result = CliRunner().invoke(
        app, ["evaluate", "--policy", "dbl", "--dataset", "repetitive", "--setting", "math", "--groups", "2"]
    )
    assert result.exit_code == 0, result.output
    assert "dbl · repetitive · closed · math: 1/2 · " in result.output
