"""What a policy is: anything with ``act(observation) -> action`` (+ optional ``reset``, ``close``)."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from robobpp.core import Action, EpisodeInfo, Observation


class PolicyError(Exception):
    """A policy failed in a way that ends the episode with a recorded reason.

    ``reason`` is a termination code (``policy_error``, ``policy_timeout``, ``protocol_violation``...),
    the message says what happened in plain words.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(detail)
        self.reason = reason
        self.detail = detail


@runtime_checkable
class Policy(Protocol):
    """The policy interface of the episode loop.

    ``act`` returns ``None`` to say "no feasible placement" for this box: the episode then ends with that
    reason, like any other termination.
    """

    name: str

    def reset(self, info: EpisodeInfo) -> None: ...

    def act(self, obs: Observation) -> Action | None: ...

    def close(self, reason: str) -> None: ...


class BasePolicy:
    """Convenience base: no-op ``reset``/``close``; subclasses write ``act``."""

    name = "policy"

    def reset(self, info: EpisodeInfo) -> None:
        return None

    def act(self, obs: Observation) -> Action | None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self, reason: str) -> None:
        return None
