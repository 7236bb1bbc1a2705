"""The default physics against the full simulation on real train episodes (docs/physics.md, "Fidelity";
``bench/fidelity_physics.py`` runs the criterion on 90 episodes).

The short episodes of the Diverse and Long Board datasets (DBL and HM end them after 4–25 boxes), so the full
simulation stays cheap. The criterion is the bench's (``robobpp.sim.physics.fidelity.compare``): the same
termination, boxes placed ±1 and Local Stability within 5 mm. Physics version 3 meets it on 11 of these 12
episodes (Long Board HM group 1 parts on Local Stability, 11.0 vs 18.6 mm; the full simulation with a 0.1 mm
higher release also meets it on 11 of the 12). The test fails when more than 2 of the 12 disagree.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from robobpp.datasets import episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsPack
from robobpp.sim.physics.fidelity import Outcome, compare

GROUPS = 3
#: Episodes of the 12 that may disagree with the full simulation (measured: 1).
ALLOWED_DISAGREEMENTS = 2


@pytest.mark.slow
def test_default_physics_agrees_with_the_full_simulation(real_data: Path) -> None:
    lines, disagree = [], 0
    for dataset in ("diverse", "longboard"):
        for spec in episode_specs(dataset, split="train", groups=GROUPS):
            for policy in ("dbl", "hm"):
                default = Outcome.of(run_episode(spec, load_policy(policy), PhysicsPack()))
                full = Outcome.of(run_episode(spec, load_policy(policy), PhysicsPack(mode="full")))
                verdict = compare(default, full)
                disagree += not verdict.agree
                lines.append(f"{dataset} {policy} group {spec.group}: {default} vs {full}: {verdict}")
    report = "\n".join(lines) + f"\nagree on {len(lines) - disagree}/{len(lines)}"
    print(report)
    assert disagree <= ALLOWED_DISAGREEMENTS, report
