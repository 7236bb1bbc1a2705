"""The install boundary is the import boundary: contracts on the import graph, and the SDK run for real
with every package of the extras made unimportable (what a fresh ``pip install robobpp`` leaves out)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[1]

#: What `pip install robobpp` (no extras) does not bring.
EXTRAS_ONLY = (
    "pybullet",
    "ompl",
    "sqlalchemy",
    "alembic",
    "celery",
    "kombu",
    "psycopg",
    "redis",
    "prometheus_client",
    "multipart",
)

_BLOCKER = """
import importlib.abc, sys
BLOCKED = set(sys.argv[1].split(","))
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Block())
"""


def _run_without_extras(body: str, blocked: tuple[str, ...] = EXTRAS_ONLY) -> subprocess.CompletedProcess:
    script = _BLOCKER + textwrap.dedent(body)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-c", script, ",".join(blocked)],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=120,
    )


def test_import_contracts_hold(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    assert lint_imports(no_cache=True, no_logo=True) == 0, "an import contract in pyproject.toml is broken"


def test_the_sdk_works_without_any_extra() -> None:
    done = _run_without_extras("""
        import gymnasium as gym, numpy as np
        import robobpp.env
        from robobpp.client.check import check_policy_server
        from robobpp.client.loading import load_policy
        from robobpp.client.serve import BackgroundServer, create_policy_app
        from robobpp.core import Box, ContainerSpec, EpisodeSpec
        from robobpp.episode import run_episode
        from robobpp.extras import MissingExtraError
        from robobpp.sim import make_setting

        boxes = tuple(Box(10.0, 10.0, 5.0, 1.0) for _ in range(6))
        spec = EpisodeSpec("handmade", "train", 0, boxes, ContainerSpec(20, 20, 20), 7.0, 0)
        env = gym.make("robobpp/Pack-v0", specs=[spec])
        env.reset(seed=0)
        mask = env.unwrapped.action_mask()
        _, _, terminated, _, _ = env.step(np.ravel_multi_index(tuple(np.argwhere(mask)[0]), mask.shape))
        with BackgroundServer(create_policy_app(load_policy("dbl"), "s3cret")) as server:
            assert not check_policy_server(server.url, "s3cret").violations
            remote = run_episode(spec, load_policy(server.url, secret="s3cret"), "math")
        assert remote.boxes_placed == 6, remote.termination_detail
        try:
            make_setting("physics")
        except MissingExtraError as exc:
            print("PHYSICS:", exc)
        for name in ("pybullet", "sqlalchemy", "celery"):
            assert name not in sys.modules, name
        print("SDK OK")
    """)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "SDK OK" in done.stdout
    assert "PHYSICS: Physics Pack needs pybullet, which is not installed: pip install 'robobpp[physics]'" in (
        done.stdout
    )


def test_a_command_of_a_missing_extra_names_the_pip_install() -> None:
    done = _run_without_extras(
        """
        sys.argv = ["robobpp", "evaluate", "--policy", "dbl", "--setting", "execution", "--groups", "1"]
        from robobpp.cli import main
        main()
    """,
        blocked=("ompl",),
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr  # (pybullet, which is there, prints its build time first)
    last = done.stderr.strip().splitlines()[-1]
    assert (
        last == "error: Execution Pack needs ompl, which is not installed: pip install 'robobpp[execution]'"
    )


@pytest.mark.parametrize(
    "imports",
    [
        "import robobpp; import gymnasium",
        "import gymnasium; import robobpp",
        "import robobpp; import gymnasium.spaces; import gymnasium",
        "import robobpp.env; import gymnasium",
    ],
)
def test_importing_robobpp_registers_the_env_whenever_gymnasium_comes(imports: str) -> None:
    """``import robobpp`` registers ``robobpp/Pack-v0`` before or after ``import gymnasium`` (README), without
    importing Gymnasium itself: the server's and the workers' processes never use it."""
    done = _run_without_extras(
        f"""
        import importlib.resources, sys
        {imports}
        import gymnasium
        assert gymnasium.spec("robobpp/Pack-v0").entry_point == "robobpp.env:PackEnv"
        assert gymnasium.make("robobpp/Pack-v0").unwrapped.__class__.__name__ == "PackEnv"
        assert importlib.resources.files("gymnasium").is_dir()  # its loader still reads its files
        assert not any("Gymnasium" in type(f).__name__ for f in sys.meta_path)  # the hook is gone
        """,
        blocked=(),
    )
    assert done.returncode == 0, done.stderr


def test_the_service_processes_do_not_import_gymnasium() -> None:
    done = _run_without_extras(
        """
        import sys
        import robobpp, robobpp.boards.worker, robobpp.cli
        assert "gymnasium" not in sys.modules
        """,
        blocked=(),
    )
    assert done.returncode == 0, done.stderr
