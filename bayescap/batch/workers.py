"""Worker processes that do not outlive the process that started them, and one batch per output
folder at a time.

A local pool's workers (``--jobs N``) are started with :func:`process_pool`: each asks the Linux
kernel for SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``), so a parent killed by
SIGTERM or SIGKILL takes its workers with it instead of leaving them computing for minutes; where
``prctl`` is not available a watchdog thread in each worker ends it once its parent is gone.

:func:`folder_lock` holds an exclusive ``flock`` on the output folder itself while a batch writes
into it: a second batch on the same folder is refused at once instead of mixing its results with
the first one's. The lock goes with the process (no lock file is left behind).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from bayescap.exceptions import InputError

__all__ = ["process_pool", "die_with_parent", "folder_lock"]

_PR_SET_PDEATHSIG = 1


def _watch_parent(parent: int, period_s: float = 1.0) -> None:
    while os.getppid() == parent:
        time.sleep(period_s)
    os._exit(1)


def die_with_parent(parent: int) -> None:
    """Pool initializer: end this worker when the process ``parent`` ends."""
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            armed = libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)
    if not armed:
        threading.Thread(target=_watch_parent, args=(parent,), daemon=True).start()


def process_pool(n_jobs: int) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor of ``n_jobs`` workers that end with this process."""
    return ProcessPoolExecutor(max_workers=n_jobs, initializer=die_with_parent, initargs=(os.getpid(),))


def stop_pool(ex: ProcessPoolExecutor) -> None:
    """End a pool now: pending tasks cancelled, running workers terminated (a batch that stops on
    an error or an interrupt does not wait for chunks nobody will read)."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(5)


@contextlib.contextmanager
def folder_lock(out):
    """Hold an exclusive lock on the folder ``out`` (created if missing) for the ``with`` block;
    :class:`InputError` at once if another batch holds it."""
    import fcntl

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(
                f"{out}: another batch is writing to this folder now; wait for it to finish "
                "(a rerun then resumes) or choose another --out"
            ) from None
        yield
    finally:
        os.close(fd)
