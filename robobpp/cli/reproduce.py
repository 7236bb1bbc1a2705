"""``robobpp reproduce``: the paper's baselines under the paper protocol, beside the paper's published tables."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from robobpp.cli.common import fail, parse_choices, table_console
from robobpp.cli.progress import LineProgress
from robobpp.vocabulary import LOOPS, PAPER

console = Console(stderr=True)


def register(root: typer.Typer) -> None:
    root.command("reproduce")(reproduce)


def reproduce(
    setting: Annotated[str, typer.Option(help="math, physics, execution, a comma list, or all.")] = "all",
    dataset: Annotated[
        str,
        typer.Option("--dataset", "--datasets", help="repetitive, diverse, longboard, a comma list, or all."),
    ] = "all",
    policies: Annotated[
        str, typer.Option(help="Comma list of built-in policies (default: the paper's 7 heuristics and PCT).")
    ] = "",
    groups: Annotated[int, typer.Option(min=1, max=10_000, help="Groups (episodes) per dataset.")] = 30,
    first_group: Annotated[
        int, typer.Option(min=0, help="Run groups first-group .. first-group+groups-1 (split a long run).")
    ] = 0,
    split: Annotated[str, typer.Option(help="train (public) or test.")] = "train",
    seed: Annotated[int, typer.Option(help="Sampling seed of the groups.")] = 0,
    protocol: Annotated[
        str, typer.Option(help="paper (the paper's: Math Pack plans replayed open loop) or closed.")
    ] = PAPER,
    metrics: Annotated[
        str, typer.Option(help="Comma list of metric keys to show (default: every metric the paper has).")
    ] = "",
    jobs: Annotated[
        int, typer.Option(min=1, max=256, help="Worker processes running groups side by side.")
    ] = 1,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the episodes and the comparison here.")
    ] = None,
    merge: Annotated[
        list[Path] | None,
        typer.Option(help="Pool the episodes of earlier --json files (repeatable) instead of running."),
    ] = None,
    markdown_out: Annotated[bool, typer.Option("--markdown", help="Print Markdown tables.")] = False,
) -> None:
    """Run the paper's baselines locally and print ours beside the paper's figures, with Spearman and mean
    |diff| per setting, dataset and metric, why each metric's figures are expected to differ, and the paper's
    score over the methods run (Decision Time left out) from ours and from the paper's figures. The paper's
    methods robobpp does not run are listed with the paper's figures only (paper-reported). The paper's figures
    are its test split (30 private groups)."""
    from robobpp.datasets import DATASETS, SPLITS, DatasetError
    from robobpp.episode import EpisodeResult
    from robobpp.paper import PAPER_BASELINES, paper_tables
    from robobpp.policies import BUILTIN, TITLES
    from robobpp.reproduction import compare, compared_metrics, figures_from_results, markdown
    from robobpp.sim import require_setting
    from robobpp.vocabulary import SETTINGS

    if protocol not in LOOPS:
        fail(f"unknown protocol {protocol!r}; expected one of {', '.join(LOOPS)}")
    if split not in SPLITS:
        fail(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    shown = None
    if metrics:
        known = sorted({m for s in SETTINGS for m in compared_metrics(s)})
        shown = parse_choices(metrics, known, "metric")
    if merge:
        results, meta = _merged(merge, EpisodeResult)
        settings: list[str] = [s for s in SETTINGS if any(r.setting == s for r in results)]
    else:
        datasets = parse_choices(dataset, DATASETS, "dataset")
        settings = parse_choices(setting, SETTINGS, "setting")
        names = parse_choices(policies, BUILTIN, "policy") if policies else list(PAPER_BASELINES)
        for name in settings:
            require_setting(name)
        try:
            results = _run(datasets, names, settings, groups, first_group, split, seed, protocol, jobs)
        except DatasetError as exc:
            fail(str(exc))
        meta = {"protocol": protocol, "split": split, "seed": seed}
    comparison = compare(figures_from_results(results), metrics=shown)
    titles = {**paper_tables().methods, **TITLES}  # the paper's spelling of the methods robobpp does not run
    counts = _group_counts(results)
    heading = (
        f"protocol {meta['protocol']}"
        + (" (Math Pack plans replayed open loop in Physics/Execution)" if meta["protocol"] == PAPER else "")
        + f"; ours: {meta['split']} split, seed {meta['seed']}, groups "
        + ", ".join(f"{d} {n}" for d, n in counts.items())
        + "; "
        "paper: its test split, 30 groups"
    )
    out = table_console()
    if markdown_out:
        out.print(heading + "\n", markup=False, highlight=False, soft_wrap=True)
        out.print(markdown(comparison, titles), markup=False, highlight=False, soft_wrap=True)
    else:
        out.print(heading, markup=False, highlight=False, soft_wrap=True)
        for s in comparison.settings:
            for table in _tables(comparison, s, titles):
                out.print(table)
                out.print()
    if json_out is not None:
        payload = {
            **meta,
            "settings": settings,
            "groups": counts,
            "episodes": [r.to_dict(trace=False) for r in results],
            "comparison": comparison.to_dict(),
        }
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(payload, indent=1, allow_nan=False))
        console.print(f"wrote {json_out}")


def _run(
    datasets: list[str],
    names: list[str],
    settings: list[str],
    groups: int,
    first_group: int,
    split: str,
    seed: int,
    protocol: str,
    jobs: int,
) -> list[Any]:
    from robobpp.datasets import episode_specs
    from robobpp.reproduction import run_baselines

    # A group's boxes depend on its index only, so groups first_group.. are those of a longer run.
    specs = {d: episode_specs(d, split, first_group + groups, seed=seed)[first_group:] for d in datasets}
    results: list[Any] = []
    with LineProgress(console) as progress:
        bar = progress.add_task("reproduce", total=len(datasets) * len(names) * groups)
        for d in datasets:
            for name in names:
                progress.update(bar, description=f"{name} · {d} · {protocol}")
                if jobs == 1:
                    for episodes in run_baselines(specs[d], name, settings, loop=protocol):
                        results += episodes
                        progress.advance(bar)
                    continue
                from robobpp.cli.parallel import run_parallel

                tasks = [(spec, tuple(settings)) for spec in specs[d]]
                for episodes in run_parallel(
                    name, {}, tasks, jobs=jobs, loop=protocol, on_done=lambda _i: progress.advance(bar)
                ):
                    results += episodes
    return results


def _merged(paths: list[Path], result_type: Any) -> tuple[list[Any], dict[str, Any]]:
    """The episodes of earlier ``--json`` files, pooled; they must agree on protocol, split and seed."""
    results: list[Any] = []
    meta: dict[str, Any] | None = None
    seen: set[tuple[str, str, str]] = set()
    for path in paths:
        try:
            data = json.loads(path.read_text())
            theirs = {k: data[k] for k in ("protocol", "split", "seed")}
            episodes = [result_type.from_dict(e) for e in data["episodes"]]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            fail(f"{path}: not a `robobpp reproduce --json` file ({type(exc).__name__}: {exc})")
        if meta is None:
            meta = theirs
        elif theirs != meta:
            fail(f"{path} holds {theirs}, not {meta} like {paths[0]}")
        for r in episodes:
            key = (r.episode_id, r.setting, r.policy)
            if key in seen:
                fail(f"{path}: {r.policy} on {r.episode_id} in {r.setting} again (overlapping runs)")
            seen.add(key)
            results.append(r)
    assert meta is not None
    return results, meta


def _group_counts(results: list[Any]) -> dict[str, int]:
    groups: dict[str, set[int]] = {}
    for r in results:
        groups.setdefault(r.dataset, set()).add(r.group)
    return {d: len(g) for d, g in groups.items()}


def _tables(comparison: Any, setting: str, titles: dict[str, str]) -> list[Table]:
    """``setting``'s terminal tables: one per metric, with why its figures are expected to differ under it, then
    the score comparison."""
    from robobpp.reproduction import EXPECTED, label, policy_title, spearman_text

    datasets = comparison.datasets(setting)
    out = []
    for metric in comparison.metrics(setting):
        expected = EXPECTED.get(metric)
        table = Table(
            title=f"{setting.capitalize()} Pack · ours vs the paper · {label(metric)}",
            caption=f"{expected.why} ({expected.doc})" if expected else None,
            caption_justify="left",
        )
        table.add_column("policy")
        for d in datasets:
            table.add_column(f"{d} paper", justify="right")
            table.add_column(f"{d} ours", justify="right")
            table.add_column("diff", justify="right")
        digits = 0 if metric == "pph" else 3
        for policy in comparison.policies(setting):
            row = [policy_title(comparison, policy, titles)]
            for d in datasets:
                c = comparison.cell(setting, d, policy, metric)
                row += [
                    _num(c and c.paper, digits),
                    _num(c and c.ours, digits),
                    _num(c and c.diff, digits, True),
                ]
            table.add_row(*row)
        agreements = [comparison.agreement_of(setting, d, metric) for d in datasets]
        spearmans = [spearman_text(a) for a in agreements]
        diffs = [_num(a and a.mean_abs_diff, digits) for a in agreements]
        table.add_row(
            "[bold]Spearman[/]", *[cell for t in spearmans for cell in ("", t, "")], end_section=False
        )
        table.add_row("[bold]mean |diff|[/]", *[cell for t in diffs for cell in ("", t, "")])
        out.append(table)
    score = _score_table(comparison, setting, titles)
    return out + ([score] if score else [])


def _score_table(comparison: Any, setting: str, titles: dict[str, str]) -> Table | None:
    """``setting``'s score comparison: per dataset our score and the one from the paper's figures, per method."""
    from robobpp.paper import PAPER_BASELINES
    from robobpp.reproduction import SCORE_TITLE

    scored = [c for c in comparison.scores if c.setting == setting]
    if not scored:
        return None
    table = Table(
        title=f"{setting.capitalize()} Pack · {SCORE_TITLE}",
        caption="The paper's weighted min–max over the methods compared here, from our figures and from the "
        "paper's figures of the same methods; the other weights renormalised.",
        caption_justify="left",
    )
    table.add_column("policy")
    for c in scored:
        table.add_column(f"{c.dataset} ours", justify="right")
        table.add_column(f"{c.dataset} paper metrics", justify="right")
    policies = [p for p in PAPER_BASELINES if any(p in c.policies for c in scored)]
    policies += sorted({p for c in scored for p in c.policies} - set(policies))
    for policy in policies:
        row = [titles.get(policy, policy)]
        for c in scored:
            both = c.of(policy)
            row += [_num(both[0], 3), _num(both[1], 3)] if both else ["—", "—"]
        table.add_row(*row)
    table.add_row("[bold]Spearman[/]", *[cell for c in scored for cell in ("", _num(c.spearman, 2))])
    return table


def _num(value: float | None, digits: int, signed: bool = False) -> str:
    if value is None:
        return "—"
    return f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"
