"""What the worker subprocesses of these tests import: a synthetic spec provider and paced policies.

Workers load them by name (``ROBOBPP_SPEC_PROVIDER=tests.celery.helpers:spec``, policy
``builtin:tests.celery.helpers:SlowDBL``), exactly as a deployment loads its real ones. The pacing only
makes an episode last long enough to be killed mid-way; no test asserts on time.
"""

from __future__ import annotations

import time

from robobpp.core import Action, EpisodeSpec, Observation
from robobpp.datasets.registry import get_dataset
from robobpp.datasets.synthetic import synthetic_episode_specs
from robobpp.policies.dbl import DBL

BOXES_PER_EPISODE = 16


def spec(dataset: str, split: str, group: int, groups: int) -> EpisodeSpec:
    """Group ``group`` of a small synthetic set in ``dataset``'s container (deterministic)."""
    get_dataset(dataset)  # unknown names fail like the real provider
    return synthetic_episode_specs(
        group + 1, seed=11, container=dataset, group_size=BOXES_PER_EPISODE, dataset=dataset, split=split
    )[group]


class PacedDBL(DBL):
    """DBL that takes a little while per box, so two workers share a submission."""

    delay_s = 0.03

    def act(self, obs: Observation) -> Action | None:
        time.sleep(self.delay_s)
        return super().act(obs)


class SlowDBL(PacedDBL):
    """DBL slow enough (several seconds per episode) to kill its worker mid-episode."""

    delay_s = 0.4
