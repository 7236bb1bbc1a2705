"""Which optional extra brings which third-party package, and the one-line error when one is missing.

``pip install robobpp`` is the participant's SDK (protocol, policies, Math Pack, the Gym env, ``serve``,
the conformance check, the API client, pull mode). Everything heavier comes with an extra; see the README.
A feature whose package is absent raises :class:`MissingExtraError`, and the CLI prints its text as is.
"""

from __future__ import annotations

import importlib
from types import ModuleType

#: top-level module → (the extra that brings it, what needs it)
EXTRA_OF: dict[str, tuple[str, str]] = {
    "pybullet": ("physics", "Physics Pack"),
    "ompl": ("execution", "Execution Pack"),
    "sqlalchemy": ("server", "the evaluation server"),
    "alembic": ("server", "the evaluation server"),
    "psycopg": ("server", "the evaluation server on PostgreSQL"),
    "prometheus_client": ("server", "the evaluation server"),
    "multipart": ("server", "the evaluation server"),
    "pydantic_settings": ("server", "the evaluation server"),
    "itsdangerous": ("server", "the evaluation server"),
    "torch": ("learn", "training"),
    "stable_baselines3": ("learn", "training"),
    "sb3_contrib": ("learn", "training"),
    "celery": ("worker", "Celery workers"),
    "kombu": ("worker", "Celery workers"),
    "redis": ("worker", "Celery workers on Redis"),
}


class MissingExtraError(ImportError):
    """A feature needs a package that only an extra installs; the text names the ``pip install``."""


def message(module: str, extra: str | None = None, what: str | None = None) -> str:
    """``Physics Pack needs pybullet, which is not installed: pip install 'robobpp[physics]'``."""
    root = module.split(".")[0]
    known_extra, known_what = EXTRA_OF.get(root, ("all", "this feature"))
    return (
        f"{what or known_what} needs {root}, which is not installed: "
        f"pip install 'robobpp[{extra or known_extra}]'"
    )


def missing_extra(exc: ModuleNotFoundError) -> MissingExtraError | None:
    """The :class:`MissingExtraError` for an import that failed on a package an extra brings, else None."""
    root = (exc.name or "").split(".")[0]
    if root not in EXTRA_OF:
        return None
    return MissingExtraError(message(root), name=root)


def require(module: str, extra: str | None = None, what: str | None = None) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` naming the extra to install."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] != module.split(".")[0]:
            raise  # something else is missing: not ours to explain
        raise MissingExtraError(message(module, extra, what), name=module) from None
