"""The default physics against the full simulation on real train episodes (docs/validation/physics.md, "Fidelity";
``bench/fidelity_physics.py`` runs the criterion on 90 episodes).

The short episodes of the Diverse and Long Board datasets (DBL and HM end them after 6–34 boxes), so the full
simulation stays cheap. The criterion is the bench's (``robobpp.sim.physics.fidelity.compare``): the same
termination, boxes placed ±1 and Local Stability within 5 mm, and its pass mark: the default parts from the full
simulation no more often than the full simulation parts from itself under a 0.1 mm higher release (exact one-sided
McNemar, p ≥ 0.05). Physics version 4 (the heuristics place overhanging panels, as the reference's) meets the
criterion on 9 of these 12 episodes and the full simulation with itself on 11 (McNemar p = 0.25): the three are
Long Board episodes where see-sawing panels settle differently (version 3, whose heuristics kept to supported
positions: 11 of 12). The test also fails when more than 4 of the 12 disagree.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from robobpp.datasets import episode_specs
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsConfig, PhysicsPack
from robobpp.sim.physics.fidelity import Outcome, compare, mcnemar_one_sided

GROUPS = 3
#: Episodes of the 12 that may disagree with the full simulation (measured: 3).
ALLOWED_DISAGREEMENTS = 4


@pytest.mark.slow
def test_default_physics_agrees_with_the_full_simulation(real_data: Path) -> None:
    lines, only_default, only_noise, disagree = [], 0, 0, 0
    noise_start = PhysicsConfig().lower_from_cm + 0.01
    for dataset in ("diverse", "longboard"):
        for spec in episode_specs(dataset, split="train", groups=GROUPS):
            for policy in ("dbl", "hm"):
                default = Outcome.of(run_episode(spec, load_policy(policy), PhysicsPack()))
                full = Outcome.of(run_episode(spec, load_policy(policy), PhysicsPack(mode="full")))
                noisy = Outcome.of(
                    run_episode(
                        spec, load_policy(policy), PhysicsPack(mode="full", lower_from_cm=noise_start)
                    )
                )
                verdict, noise = compare(default, full), compare(noisy, full)
                disagree += not verdict.agree
                only_default += noise.agree and not verdict.agree
                only_noise += verdict.agree and not noise.agree
                lines.append(
                    f"{dataset} {policy} group {spec.group}: {default} vs {full}: {verdict}; noise {noise}"
                )
    p = mcnemar_one_sided(only_default, only_noise)
    report = "\n".join(lines) + f"\nagree on {len(lines) - disagree}/{len(lines)}; McNemar p = {p:.3f}"
    print(report)
    assert p >= 0.05, report
    assert disagree <= ALLOWED_DISAGREEMENTS, report
