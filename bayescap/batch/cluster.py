"""The batch's tasks on a ``dask.distributed`` cluster (``fit_many(..., client=...)``,
``bayescap fit *.csv --out DIR --scheduler ADDRESS | --dask N``). Dask is an optional extra
(``pip install 'bayescap[dask]'``), imported only here and only when a cluster is asked for.

Every chunk is one task (:func:`bayescap.batch.runner.run_chunk`), submitted with its sensors'
models as arguments (a few kB a sensor), its result a list of plain dicts gathered back to the
client, which writes them. ``pure=False``: a task is never merged with another of the same
arguments. A worker that dies takes its running tasks with it; the scheduler runs them again on
another worker (up to ``distributed.scheduler.allowed-failures`` times, 3 by default), and the
client sees each task finish once.
"""

from __future__ import annotations

from bayescap._heap import MMAP_THRESHOLD_BYTES, TRIM_THRESHOLD_BYTES
from bayescap.exceptions import InputError

__all__ = [
    "DASK_HINT",
    "QUIET_CLUSTER",
    "WORKER_MALLOC_ENV",
    "DaskTasks",
    "import_distributed",
    "local_cluster",
    "start_client",
]

#: glibc's malloc thresholds for a worker process, as :func:`bayescap.retain_freed_memory` sets them
#: in this one. A Dask nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``
#: (``distributed.nanny.pre-spawn-environ``), which hands every freed ``log_prob`` temporary back to
#: the kernel: the batch's fits then take about 1.5x as long. A cluster bayescap starts gets these
#: instead; for a cluster of your own, set them in that configuration key (docs/batch.md).
WORKER_MALLOC_ENV = {
    "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD_BYTES),
    "MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD_BYTES),
}

#: the background work of a cluster that a batch of fits does not use: the workers' statistical
#: profiler (a stack sample every 10 ms, for the dashboard's Profile page) and the event loops'
#: health ticks (every 20 ms). Left on, an idle 2-worker cluster uses ~0.23 of a core (4.6 CPU-s per
#: 20 s), ~8 % of a 2-core focal-plane batch; with these ~0.06. The dashboard's task stream and
#: worker pages are unchanged; a cluster the user starts (``--scheduler``) keeps its own settings.
QUIET_CLUSTER = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "500ms"}

DASK_HINT = "a Dask cluster needs dask.distributed: pip install 'bayescap[dask]'"


def import_distributed():
    """``distributed``, or :class:`~bayescap.exceptions.InputError` with the install hint."""
    try:
        import distributed
    except ImportError:
        raise InputError(DASK_HINT) from None
    return distributed


class DaskTasks:
    """The runner's task interface (``submit``, ``completed``, ``close``) on a Dask client."""

    def __init__(self, client):
        distributed = import_distributed()
        self.client = client
        self.done = distributed.as_completed()

    def submit(self, fn, arg):
        fut = self.client.submit(fn, arg, pure=False)
        self.done.add(fut)
        return fut

    def completed(self):
        for fut in self.done:  # futures added while iterating are waited for too
            yield fut.result()

    def close(self, cancel=False):
        if cancel:
            futs = list(self.done.futures)
            self.done.clear()
            if futs:
                self.client.cancel(futs)


def start_client(scheduler=None, n_workers=None):
    """A client of the scheduler at ``scheduler``, or of a new ``LocalCluster`` of ``n_workers``
    single-threaded worker processes; returns ``(client, cluster or None)``."""
    distributed = import_distributed()
    if scheduler is not None:
        try:
            return distributed.Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError, ValueError) as e:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({type(e).__name__}: {e})") from None
    cluster = local_cluster(int(n_workers))
    return distributed.Client(cluster), cluster


def local_cluster(n_workers: int):
    """A ``LocalCluster`` of ``n_workers`` single-threaded worker processes whose malloc keeps freed
    temporaries (:data:`WORKER_MALLOC_ENV`), without the profiler and fast ticks
    (:data:`QUIET_CLUSTER`)."""
    import dask

    distributed = import_distributed()
    environ = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **WORKER_MALLOC_ENV}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ, **QUIET_CLUSTER}):
        # each nanny also gets the quiet settings as its own configuration, which it hands to every
        # worker process it starts: a worker restarted after the first died read the defaults again
        return distributed.LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",
            config=dict(QUIET_CLUSTER),
        )
