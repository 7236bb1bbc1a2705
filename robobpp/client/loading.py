"""Load any policy by name, including the URL of a policy server.

:func:`robobpp.policies.load_policy` knows the built-in names and ``module:Class``; a URL needs the
client's :class:`~robobpp.client.remote.RemotePolicy`, and the policies package must not import the
client (the client is built on the policies, not the other way round). The CLI and anything else that
takes a policy name from a person loads it through here.
"""

from __future__ import annotations

from robobpp.policies import Policy, PolicyLoadError
from robobpp.policies import load_policy as load_local_policy

URL_PREFIXES = ("http://", "https://")


def load_policy(name: str, **kwargs: object) -> Policy:
    """A built-in name, ``module:Class``, or an ``http(s)://`` URL of a server speaking robobpp/1."""
    if name.startswith(URL_PREFIXES):
        from robobpp.client.remote import RemotePolicy

        try:
            return RemotePolicy(name, **kwargs)  # type: ignore[arg-type]
        except (TypeError, ValueError) as exc:
            raise PolicyLoadError(str(exc)) from exc
    return load_local_policy(name, **kwargs)


__all__ = ["PolicyLoadError", "load_policy"]
