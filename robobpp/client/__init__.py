"""Client SDK: serve a policy over protocol robobpp/1 (``serve``, or ``connect`` it out to a server in pull
mode), drive a remote one as a local policy, and talk to an evaluation server (:class:`ServerClient`).

Imports are lazy so that using :class:`RemotePolicy` never pulls in FastAPI and uvicorn.
"""

from __future__ import annotations

import sys
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from robobpp.client.api import ServerClient, ServerError
    from robobpp.client.connect import connect
    from robobpp.client.remote import RemotePolicy
    from robobpp.client.serve import BackgroundServer, create_policy_app, serve

_LAZY = {
    "RemotePolicy": "robobpp.client.remote",
    "BackgroundServer": "robobpp.client.serve",
    "create_policy_app": "robobpp.client.serve",
    "serve": "robobpp.client.serve",
    "ServerClient": "robobpp.client.api",
    "ServerError": "robobpp.client.api",
    "connect": "robobpp.client.connect",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'robobpp.client' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)


class _ClientPackage(ModuleType):
    """Keeps ``robobpp.client.serve`` the function although a submodule bears the same name.

    Importing ``robobpp.client.serve`` (the module) makes Python bind it as the package attribute
    ``serve``, so ``from robobpp.client import serve`` would hand participants a module that cannot be
    called. The package refuses that binding; the module stays reachable through ``sys.modules`` and
    ``from robobpp.client.serve import ...``.
    """

    def __setattr__(self, name: str, value: object) -> None:
        if name in ("serve", "connect") and isinstance(value, ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _ClientPackage

__all__ = [
    "BackgroundServer",
    "RemotePolicy",
    "ServerClient",
    "ServerError",
    "connect",
    "create_policy_app",
    "serve",
]
