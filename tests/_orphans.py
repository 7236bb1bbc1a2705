"""Servers started by tests die with the test run, even when it is killed.

A test that starts ``robobpp serve`` stops it in ``finally``, which a killed pytest (a CI timeout, kill -9)
never reaches: such a server once kept running 90 minutes with its worker processes. ``with_parent_death``
prefixes a command with a small launcher that asks Linux to send it SIGTERM when its parent dies
(``PR_SET_PDEATHSIG``, kept across ``exec``), then becomes the command. Elsewhere it runs the command as is.
"""

from __future__ import annotations

import sys

_LAUNCHER = """
import ctypes, os, signal, sys
parent = int(sys.argv[1])
try:
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
except (OSError, AttributeError):
    pass
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
