"""Child processes that die with their parent and yield the CPU to the haptic loop.

A killed ``twin local`` (SIGKILL, out of memory) must not leave 300 MB of idle workers behind. On Linux
each child asks the kernel for a signal when its parent dies (``prctl(PR_SET_PDEATHSIG)``); elsewhere
this is a no-op and children end when their pipes close. Estimation and CoACD workers also run at a lower
priority (:func:`background_worker`): on two cores, a worker at full speed otherwise takes the CPU from the
1 kHz loop for tens of milliseconds while an object is added.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


def die_with_parent() -> None:
    """Call first thing in a child process: SIGTERM it when the process that started it dies."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() == 1:  # the parent died before we asked: nobody will send the signal
        os.kill(os.getpid(), signal.SIGTERM)


#: Niceness added to estimation and CoACD workers: they may take seconds, the loop may not wait 1 ms.
WORKER_NICENESS = 10


def background_worker() -> None:
    """Initializer for worker pools: :func:`die_with_parent`, and a lower scheduling priority."""
    die_with_parent()
    lower_priority()


def lower_priority() -> None:
    """Lower the calling thread's scheduling priority by :data:`WORKER_NICENESS` (on Linux niceness is a
    thread's own: a background thread of a loop's process may call it; elsewhere, the process's)."""
    try:
        os.nice(WORKER_NICENESS)
    except OSError:  # not permitted here: run at the parent's priority
        pass
