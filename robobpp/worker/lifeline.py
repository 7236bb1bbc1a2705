"""Processes that end with the process that started them, however it ends.

``robobpp serve`` starts processes: the API processes of ``--server-workers``, the local workers, the board
worker. Killed outright (``SIGKILL``, the OOM killer), it runs no ``finally`` and stops none of them. Left alone,
API processes would go on answering on the port (``/healthz`` "ok") and accepting submissions that nothing
dispatches; a new ``robobpp serve`` could not bind the port; a worker would finish its episode first. So each
child holds a :class:`Lifeline` to its parent, made by the parent (:meth:`Lifeline.to_here`) and passed to the
child, which calls :meth:`Lifeline.hold` first thing:

- On Linux the kernel sends the child ``SIGKILL`` the moment its parent dies (``PR_SET_PDEATHSIG``), even in the
  middle of a computation in C. The kernel sends it when the *thread* that started the child ends, not the
  process, so this is asked for only when that thread lasts as long as the process (its main thread, or a
  thread that outlives its children: :meth:`Lifeline.to_here`).
- Everywhere, a daemon thread checks every :data:`PARENT_CHECK_S` that the parent process id is still the one
  that started it (an orphan is adopted by init or a subreaper, so its parent id changes) and ends the process
  when it is not. This is the only guard off Linux, and for a child started by a short-lived thread.
- A parent that died before the child got this far is noticed at once.

An API process between its supervisor's death and its own exit reports itself unhealthy: :meth:`Lifeline.intact`.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass

log = logging.getLogger("robobpp.lifeline")

#: ``prctl`` option: the signal to receive when the parent dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1
#: How often a child checks that its parent is still there (the portable guard).
PARENT_CHECK_S = 0.5


def set_parent_death_signal(sig: int) -> bool:
    """Ask Linux to send this process ``sig`` when its parent (the thread that started it) ends; the request is
    kept across ``exec``. ``False`` where it cannot be asked (not Linux, no ``prctl``)."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        return int(ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False


@dataclass(frozen=True)
class Lifeline:
    """What a child needs to end with its parent: the parent's process id, and whether the kernel may be asked to
    end it (``kernel``: the thread that starts the child lives as long as the parent process)."""

    parent: int
    kernel: bool

    @classmethod
    def to_here(cls, *, long_lived_thread: bool | None = None) -> Lifeline:
        """A lifeline to this process, for a child the current thread is about to start. The kernel's signal is
        used when this is the main thread, or ``long_lived_thread`` says this thread outlives its children."""
        if long_lived_thread is None:
            long_lived_thread = threading.current_thread() is threading.main_thread()
        return cls(os.getpid(), long_lived_thread)

    def intact(self) -> bool:
        """Whether the process that started this one is still there."""
        return os.getppid() == self.parent

    def hold(self, what: str) -> None:
        """In the child, before anything else: end this process (``what`` names it in the log) with its parent."""
        if self.kernel:
            set_parent_death_signal(signal.SIGKILL)
        if not self.intact():  # the parent died before the request: nothing would ever end this process
            self._end(what)
        threading.Thread(target=self._watch, args=(what,), daemon=True, name="robobpp-lifeline").start()

    def _watch(self, what: str) -> None:
        while self.intact():
            time.sleep(PARENT_CHECK_S)
        self._end(what)

    def _end(self, what: str) -> None:
        log.warning("the process %d that started this %s is gone: it ends too", self.parent, what)
        logging.shutdown()
        os._exit(0)
