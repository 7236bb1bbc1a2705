"""The server's log format, in one place: every process of ``robobpp serve`` (the API, its board worker, the
API processes of ``--server-workers``) and uvicorn's own lines write ``time level logger: message``.

An operator reading a log after the fact needs to know when each line happened (a backlog's progress, a
restart, a failure): every line carries its time, to the second, in the machine's local time zone.
"""

from __future__ import annotations

import logging
from typing import Any

#: Every log line: ``2025-01-31 14:02:07 INFO robobpp.server: ...``.
FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
DATE_FORMAT = "%Y-%m-%d %H:%M:%S"


def configure(level: int = logging.INFO) -> None:
    """The root logger's handler and format (the first call in a process wins, as ``logging.basicConfig``)."""
    logging.basicConfig(level=level, format=FORMAT, datefmt=DATE_FORMAT)
    logging.getLogger("alembic.runtime.plugins").setLevel(logging.WARNING)  # seven lines of plugin set-up


def uvicorn_log_config() -> dict[str, Any]:
    """uvicorn's ``log_config``: its loggers keep their levels but no handler of their own, so their lines go
    to the root logger's (:func:`configure`) and have the same format and time stamp as ours."""
    names = ("uvicorn", "uvicorn.error", "uvicorn.access")
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "loggers": {name: {"handlers": [], "level": "INFO", "propagate": True} for name in names},
    }
