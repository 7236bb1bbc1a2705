"""A built-in baseline reaches the worker the way a participant's policy does: over ``robobpp/1``.

A built-in (``builtin:NAME``) is served by the SDK's own server (:func:`robobpp.client.serve.create_policy_app`)
on a free loopback port of the worker process, and driven by :class:`~robobpp.client.remote.RemotePolicy`,
signed, with the network probes on: it pays the serialisation, the HTTP exchange and the network estimate's
subtraction that every participant pays, so a participant serving the same method is measured alike
(docs/server.md, "Built-in policies"; BENCHMARKS.md, "Decision Time: built-ins served, and what a measurement
resolves"). Placements are those of the policy in-process: each episode gets a fresh instance, as it did
in-process, the server rebuilds the very observation, and the episode id the policy seeds from travels in
``/reset``.

One server per worker process and built-in, started on first use and kept: starting and stopping one per
episode cost about 0.15 s an episode, as much as a whole Math Pack episode of a heuristic.
"""

from __future__ import annotations

import os
import secrets
import threading
from collections import OrderedDict
from typing import Any

from robobpp.client.remote import RemotePolicy
from robobpp.client.serve import BackgroundServer, create_policy_app
from robobpp.core import Action, EpisodeInfo, Observation
from robobpp.policies import load_policy

#: Episodes whose policy instance a server keeps, the least recently reset dropped first: more than a Celery
#: threads pool runs at once in one process (``/close`` names no episode, so none is dropped at its end); a
#: built-in's instance is small (PCT's weights are cached once per process).
KEEP_EPISODES = 256


class FreshPerEpisode:
    """The built-in ``builtin`` as the server's one policy: a new instance at each ``reset``, kept by
    episode id (the serve app calls it one request at a time)."""

    def __init__(self, builtin: str) -> None:
        first = load_policy(builtin)  # fails here, at once, for an unknown name
        self.builtin = builtin
        self.name: str = getattr(first, "name", builtin)
        self.version: str | None = getattr(first, "version", None)
        self._episodes: OrderedDict[str, Any] = OrderedDict()

    def reset(self, info: EpisodeInfo) -> None:
        policy = load_policy(self.builtin)
        policy.reset(info)
        self._episodes[info.episode_id] = policy
        while len(self._episodes) > KEEP_EPISODES:
            self._episodes.popitem(last=False)

    def act(self, obs: Observation) -> Action | None:
        policy = self._episodes.get(obs.episode_id)
        if policy is None:
            raise RuntimeError(f"act for episode {obs.episode_id!r}, which had no reset")
        result: Action | None = policy.act(obs)
        return result

    def close(self, reason: str) -> None:
        """Nothing to do: no built-in keeps anything past an episode, and ``/close`` names no episode to
        drop (the instances go by ``KEEP_EPISODES``)."""


#: This process's servers by (process id, built-in): the server, its secret and the policy's name.
_servers: dict[tuple[int, str], tuple[BackgroundServer, str, str]] = {}
_lock = threading.Lock()


def served(builtin: str) -> tuple[str, str, str]:
    """This process's server of ``builtin``: its URL, secret and the policy's name (started on first use;
    keyed by process id, so a forked worker starts its own)."""
    key = (os.getpid(), builtin)
    with _lock:
        if key not in _servers:
            policy = FreshPerEpisode(builtin)
            secret = secrets.token_hex(16)  # signed, as a participant's server is asked to be
            server = BackgroundServer(create_policy_app(policy, secret)).start()
            _servers[key] = (server, secret, policy.name)
        server, secret, name = _servers[key]
        return server.url, secret, name


class ServedBuiltin(RemotePolicy):
    """The built-in policy ``builtin`` through this process's loopback server, for one episode."""

    def __init__(self, builtin: str, *, step_timeout_s: float, episode_timeout_s: float | None) -> None:
        url, secret, name = served(builtin)
        super().__init__(
            url,
            secret,
            step_timeout_s=step_timeout_s,
            episode_timeout_s=episode_timeout_s,
            name=name,
            probe_network=True,
        )
