"""A server a test starts dies with the test process, even when that process is killed (tests/_orphans.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

PARENT = """
import subprocess, sys
from tests._orphans import with_parent_death
child = subprocess.Popen(with_parent_death([sys.executable, "-c", "import time; time.sleep(120)"]))
print(child.pid, flush=True)
import time; time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped by init) counts as gone
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("launcher", [True, False])
def test_a_server_started_by_a_killed_test_process_goes_too(launcher: bool) -> None:
    code = PARENT if launcher else PARENT.replace("with_parent_death([", "([")
    parent = subprocess.Popen(
        [sys.executable, "-c", code],
        stdout=subprocess.PIPE,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))),
    )
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    try:
        assert _alive(child)
        parent.send_signal(signal.SIGKILL)  # as a CI timeout or kill -9 ends a test run: no finally runs
        parent.wait(10)
        deadline = time.monotonic() + (10 if launcher else 1)
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _alive(child) is (not launcher)  # without the launcher the child is orphaned, still running
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)
