"""Fast mode (frozen far boxes, early stop at rest) against the full dynamic simulation (docs/benchmark.md, "Settings").

A fixed set of DBL episodes with runs of identical boxes in a small pallet, so that a couple of dozen boxes
already make three or four layers. The criterion is the fidelity bench's (docs/validation/physics.md, "Fidelity";
``robobpp.sim.physics.fidelity.compare``): the same termination, boxes placed ±1 and Local Stability within
5 mm, and its pass mark: fast mode parts from the full simulation no more often than the full simulation parts from
itself under a 0.1 mm higher release (exact one-sided McNemar, p >= 0.05). Physics version 3 met the criterion on
all 20; version 4's DBL (no support rule, as the reference's) overhangs and collapses more, and fast mode parts on 2
of the 20 (a collapse at box 18 against a completed episode, and Local Stability 5.1 mm apart after a collapse):
the test also failed when more than 3 of the 20 disagreed. Version 5 lands each box as the reference does (a
mesh lowered until it touches), whose contacts are livelier: the full simulation then parts from itself under a
0.1 mm higher start on 8 of the 20 (after a collapse, Local Stability more than 5 mm apart) and fast mode from it on
6; the test fails when fast mode disagrees on more than 2 episodes beyond what the full simulation does with itself.
"""

from __future__ import annotations

import pytest

from robobpp.core import ContainerSpec
from robobpp.episode import run_episode
from robobpp.policies import load_policy
from robobpp.sim.physics import PhysicsConfig, PhysicsPack
from robobpp.sim.physics.fidelity import Outcome, compare, mcnemar_one_sided
from tests.sim.physics._physics_specs import repetitive_like

EPISODES = 20
BOXES = 20
SMALL = ContainerSpec(80, 60, 100)
#: Episodes beyond the full simulation's own disagreements with itself where fast mode may disagree with it
#: (measured at physics version 5: fast 6, the full simulation with itself 8).
ALLOWED_EXTRA_DISAGREEMENTS = 2


@pytest.mark.slow
def test_fast_mode_matches_the_full_simulation() -> None:
    """Box sides to 1 mm like the real data (27.4 cm), so a policy on the 1 cm grid puts neighbours a few
    millimetres into each other's footprint: the case that parted the two modes on real data before the
    release cleared such neighbours (docs/physics.md). ``test_fidelity_real.py`` holds real episodes."""
    agree, noise_agree, only_fast, only_noise = 0, 0, 0, 0
    lines = []
    noise_start = PhysicsConfig().lower_from_cm + 0.01
    for group in range(EPISODES):
        spec = repetitive_like(group, n=BOXES, container=SMALL, millimetres=True)
        fast = Outcome.of(run_episode(spec, load_policy("dbl"), PhysicsPack(mode="fast")))
        full = Outcome.of(run_episode(spec, load_policy("dbl"), PhysicsPack(mode="full")))
        noisy = Outcome.of(
            run_episode(spec, load_policy("dbl"), PhysicsPack(mode="full", lower_from_cm=noise_start))
        )
        verdict, noise = compare(fast, full), compare(noisy, full)
        agree += verdict.agree
        noise_agree += noise.agree
        only_fast += noise.agree and not verdict.agree
        only_noise += verdict.agree and not noise.agree
        lines.append(f"{group}: {fast} vs {full}: {verdict}; noise {noise}")
    p = mcnemar_one_sided(only_fast, only_noise)
    report = "\n".join(lines) + f"\nagree on {agree}/{EPISODES}; McNemar p = {p:.3f}"
    print(report)
    assert p >= 0.05, report
    assert EPISODES - agree <= EPISODES - noise_agree + ALLOWED_EXTRA_DISAGREEMENTS, report
