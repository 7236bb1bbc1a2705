"""robobpp: closed-loop benchmark and evaluation service for robotic online 3D bin packing."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import sys
from types import ModuleType
from typing import Any

__version__ = "0.1.0"

#: The Gymnasium id of the packing env (robobpp/env.py); registered when robobpp is imported.
GYM_ENV_ID = "robobpp/Pack-v0"
#: Episode step limit of the registered env: above any dataset group, so it never cuts a real episode.
GYM_MAX_EPISODE_STEPS = 1000


def register_gym_envs() -> None:
    """Register ``robobpp/Pack-v0`` with Gymnasium without importing the env module (idempotent).

    Gymnasium ≥ 1.0 has no plugin entry points, so registration rides on ``import robobpp``; the
    ``gymnasium.envs`` entry point in pyproject.toml points here for tools that still load plugins.
    """
    import gymnasium

    if GYM_ENV_ID not in gymnasium.registry:
        gymnasium.register(
            GYM_ENV_ID, entry_point="robobpp.env:PackEnv", max_episode_steps=GYM_MAX_EPISODE_STEPS
        )


class _RegisterAfterImport(importlib.abc.Loader):
    """Gymnasium's own loader, which registers the env once Gymnasium's package has run."""

    def __init__(self, loader: importlib.abc.Loader) -> None:
        self._loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self._loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self._loader.exec_module(module)
        register_gym_envs()

    def __getattr__(self, name: str) -> Any:  # resource readers and the like: the real loader's
        return getattr(self._loader, name)


class _WhenGymnasiumIsImported(importlib.abc.MetaPathFinder):
    """Registers the env when Gymnasium is first imported, so that ``import robobpp`` does not import it: the
    server's, the workers' and the board worker's processes never use it (5 MB and 0.2 s of start-up each,
    every CLI command included), while ``import robobpp`` before or after ``import gymnasium`` registers
    ``robobpp/Pack-v0`` as before. Removes itself once it has found Gymnasium."""

    def find_spec(
        self, name: str, path: Any = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)  # as the finders after this one find it
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisterAfterImport(spec.loader)
        return spec


if "gymnasium" in sys.modules:
    register_gym_envs()
elif not any(isinstance(finder, _WhenGymnasiumIsImported) for finder in sys.meta_path):
    sys.meta_path.insert(0, _WhenGymnasiumIsImported())
