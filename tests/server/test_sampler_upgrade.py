"""A server upgraded to a new sampler version (docs/datasets.md, "Private groups nobody can look up"): at start it
draws its private split and hold-out draw again where another version drew them, and queues again the baselines
whose runs a board would now leave out."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select, update

from robobpp.datasets import load_private
from robobpp.datasets.private import HOLDOUT_DIR
from robobpp.datasets.sampling import SAMPLER_VERSION
from robobpp.db.models import EpisodeRow, RunRow, Submission
from robobpp.server.app import create_app
from robobpp.server.bootstrap import bootstrap, ensure_baselines, ensure_private_split
from robobpp.server.config import Settings
from robobpp.sim.math_pack import MATH_RULES_VERSION

ADMIN = "sampler-admin-token-0123456789abcdef"


def _settings(tmp_path: Path, **extra: Any) -> Settings:
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'sampler.sqlite3'}",
        state_dir=tmp_path,
        private_dir=tmp_path / "datasets_private",
        admin_token=ADMIN,
        workers=0,
        evaluate_baselines=False,
        settings=("math",),
        datasets=("repetitive", "diverse"),
        groups=2,
        public_baselines=False,
        **extra,
    )


@pytest.mark.network
def test_a_private_set_of_another_sampler_version_is_drawn_again_at_start(
    real_data: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    settings = _settings(tmp_path)
    assert ensure_private_split(settings)  # first start: both draws
    roots = (settings.private_dir, settings.private_dir / HOLDOUT_DIR)
    first = {root: load_private("repetitive", root) for root in roots}
    kept = load_private("diverse", settings.private_dir)
    # As a version-1 server left it: its entries record no sampler (the files say version 1).
    for root in roots:
        manifest = json.loads((root / "manifest.json").read_text())
        del manifest["datasets"]["repetitive"]["sampler"]
        (root / "manifest.json").write_text(json.dumps(manifest))
    with caplog.at_level("WARNING", logger="robobpp.server"):
        assert ensure_private_split(settings)
    assert f"not drawn by sampler {SAMPLER_VERSION}" in caplog.text and "['repetitive']" in caplog.text
    for root in roots:
        again = load_private("repetitive", root)
        assert again != first[root] and {s.sampler_version for s in again} == {SAMPLER_VERSION}
    assert load_private("diverse", settings.private_dir) == kept  # current: left as it was
    caplog.clear()
    with caplog.at_level("WARNING", logger="robobpp.server"):
        assert ensure_private_split(settings)  # nothing stale: nothing built
    assert "building the private split" not in caplog.text


def test_baselines_whose_runs_another_sampler_drew_are_queued_again(tmp_path: Path) -> None:
    settings = _settings(
        tmp_path, baselines=("dbl", "lsah"), spec_provider="robobpp.worker.specs:offline_spec"
    )
    app = create_app(settings, start_workers=False)
    bootstrap(app.state.runtime)
    try:
        with app.state.runtime.session() as s:
            assert ensure_baselines(s, settings) == 2
            ids = {sub.policy_url: sub.id for sub in s.execute(select(Submission)).scalars()}
            s.execute(update(Submission).values(status="completed"))
            s.execute(update(EpisodeRow).values(status="done"))
            for url, sampler in (("builtin:dbl", "1"), ("builtin:lsah", SAMPLER_VERSION)):
                s.execute(
                    update(RunRow)
                    .where(RunRow.submission_id == ids[url])
                    .values(extras={"provenance": {"math_rules": MATH_RULES_VERSION, "sampler": sampler}})
                )
        with app.state.runtime.session() as s:
            assert ensure_baselines(s, settings) == 1
            queued = s.execute(select(Submission.policy_url).where(Submission.status == "queued")).scalars()
            assert list(queued) == ["builtin:dbl"]
    finally:
        app.state.runtime.dispose()
