"""Every result records the physics version that produced it; a board never mixes versions."""

from __future__ import annotations

import pytest
from sqlalchemy import select

from robobpp.boards.engine import leaderboard
from robobpp.core import Box
from robobpp.db import work
from robobpp.db.migrate import upgrade
from robobpp.db.models import EpisodeRow, Participant
from robobpp.db.session import make_engine, make_session_factory, transaction
from robobpp.episode import EpisodeResult, run_episode
from robobpp.policies import load_policy
from robobpp.sim import make_setting
from robobpp.sim.physics import PHYSICS_VERSION, PhysicsConfig
from tests.server.conftest import complete_next_episode
from tests.sim.physics._physics_specs import spec_of


def test_results_record_the_physics_version() -> None:
    spec = spec_of([Box(20, 20, 10, 1.0)] * 2)
    physics = run_episode(spec, load_policy("dbl"), "physics")
    assert physics.physics_version == PHYSICS_VERSION
    assert EpisodeResult.from_dict(physics.to_dict(trace=False)).physics_version == PHYSICS_VERSION
    assert run_episode(spec, load_policy("dbl"), "math").physics_version is None
    # Full mode is the validated default's reference: the same version. Changed physics is not.
    assert make_setting("physics", mode="full").physics_version == PHYSICS_VERSION
    custom = make_setting("physics", lateral_friction=0.5).physics_version
    assert custom is not None and custom.startswith(PHYSICS_VERSION + "+")
    assert custom != make_setting("physics", walls=True).physics_version
    assert PhysicsConfig(lateral_friction=0.5).version == custom  # a pure function of the settings


def test_an_experiment_robot_is_a_version_of_its_own() -> None:
    """The Execution Pack's robot options (the reference-robot experiments) change results as physics options
    do: before, ``approximate_plans=True`` recorded the benchmark's version and could share its boards."""
    assert make_setting("execution").physics_version == PHYSICS_VERSION
    approximate = make_setting("execution", approximate_plans=True).physics_version
    reference = make_setting("execution", descend=False, carried_yaw_deg=90.0).physics_version
    physics_change = make_setting("execution", lateral_friction=0.5).physics_version
    versions = {approximate, reference, physics_change}
    assert len(versions) == 3 and all(v is not None and v.startswith(PHYSICS_VERSION + "+") for v in versions)
    assert make_setting("execution", approximate_plans=True).physics_version == approximate  # deterministic
    # the physics part of the digest is the Physics Pack's own
    assert physics_change == make_setting("physics", lateral_friction=0.5).physics_version


@pytest.fixture
def factory(tmp_path):
    url = f"sqlite:///{tmp_path / 'board.db'}"
    engine = make_engine(url)
    upgrade(url, engine=engine)
    yield make_session_factory(engine)
    engine.dispose()


def _finished_submission(factory, name: str, version: str | None) -> None:
    with transaction(factory) as s:
        p = s.execute(select(Participant).where(Participant.name == "p")).scalar_one_or_none()
        if p is None:
            p = Participant(name="p")
            s.add(p)
            s.flush()
        work.create_submission(
            s,
            p,
            name=name,
            policy_url="builtin:dbl",
            datasets=["diverse"],
            settings=["math", "physics"],
            groups=1,
        )
    # closed loop, then the paper protocol's replay of the Math episode (docs/server.md)
    for setting, protocol in (("math", "closed"), ("physics", "closed"), ("physics", "paper")):
        metrics = {"space_utilization": 0.5, "occupancy": 0.9, "decision_time": 0.01}
        if setting == "physics":
            metrics |= {"local_stability": 0.01, "static_stability": 0.4}
        recorded = version if setting == "physics" else None
        claim = complete_next_episode(factory, metrics, physics_version=recorded)
        with transaction(factory) as s:
            row = s.get(EpisodeRow, claim.episode_id)
            assert row is not None and (row.setting, row.protocol) == (setting, protocol)
            assert row.physics_version == recorded


def test_a_physics_board_shows_only_the_current_version(factory) -> None:
    _finished_submission(factory, "now", PHYSICS_VERSION)
    _finished_submission(factory, "old", "1")
    _finished_submission(factory, "unversioned", None)
    with transaction(factory) as s:
        physics = [e["name"] for e in leaderboard(s, "diverse", "physics", track="private").entries]
        math = sorted(e["name"] for e in leaderboard(s, "diverse", "math", track="private").entries)
    assert physics == ["now"]
    assert math == ["now", "old", "unversioned"]  # geometry has no physics version
