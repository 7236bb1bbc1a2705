"""Outage logging: one clear line when the database or the broker goes away, one when it is back.

Background loops (dispatcher, lease sweeper, workers, lease renewal) retry every round; logging a
traceback per attempt buried the one fact that mattered (an 11 s Redis outage wrote 31 tracebacks). An
:class:`OutageLog` remembers whether each dependency is down and logs only the changes of state; the
attempts in between go to DEBUG. An error that is not an outage (a bug) is still logged with its traceback.
"""

from __future__ import annotations

import logging
import time


def dependency_of(exc: BaseException) -> str | None:
    """``database``, ``broker`` or ``None`` (not a connection problem: a bug worth a traceback)."""
    from sqlalchemy.exc import DBAPIError, OperationalError
    from sqlalchemy.exc import TimeoutError as PoolTimeout

    if isinstance(exc, OperationalError | PoolTimeout) or (
        isinstance(exc, DBAPIError) and exc.connection_invalidated
    ):
        return "database"
    module = type(exc).__module__
    if module.startswith(_BROKER_LIBRARIES) or isinstance(exc, ConnectionError | TimeoutError):
        return "broker"
    if _raised_in_broker_library(exc):
        # A client library left in a broken state by an outage fails with a plain AttributeError or the like
        # (kombu's "'NoneType' object has no attribute '_used_channel_ids'"): still the broker, not our bug.
        return "broker"
    return None


_BROKER_LIBRARIES = ("kombu", "redis", "amqp", "celery")


def _raised_in_broker_library(exc: BaseException) -> bool:
    tb = exc.__traceback__
    if tb is None:
        return False
    while tb.tb_next is not None:
        tb = tb.tb_next
    module = str(tb.tb_frame.f_globals.get("__name__", ""))
    return module.startswith(_BROKER_LIBRARIES)


def _short(exc: BaseException) -> str:
    text = " ".join(str(getattr(exc, "orig", None) or exc).split())
    return f"{type(exc).__name__}: {text[:200]}"


class OutageLog:
    """Tracks down/up per dependency for one component (``what``: "dispatcher", "worker 1234", ...)."""

    def __init__(self, log: logging.Logger, what: str) -> None:
        self.log = log
        self.what = what
        self.down_since: dict[str, float] = {}

    def failed(self, exc: BaseException, doing: str = "round") -> None:
        dependency = dependency_of(exc)
        if dependency is None:
            self.log.warning("%s: %s failed", self.what, doing, exc_info=exc)
            return
        if dependency in self.down_since:
            self.log.debug("%s: %s still unreachable (%s)", self.what, dependency, _short(exc))
            return
        self.down_since[dependency] = time.monotonic()
        self.log.error(
            "%s: %s unreachable (%s); retrying quietly until it answers", self.what, dependency, _short(exc)
        )

    def ok(self, *dependencies: str) -> None:
        """A round succeeded using ``dependencies`` (``database``, ``broker``): those answer again."""
        for dependency in dependencies:
            since = self.down_since.pop(dependency, None)
            if since is not None:
                self.log.warning(
                    "%s: %s reachable again after %.1f s", self.what, dependency, time.monotonic() - since
                )
