"""How many threads and processes a fit may use (:func:`n_threads`, :func:`_allowed`), and the
split of a large ``log_prob`` call into two halves, the second on a worker thread
(:func:`_split_rows`).
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["SPLIT_MIN_ELEMENTS", "n_threads"]

#: a :meth:`PTCModel.log_prob` call of this many draws × observations or more (and ≥ 1 000 draws)
#: is evaluated in two halves, one of them on a second thread (numpy's ufuncs release the GIL).
#: Measured on this project's 2-core VM, a call alone: Basler CCD (133 observations a draw) 4 000
#: draws 29.0 → 18.2 ms, 2 000 15.7 → 12.5, 1 500 12.2 → 9.5, 933 7.4 → 7.1, 500 4.4 → 5.7; a
#: simulated Gpixel ROI (90) 2 000 draws 7.2 → 8.3 ms, slower: the hand-over costs ~1 ms.
#: Inside a fast fit the Basler's calls gained nothing
#: until OpenBLAS's spinning worker was held off (bayescap/_blas.py); since, two halves on two threads
#: against one: 1 000 draws 0.85, 2 000 0.73, 4 000 0.64.
SPLIT_MIN_ELEMENTS = 200_000

_SPLIT_POOL = {}


def _env_count(name):
    """The environment variable ``name`` as a count ≥ 1, or None when unset or not an integer."""
    env = os.environ.get(name)
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            pass
    return None


def _allowed(env_name, default_fn) -> int:
    """How many processes or threads a fit may use: the environment variable ``env_name`` if set;
    else 1 in a process started by :mod:`multiprocessing` (a pool worker, e.g. one of
    ``bayescap.batch.fit_many``'s: its siblings have the other cores); else ``default_fn()``."""
    env = _env_count(env_name)
    if env is not None:
        return env
    import multiprocessing as mp

    if mp.parent_process() is not None:
        return 1
    return default_fn()


def n_threads() -> int:
    """Threads a large ``log_prob`` call may use (:func:`_allowed`, ``BAYESCAP_THREADS``): 2 where this
    process may run on two cores or more."""

    def two_if_two_cores():
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not on Linux
            cores = os.cpu_count() or 1
        return 2 if cores >= 2 else 1

    return _allowed("BAYESCAP_THREADS", two_if_two_cores)


def _split_rows(fn, th):
    """``fn(th)`` for row-wise ``fn``, as ``fn`` of the first and of the second half of the rows,
    concatenated: the second half on a worker thread when :func:`n_threads` > 1, else after the
    first. The halves are the same whatever the thread count (and the number of cores), so the
    numbers are too. (A call's rows are not quite independent: :meth:`PTCModel.predict` skips clip
    rows that no draw of the call needs, which changes a value in its last bits; so a split call can
    differ from an unsplit one there, never from another split one.)"""
    k = th.shape[0] // 2
    if n_threads() < 2:
        return np.concatenate([fn(th[:k]), fn(th[k:])])
    import contextvars
    from concurrent.futures import ThreadPoolExecutor

    pid = os.getpid()
    pool = _SPLIT_POOL.get(pid)
    if pool is None:  # one per process: a pool inherited through fork has no thread
        _SPLIT_POOL.clear()
        pool = _SPLIT_POOL[pid] = ThreadPoolExecutor(1, thread_name_prefix="bayescap-log-prob")
    # the worker runs in a copy of this context: numpy's errstate (a context variable) goes with it
    fut = pool.submit(contextvars.copy_context().run, fn, th[k:])
    try:
        first = fn(th[:k])
    finally:
        second = fut.result()
    return np.concatenate([first, second])
