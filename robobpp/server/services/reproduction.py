"""The Reproduction page's data: the paper's baselines under the paper protocol, from the server's stored runs,
beside the paper's published tables (:mod:`robobpp.reproduction` compares; this module only gathers).

The baselines the server evaluates (``ROBOBPP_BASELINES``) are ordinary submissions of built-in participants; with
Math Pack among their settings each also has its physical settings under the paper protocol (docs/server.md,
"The paper protocol"). The latest completed run of each (policy, setting, dataset) is the one compared.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from robobpp.db import queries
from robobpp.paper import PAPER_BASELINES
from robobpp.reproduction import Key, compare, with_derived
from robobpp.vocabulary import DATASETS, PAPER, SETTINGS

BUILTIN_PREFIX = "builtin:"


def reproduction(session: Session, track: str) -> dict[str, Any]:
    """``{"track", "protocol": "paper", "runs": [...], **Comparison.to_dict()}``: every figure ours beside the
    paper's, and per setting, dataset and metric the Spearman rank correlation and the mean |diff|."""
    latest: dict[tuple[str, str, str], dict[str, Any]] = {}
    for run in queries.baseline_runs(session, track):
        policy = str(run["policy_url"]).removeprefix(BUILTIN_PREFIX)
        if policy in PAPER_BASELINES:  # the methods the paper tabulates
            latest[(run["setting"], run["dataset"], policy)] = run
    ours: dict[Key, float | None] = {}
    runs = []
    for (setting, dataset, policy), run in latest.items():
        for metric, value in with_derived(setting, run["metrics"] or {}).items():
            ours[(setting, dataset, policy, metric)] = value
        runs.append(
            {
                "setting": setting,
                "dataset": dataset,
                "policy": policy,
                "protocol": run["protocol"],
                "submission_id": run["submission_id"],
                "groups": int((run["extras"] or {}).get("episodes") or 0),
            }
        )
    order = {name: i for i, name in enumerate((*SETTINGS, *DATASETS, *PAPER_BASELINES))}
    runs.sort(key=lambda r: (order[r["setting"]], order[r["dataset"]], order[r["policy"]]))
    return {"track": track, "protocol": PAPER, "runs": runs, **compare(ours).to_dict()}
