"""Servers started by tests die with the test run, even when it is killed.

A test that starts ``robobpp serve`` stops it in ``finally``, which a killed pytest (a CI timeout, kill -9)
never reaches: such a server once kept running 90 minutes with its worker processes. ``with_parent_death``
prefixes a command with a small launcher that asks Linux to send it SIGTERM when its parent dies
(``PR_SET_PDEATHSIG``, kept across ``exec``: robobpp/worker/lifeline.py, which ``robobpp serve`` uses for the
processes it starts), then becomes the command. Elsewhere it runs the command as is.
"""

from __future__ import annotations

import sys

_LAUNCHER = """
import os, signal, sys
from robobpp.worker.lifeline import set_parent_death_signal
parent = int(sys.argv[1])
set_parent_death_signal(signal.SIGTERM)
if os.getppid() != parent:  # the parent died before the request: nobody would stop this server
    sys.exit(1)
os.execv(sys.argv[2], sys.argv[2:])
"""


def with_parent_death(cmd: list[str]) -> list[str]:
    """``cmd`` (its first item an absolute executable path) to run so it ends when this process ends."""
    if not sys.platform.startswith("linux"):
        return cmd
    import os

    return [sys.executable, "-c", _LAUNCHER, str(os.getpid()), *cmd]
