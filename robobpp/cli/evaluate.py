"""``robobpp evaluate``: run a policy over dataset groups in one setting, locally, with a progress bar."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from robobpp.cli.common import DatasetOpt, fail, import_from_cwd, parse_choices, table_console
from robobpp.cli.progress import LineProgress
from robobpp.provenance import of_results, one_line
from robobpp.scoring import stats
from robobpp.scoring.metrics import aggregate, metrics_for
from robobpp.scoring.scores import score_board
from robobpp.scoring.stats import POLICY_FAILURES
from robobpp.vocabulary import CLOSED, LOOPS, PAPER, PHYSICAL

if TYPE_CHECKING:
    from robobpp.core import EpisodeSpec
    from robobpp.episode import EpisodeResult

console = Console(stderr=True)


def register(root: typer.Typer) -> None:
    root.command("evaluate")(evaluate)


def evaluate(
    policy: Annotated[
        str, typer.Option(help="Built-in name (dbl, hm, ...), module:Class, or http(s):// URL.")
    ],
    dataset: DatasetOpt = "all",
    setting: Annotated[str, typer.Option(help="math, physics, execution, a comma list, or all.")] = "math",
    groups: Annotated[int, typer.Option(min=1, max=10_000, help="Groups (episodes) per dataset.")] = 30,
    split: Annotated[str, typer.Option(help="train (public) or test.")] = "train",
    seed: Annotated[int, typer.Option(help="Sampling seed of the groups.")] = 0,
    lookahead: Annotated[int, typer.Option(min=0, max=20, help="Next boxes shown to the policy.")] = 0,
    secret: Annotated[
        str | None, typer.Option(help="HMAC secret for a remote policy.", envvar="ROBOBPP_POLICY_SECRET")
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write summary and per-episode metrics here.")
    ] = None,
    csv_out: Annotated[
        Path | None, typer.Option("--csv", help="Write one row per group (episode) here, with provenance.")
    ] = None,
    trace: Annotated[
        Path | None, typer.Option(help="Write full per-step traces here (for `robobpp view`).")
    ] = None,
    jobs: Annotated[
        int, typer.Option(min=1, max=256, help="Worker processes running episodes side by side.")
    ] = 1,
    protocol: Annotated[
        str,
        typer.Option(
            help="closed: the policy observes each setting's state at every step. paper: the paper's "
            "protocol, the policy plans in Math Pack and its actions are replayed open loop in physics "
            "and execution (docs/benchmark.md, 'Two protocols')."
        ),
    ] = CLOSED,
) -> None:
    """Evaluate a policy locally and print a results table. Exit code 3: every episode ended in a policy failure."""
    from robobpp.client.loading import PolicyLoadError, load_policy
    from robobpp.datasets import DATASETS, SPLITS, DatasetError, episode_specs
    from robobpp.replay import play
    from robobpp.sim import require_setting
    from robobpp.vocabulary import SETTINGS

    datasets = parse_choices(dataset, DATASETS, "dataset")
    settings = parse_choices(setting, SETTINGS, "setting")
    if protocol not in LOOPS:
        fail(f"unknown protocol {protocol!r}; expected one of {', '.join(LOOPS)}")
    replayed = [name for name in settings if name in PHYSICAL]
    if protocol == PAPER and not replayed:
        fail(
            "--protocol paper replays the Math Pack actions in physics or execution; in Math Pack both "
            "protocols are the same episode: add --setting physics or execution, or use --protocol closed"
        )
    for name in settings:
        require_setting(name)  # before any work: a missing extra is one line naming the pip install
    if split not in SPLITS:
        fail(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    kwargs = {"secret": secret} if policy.startswith(("http://", "https://")) and secret else {}
    import_from_cwd(policy)
    try:
        agent = load_policy(policy, **kwargs)
    except PolicyLoadError as exc:
        fail(str(exc))
    _name_served(agent)
    try:
        specs = {name: episode_specs(name, split=split, groups=groups, seed=seed) for name in datasets}
    except DatasetError as exc:
        fail(str(exc))
    tasks: list[tuple[EpisodeSpec, tuple[str, ...]]]
    if protocol == PAPER:
        # One task per group: the Math Pack episode, then its replay in each physical setting asked for.
        tasks = [(spec, ("math", *replayed)) for name in datasets for spec in specs[name]]
    else:
        tasks = [(spec, (s,)) for name in datasets for s in settings for spec in specs[name]]
    with LineProgress(console) as progress:
        bar = progress.add_task(agent.name, total=len(tasks))
        if jobs == 1:
            groups_run: list[list[EpisodeResult]] = []
            for spec, names in tasks:
                progress.update(
                    bar, description=f"{agent.name} · {spec.dataset} · {protocol} · {','.join(names)}"
                )
                groups_run.append(play(protocol, spec, agent, names, lookahead=lookahead))
                progress.advance(bar)
        else:
            from robobpp.cli.parallel import run_parallel

            progress.update(bar, description=f"{agent.name} · {protocol} · {jobs} processes")
            groups_run = list(
                run_parallel(
                    policy,
                    kwargs,
                    tasks,
                    jobs=jobs,
                    lookahead=lookahead,
                    loop=protocol,
                    on_done=lambda _i: progress.advance(bar),
                )
            )
    runs: dict[tuple[str, str], list[EpisodeResult]] = {}
    for result in (r for group in groups_run for r in group):
        if result.setting in settings:  # the paper protocol's Math plan is shown when Math Pack was asked for
            runs.setdefault((result.dataset, result.setting), []).append(result)
    runs = {
        key: runs[key] for key in sorted(runs, key=lambda k: (datasets.index(k[0]), settings.index(k[1])))
    }
    results = [r for rs in runs.values() for r in rs]
    summary = _summarise(runs)
    provenance = of_results(
        results, protocol=protocol, split=split, seed=seed, groups=groups, lookahead=lookahead
    )
    out = table_console()
    out.print(_table(agent.name, summary, protocol, provenance))
    for note in failure_notes(runs):
        console.print(note, markup=False, highlight=False)
    payload = {
        "policy": agent.name,
        "split": split,
        "seed": seed,
        "groups": groups,
        "protocol": protocol,
        "lookahead": lookahead,
        "confidence": stats.CONFIDENCE,
        "resamples": stats.RESAMPLES,
        "provenance": provenance,
        "runs": summary,
        "episodes": [r.to_dict(trace=False) for rs in runs.values() for r in rs],
    }
    if json_out is not None:
        _write_json(json_out, payload)
    if csv_out is not None:
        from robobpp.export import group_csv

        _write_text(csv_out, group_csv(payload))
    if trace is not None:
        _write_json(
            trace, {"policy": agent.name, "episodes": [r.to_dict() for rs in runs.values() for r in rs]}
        )
    if results and all(r.termination in POLICY_FAILURES for r in results):
        console.print(
            f"every episode ended in a policy failure: exit code {EXIT_POLICY_FAILED}", markup=False
        )
        raise typer.Exit(EXIT_POLICY_FAILED)


#: Exit code when every episode ended in a policy failure (unreachable policy, errors, garbage answers,
#: timeouts, protocol violations): scripts and CI must not mistake such a run for a result. 2 is a usage error.
EXIT_POLICY_FAILED = 3


def _name_served(agent: Any) -> None:
    """A served policy is labelled by its ``/info`` name and version, not its URL; a server that does not
    answer keeps its URL, and its episodes say what went wrong."""
    from robobpp.client.remote import RemotePolicy
    from robobpp.policies.base import PolicyError

    if isinstance(agent, RemotePolicy):
        with contextlib.suppress(PolicyError):
            agent.fetch_info()


def failure_notes(runs: dict[tuple[str, str], list[EpisodeResult]]) -> list[str]:
    """One line per policy failure reason with its first episode's detail (e.g. a wrong secret)."""
    first: dict[str, tuple[int, EpisodeResult]] = {}
    for results in runs.values():
        for r in results:
            if r.termination in POLICY_FAILURES:
                count, example = first.get(r.termination, (0, r))
                first[r.termination] = (count + 1, example)
    return [
        f"{reason} in {count} episode(s), e.g. {example.episode_id}: {example.termination_detail}"
        for reason, (count, example) in first.items()
    ]


def _summarise(runs: dict[tuple[str, str], list[EpisodeResult]]) -> list[dict[str, Any]]:
    """Each (dataset, setting): its figures with the board's 95 % bootstrap intervals over groups
    (:func:`robobpp.scoring.scores.score_board` on this run alone) and its stable score with interval."""
    out: list[dict[str, Any]] = []
    for (dataset, setting), results in runs.items():
        terminations: dict[str, int] = {}
        for r in results:
            terminations[r.termination] = terminations.get(r.termination, 0) + 1
        episodes = [{**r.metrics, **r.counters, "group": r.group} for r in results]
        metrics = aggregate(episodes, setting)
        scored = score_board(
            [{"metrics": metrics, "figures": stats.group_figures(episodes, setting)}], setting
        )
        out.append(
            {
                "dataset": dataset,
                "setting": setting,
                "protocol": results[0].protocol,
                "episodes": len(results),
                "boxes_placed": sum(r.boxes_placed for r in results) / len(results),
                "metrics": metrics,
                "intervals": {k: list(v) if v else None for k, v in scored.metric_ci[0].items()},
                "stable": scored.stable[0],
                "stable_interval": list(scored.stable_ci[0]),
                "terminations": terminations,
            }
        )
    return out


def _with_interval(value: float | None, interval: list[float] | None, digits: int = 4) -> str:
    if value is None:
        return "—"
    text = f"{value:.{digits}f}"
    return text + (f" [dim][{interval[0]:.{digits}f}, {interval[1]:.{digits}f}][/]" if interval else "")


def _table(
    policy: str,
    summary: list[dict[str, Any]],
    protocol: str = CLOSED,
    provenance: dict[str, Any] | None = None,
) -> Table:
    from robobpp.replay import LOOP_DESCRIPTIONS

    keys = [m for m in metrics_for("execution") if any(m.key in row["metrics"] for row in summary)]
    table = Table(
        title=f"robobpp evaluate · {escape(policy)} · protocol {protocol}",
        caption=f"{protocol}: {LOOP_DESCRIPTIONS[protocol]}\n[dim]brackets: bootstrap "
        f"{100 * stats.CONFIDENCE:.0f} % interval over groups · {escape(one_line(provenance or {}))}[/]",
    )
    table.add_column("dataset")
    table.add_column("setting")
    table.add_column("protocol")
    table.add_column("episodes", justify="right")
    table.add_column("boxes placed", justify="right")
    for m in keys:
        arrow = "↑" if m.better == "up" else "↓"
        table.add_column(f"{m.label} {arrow}" + (f" ({m.unit})" if m.unit else ""), justify="right")
    table.add_column("stable score ↑", justify="right")
    table.add_column("terminations", min_width=28)
    for row in summary:
        cells = [
            row["dataset"],
            row["setting"],
            row["protocol"],
            str(row["episodes"]),
            f"{row['boxes_placed']:.1f}",
        ]
        for m in keys:
            cells.append(_with_interval(row["metrics"].get(m.key), row["intervals"].get(m.key)))
        cells.append(_with_interval(row["stable"], row["stable_interval"], 3))
        cells.append(", ".join(f"{k}: {v}" for k, v in sorted(row["terminations"].items())))
        table.add_row(*cells)
    return table


def _write_json(path: Path, payload: dict[str, Any]) -> None:
    _write_text(path, json.dumps(payload, indent=1, allow_nan=False))


def _write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    console.print(f"wrote {path}")
