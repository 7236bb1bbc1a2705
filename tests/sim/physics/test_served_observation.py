"""A served policy sees the physical pile an in-process policy sees.

The SDK rebuilds each /act's heightmap from ``placed``. It took every box as axis-aligned at its corner, as in
Math Pack, while the Physics and Execution Pack observe each box's actual, possibly tilted, bounds (shrunk and
rounded): on real groups the served policy's heightmap was up to tens of cm off (a tilted Long Board panel
stands cm higher; each box edge moved by a cell) on most steps, so DBL served over HTTP packed differently from
the built-in DBL the server runs in-process (Repetitive train group 1: a collapse at 37 boxes against 52), and on
Long Board it ended on too_high. Every participant's policy is served; the baselines are not.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from robobpp import protocol as P
from robobpp.client.loading import load_policy as load_any
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.policies.dbl import DBL


class _Rebuilt:
    """DBL in-process, comparing each observation with the one the SDK rebuilds from its /act body."""

    name = "dbl"

    def __init__(self) -> None:
        self.inner = load_policy("dbl")
        self.worst = 0.0
        self.cells_off = 0
        self.cells = 0

    def reset(self, info: EpisodeInfo) -> None:
        self.inner.reset(info)

    def act(self, obs: Observation) -> Action | None:
        wire = P.ActRequest.model_validate_json(json.dumps(P.act_payload(obs)))
        off = np.abs(P.observation_from_act(wire).heightmap - obs.heightmap)
        self.worst = max(self.worst, float(off.max()))
        self.cells_off += int((off > 0.11).sum())  # beyond the 0.1 cm rounding of the observed poses
        self.cells += off.size
        return self.inner.act(obs)

    def close(self, reason: str) -> None:
        self.inner.close(reason)


@pytest.mark.network
@pytest.mark.parametrize(("dataset", "group"), [("repetitive", 1), ("longboard", 0)])
def test_the_rebuilt_heightmap_is_the_in_process_one(real_data: Path, dataset: str, group: int) -> None:
    from robobpp.datasets import episode_specs

    spec = episode_specs(dataset, "train", group + 1)[group]
    probe = _Rebuilt()
    result = run_episode(spec, probe, "physics")
    assert result.boxes_placed > 20, result.termination_detail
    if dataset == "repetitive":
        assert probe.worst <= 0.11  # the observed poses are rounded to 0.1 cm
    # Long Board: a box edge within the poses' rounding of a cell boundary may still fall in the next cell
    assert probe.cells_off <= 0.001 * probe.cells, (probe.worst, probe.cells_off)


@pytest.mark.network
def test_dbl_served_over_http_packs_as_the_built_in_dbl(real_data: Path) -> None:
    from robobpp.datasets import episode_specs

    spec = episode_specs("repetitive", "train", 2)[1]
    local = run_episode(spec, load_policy("dbl"), "physics")
    with BackgroundServer(create_policy_app(DBL)) as server:
        served = run_episode(spec, load_any(server.url), "physics")
    assert (served.termination, served.boxes_placed) == (local.termination, local.boxes_placed)
    assert served.metrics["space_utilization"] == pytest.approx(local.metrics["space_utilization"])
