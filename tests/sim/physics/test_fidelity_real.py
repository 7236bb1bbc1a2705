"""The default physics against the full simulation on real train episodes (the criterion of docs/physics.md,
"Fidelity", on a handful of the bench's episodes; ``bench/fidelity_physics.py`` runs it on 90).

The short episodes of the Diverse and Long Board datasets (DBL and HM end them after 5–25 boxes), so the full
simulation stays cheap. Fails when the default mode drifts from the full simulation on more of them than the
full simulation's own chaos accounts for (the bench measures that noise floor).
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
#: Episodes of the set that may disagree: a quarter, the rate at which the full simulation disagrees with
#: itself under a 0.1 mm larger release gap on the bench's real episodes (docs/physics.md, "Fidelity"; on
#: these 12 it disagrees on 2, the default mode on 3).
ALLOWED_MISSES = 3


@pytest.mark.slow
def test_default_physics_agrees_with_the_full_simulation_on_real_episodes(real_data: Path) -> None:
    lines, misses = [], 0
    for dataset in ("diverse", "longboard"):
        for spec in episode_specs(dataset, split="train", groups=GROUPS):
            for policy in ("dbl", "hm"):
                default = Outcome.of(run_episode(spec, load_policy(policy), PhysicsPack()))
                full = Outcome.of(run_episode(spec, load_policy(policy), PhysicsPack(mode="full")))
                verdict = compare(default, full)
                misses += not verdict.agree
                lines.append(f"{dataset} {policy} group {spec.group}: {default} vs {full}: {verdict}")
    report = "\n".join(lines)
    print(report)
    assert misses <= ALLOWED_MISSES, report
