"""A closed loop is never worse than a blind replay for want of a support rule the environment does not have.

Real data: Long Board train group 1, LSAH. A 79 × 40 box takes the corner; the next box, a 234 × 44 panel, has
only positions that overhang it. Physics version 3's heuristics applied the reference's support rule to their
candidates in the physical settings, refused all of them, and the episode ended at box 1 while the same plan
replayed blind went on. The reference's environment accepts what fits (bounds and height); its heuristics test no
support. Now the panel is placed and gravity decides.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from robobpp.core import ContainerSpec
from robobpp.env import feasible_mask
from robobpp.episode import Episode
from robobpp.policies import load_policy


@pytest.mark.network
def test_lsah_places_the_panel_no_position_supports_on_a_real_long_board_group(real_data: Path) -> None:
    from robobpp.datasets import episode_specs

    spec = episode_specs("longboard", "train", 2)[1]
    assert spec.container == ContainerSpec(250, 120, 100)
    assert (spec.boxes[0].length, spec.boxes[0].width) == (79, 40)
    assert (spec.boxes[1].length, spec.boxes[1].width) == (234, 44)
    policy = load_policy("lsah")
    episode = Episode(spec, "physics")
    policy.reset(episode.info)
    first = episode.step(policy.act(episode.observe()), 0.0)
    assert first.placement is not None and first.termination is None
    obs = episode.observe()
    assert obs.step == 1 and obs.placed[0].quaternion is not None  # a physical state
    # the panel fits (bounds, height) at some positions, and the support rule accepts none of them
    fits, supported = feasible_mask(obs), feasible_mask(obs, supported=True)
    assert fits.any() and not supported.any()
    action = policy.act(obs)
    assert action is not None
    second = episode.step(action, 0.0)
    assert second.placement is not None
    # the episode goes on beyond box 1
    for _ in range(3):
        if episode.done:
            break
        episode.step(policy.act(episode.observe()), 0.0)
    result = episode.result("lsah")
    assert result.boxes_placed >= 3, (result.termination, result.termination_detail)
    assert result.steps[1].placement is not None
    utilisation = result.metrics["space_utilization"]
    assert utilisation is not None and np.isfinite(utilisation)
