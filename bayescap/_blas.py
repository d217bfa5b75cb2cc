"""BLAS worker threads held to one while bayescap samples.

NumPy's OpenBLAS runs a matrix product on all cores once it exceeds ~2.6·10⁵ multiply-adds: the
Student-t draws of the fast path (a few thousand draws × D, times a D×D factor) are just above
that. After such a call its worker threads spin, waiting for more work, for a while (OpenBLAS's
thread timeout), on the core that :func:`bayescap.model.threads._split_rows` hands the second half
of a large ``log_prob`` call to: on the bundled Basler CCD that call then took as long as on one
thread (2 900 draws, 23 ms against 15 ms when no BLAS thread spins), and the whole fast path
~10 % longer (docs/performance.md, "Processes, threads and memory"). bayescap's matrices are D×D with D ≤ 14,
so a second BLAS thread never pays for itself here.

:func:`one_blas_thread` is a decorator that limits the BLAS libraries threadpoolctl finds to one
thread for the duration of a call (restoring the caller's setting afterwards; nested calls are
cheap, ~20 µs). Without threadpoolctl it does nothing. The setting is the process's, not the
thread's: two fits started concurrently from two threads of one process can restore each other's
saved value in the wrong order and leave BLAS at one thread afterwards (speed only, never numbers).
"""

from __future__ import annotations

import functools

_CONTROLLER = []  # [ThreadpoolController], made at the first call (~1.5 ms; threadpoolctl ~17 ms to import)


def _controller():
    if not _CONTROLLER:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # an optional speed-up: without it, BLAS keeps its own setting
            _CONTROLLER.append(None)
        else:
            _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0]


def one_blas_thread(fn):
    """Run ``fn`` with the BLAS thread pools limited to one thread (module docstring)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        ctl = _controller()
        if ctl is None:
            return fn(*args, **kwargs)
        with ctl.limit(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
