"""Policies: the paper's baseline heuristics (one module each) and loading of user policies.

A policy is named by a built-in name (``dbl``) or a ``module:Class`` path. The URL of a policy server
is the client's business (:func:`robobpp.client.loading.load_policy`): this package is below the client
and imports nothing from it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from robobpp.policies.base import BasePolicy, Policy, PolicyError

#: Built-in policies: name → "module:Class". Modules load lazily so one slow import never taxes the rest.
BUILTIN: dict[str, str] = {
    "dbl": "robobpp.policies.dbl:DBL",
    "hm": "robobpp.policies.hm:HM",
    "lsah": "robobpp.policies.lsah:LSAH",
    "onlinebph": "robobpp.policies.onlinebph:OnlineBPH",
    "br": "robobpp.policies.br:BR",
    "macs": "robobpp.policies.macs:MACS",
    "sdfpack": "robobpp.policies.sdfpack:SDFPack",
    "packe-rules": "robobpp.policies.packe_rules:PackERules",
    "random": "robobpp.policies.random_policy:RandomPolicy",
    "pct": "robobpp.policies.pct:PCT",  # learned: the authors' trained weights (policies/pct/)
}

#: Learned policies with published weights; on the leaderboard beside the baselines (docs/baselines.md, "PCT").
LEARNED: tuple[str, ...] = ("pct",)
#: The paper's baselines shown on the leaderboard (a subset of BUILTIN, in the paper's order).
BASELINES: tuple[str, ...] = tuple(name for name in BUILTIN if name not in LEARNED)

#: Display names, spelled as in the paper.
TITLES: dict[str, str] = {
    "dbl": "DBL",
    "hm": "HM",
    "lsah": "LSAH",
    "onlinebph": "OnlineBPH",
    "br": "BR",
    "macs": "MACS",
    "sdfpack": "SDFPack",
    "packe-rules": "PackE-rules",
    "random": "Random",
    "pct": "PCT",
}


class PolicyLoadError(ValueError):
    """The policy name could not be turned into a policy (unknown name, bad import path)."""


def _import(path: str) -> Callable[..., Any]:
    module_name, _, attr = path.partition(":")
    if not module_name or not attr:
        raise PolicyLoadError(f"policy path {path!r} must look like 'package.module:ClassName'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise PolicyLoadError(f"cannot import module {module_name!r}: {exc}") from exc
    try:
        factory: Callable[..., Any] = getattr(module, attr)
    except AttributeError as exc:
        raise PolicyLoadError(f"module {module_name!r} has no attribute {attr!r}") from exc
    return factory


def load_policy(name: str, **kwargs: object) -> Policy:
    """Instantiate a policy from a built-in name or ``module:Class``."""
    if name.startswith(("http://", "https://")):
        raise PolicyLoadError(
            f"{name!r} is a policy server URL: load it with robobpp.client.loading.load_policy"
        )
    path = BUILTIN.get(name.lower())
    if path is None and ":" not in name:
        known = ", ".join(sorted(BUILTIN))
        raise PolicyLoadError(
            f"unknown policy {name!r}; use one of {known}, 'module:Class' or an http(s) URL"
        )
    factory = _import(path or name)
    try:
        policy: Policy = factory(**kwargs)
    except TypeError as exc:
        raise PolicyLoadError(f"cannot construct policy {name!r}: {exc}") from exc
    if not callable(getattr(policy, "act", None)):
        raise PolicyLoadError(f"{name!r} has no act(observation) method")
    for hook in ("reset", "close"):  # optional for user policies: fill in no-ops
        if not callable(getattr(policy, hook, None)):
            setattr(policy, hook, lambda *_a, **_k: None)
    if not getattr(policy, "name", None):
        policy.name = name
    return policy


__all__ = [
    "BASELINES",
    "BUILTIN",
    "LEARNED",
    "TITLES",
    "BasePolicy",
    "Policy",
    "PolicyError",
    "PolicyLoadError",
    "load_policy",
]
