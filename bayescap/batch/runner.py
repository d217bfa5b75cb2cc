"""A batch written to an output folder as it runs (``fit_many(..., out=DIR)``): chunks of sensors
as tasks, on this process, a local process pool or a Dask cluster, each chunk's results written
(:mod:`bayescap.batch.store`) as it finishes, and a rerun resuming.

**Tasks.** The sensors still to fit are sorted into groups that stack
(:func:`~bayescap.inference.lockstep.stack_groups`), each group cut into pieces and the pieces
packed into tasks of at most ``chunk_size`` sensors, smaller towards the end (:func:`_chunks`): a
task fits each of its pieces' fast paths in lockstep and returns, per sensor, its
fit JSON (``FitResult.to_dict()``: plain data, a few kB), its error, or, where the fast path
rejected its draws and ``fallback``, the fast path's diagnostics; each such sensor's MCMC fallback is
then a task of its own, so that the fallbacks, which take far longer than a fast path and fall
unevenly between chunks, go to whichever worker is free. The process that runs the batch writes
every ``result.json`` when its task returns: workers need no shared file system.

**Same numbers.** A sensor's result is its own ``bayescap.fit(data, seed=s, quality="fast")``
(lockstep evaluation is exact, :mod:`bayescap.batch.engine`), with ``s`` set by its position in the
batch: neither the runner, the number of workers, the chunk size nor the order tasks finish in
changes it. A task that is lost with its worker is run again by Dask (or, in the local pool, the
batch stops with the error; rerun it to resume).
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

import numpy as np

import bayescap.batch.store as store
from bayescap._blas import one_blas_thread
from bayescap.batch.engine import _Deferred, _fallback_fit, _fit_groups, sensor_seeds
from bayescap.batch.summary import write_summary
from bayescap.batch.workers import folder_lock, process_pool, stop_pool
from bayescap.inference import FastSettings

__all__ = ["fit_to_folder", "run_chunk", "run_fallback"]


def _error(e) -> dict:
    return {"error": f"{type(e).__name__}: {e}"}


@one_blas_thread
def run_chunk(task):
    """One task: ``(items, quality, settings, fallback, stack_size)`` with ``items`` a list of
    ``(index, model, seed)``, or a list of such lists, each of one stack group (a chunk packs the
    small groups of a batch whose sensors do not stack, e.g. tables of different lengths). Returns
    ``[(index, kind, value)]``: ``("doc", fit JSON)``, ``("error", message)`` or ``("deferred",
    fast-path diagnostics)``."""
    items, quality, settings, fallback, stack_size = task
    parts = items if items and isinstance(items[0], list) else [items]
    items = [it for part in parts for it in part]
    out = []
    if quality != "fast":
        from bayescap.api import fit

        for i, m, s in items:
            try:
                out.append((i, "doc", fit(m.data, seed=s, quality=quality).to_dict()))
            except Exception as e:  # one bad sensor must not stop a batch
                out.append((i, "error", _error(e)["error"]))
        return out
    models = [m for _, m, _ in items]
    seeds = [s for _, _, s in items]
    bounds = np.cumsum([0] + [len(part) for part in parts])
    groups = [list(range(a, b)) for a, b in zip(bounds[:-1], bounds[1:])]
    done = _fit_groups((models, seeds, groups, settings, fallback, False, stack_size, True))
    for k, (i, _, _) in enumerate(items):
        out.append((i, *_outcome(done[k])))
    return out


def _outcome(r):
    if isinstance(r, _Deferred):
        return "deferred", r.diag
    if isinstance(r, BaseException):
        return "error", _error(r)["error"]
    try:
        return "doc", r.to_dict()
    except Exception as e:  # a result that cannot be reported is this sensor's error
        return "error", _error(e)["error"]


@one_blas_thread
def run_fallback(task):
    """One sensor's MCMC fallback: ``(index, model, seed, fast-path diagnostics, settings)``."""
    i, m, seed, diag, settings = task
    return [(i, *_outcome(_fallback_fit((m, seed, diag, settings, False))))]


class _Inline:
    """Tasks run in this process, one at a time, when asked for (``n_jobs=1``, no client)."""

    def __init__(self):
        self.queue = []

    def submit(self, fn, arg):
        self.queue.append((fn, arg))
        return len(self.queue) - 1

    def completed(self):
        while self.queue:
            fn, arg = self.queue.pop(0)
            yield fn(arg)

    def close(self, cancel=False):
        self.queue.clear()


class _Pool:
    """Tasks on a local process pool (``n_jobs > 1``)."""

    def __init__(self, n_jobs):
        self.ex = process_pool(n_jobs)  # workers end with this process (batch.workers)
        self.pending = set()

    def submit(self, fn, arg):
        f = self.ex.submit(fn, arg)
        self.pending.add(f)
        return f

    def completed(self):
        while self.pending:
            done, self.pending = wait(self.pending, return_when=FIRST_COMPLETED)
            for f in done:
                yield f.result()

    def close(self, cancel=False):
        if cancel:  # an error or an interrupt: nobody reads the running chunks
            stop_pool(self.ex)
        else:
            self.ex.shutdown(wait=True)


def _chunks(groups, chunk_size, n_workers):
    """The batch's tasks: each a list of pieces of stack groups, at most ``chunk_size`` sensors in
    all. A group larger than a task is cut into near-equal pieces; groups smaller than a task are
    packed together (sensors that do not stack, e.g. amplifier tables of 40–400 rows, are each a
    group of one: a task per sensor cost the Dask run of 256 focal-plane tables a quarter more time
    than the local pool). The tasks shrink towards the end of the batch (guided scheduling: each
    about the sensors left over four per worker, down to 8), so that the last ones do not leave
    workers idle while one finishes a large chunk; the tasks are submitted, and run, in order."""
    n = sum(len(g) for g in groups)
    size = max(1, int(chunk_size))
    workers = max(1, int(n_workers))
    cut = min(size, max(8, math.ceil(n / (4 * workers))))  # (at least four pieces a worker)
    pieces = []
    for g in groups:
        k = math.ceil(len(g) / cut)
        pieces.extend([g[round(j * len(g) / k) : round((j + 1) * len(g) / k)] for j in range(k)])
    out, task, in_task, left = [], [], 0, n
    for piece in pieces:
        want = min(size, max(min(8, size), math.ceil(left / (4 * workers))))
        if task and in_task + len(piece) > want:
            out.append(task)
            left -= in_task
            task, in_task = [], 0
        task.append(piece)
        in_task += len(piece)
    if task:
        out.append(task)
    return out


def fit_to_folder(
    datas,
    *,
    out,
    quality: str = "fast",
    seed,
    n_jobs: int = 1,
    fallback: bool = True,
    settings: FastSettings = FastSettings(),
    stack_size: int = 64,
    chunk_size: int = 128,
    client=None,
    progress: bool = False,
    on_chunk=None,
):
    """:func:`bayescap.batch.fit_many` with ``out``: see there and the module docstring. Returns one
    dict per input, in order: ``{"name", "status"}`` with status ``"fitted"`` (this run),
    ``"resumed"`` (found done in ``out``) or ``"error"`` (with ``"error"``: the message)."""
    with folder_lock(out):  # one batch per folder at a time (batch.workers)
        return _fit_to_folder(
            datas,
            out=out,
            quality=quality,
            seed=seed,
            n_jobs=n_jobs,
            fallback=fallback,
            settings=settings,
            stack_size=stack_size,
            chunk_size=chunk_size,
            client=client,
            progress=progress,
            on_chunk=on_chunk,
        )


def _write(args):
    """Write one sensor's result; its error message (one line) instead of raising."""
    out, name = args[0], args[1]
    try:
        store.write_result(*args)
        return None
    except (OSError, ValueError) as e:
        what = getattr(e, "strerror", None) or str(e)
        return f"cannot write {store.result_path(out, name)} ({what}); the other sensors go on"


def _fit_to_folder(
    datas, *, out, quality, seed, n_jobs, fallback, settings, stack_size, chunk_size, client, progress, on_chunk
):
    from bayescap.api import load
    from bayescap.inference.lockstep import stack_groups
    from bayescap.io.ptc_csv import PTCData
    from bayescap.model import PTCModel

    datas = list(datas)
    seeds = sensor_seeds(seed, len(datas))
    cfg = store.config_digest(quality, fallback, settings)
    loaded, report = [], [None] * len(datas)
    for i, d in enumerate(datas):
        try:
            loaded.append(d if isinstance(d, PTCData) else load(d))
        except Exception as e:  # one bad sensor must not stop a batch
            loaded.append(None)
            report[i] = _error(e)
    names = store.sensor_names([d.source if d is not None else datas[i] for i, d in enumerate(loaded)])
    entries, models = [None] * len(datas), [None] * len(datas)
    for i, d in enumerate(loaded):
        if d is None:
            continue
        entries[i] = store.batch_entry(seeds[i], store.data_digest(d), cfg)
        if store.is_done(out, names[i], entries[i]):
            report[i] = {"status": "resumed"}
            continue
        try:
            models[i] = PTCModel.for_fit(d)
        except Exception as e:
            report[i] = _error(e)
    for i, r in enumerate(report):
        if r is not None and "error" in r:
            report[i] = {"status": "error", **r}
    todo = [i for i, r in enumerate(report) if r is None]
    if client is not None:
        from bayescap.batch.cluster import DaskTasks

        tasks, n_workers = DaskTasks(client), max(1, len(client.scheduler_info().get("workers", {})))
    elif n_jobs > 1 and len(todo) > 1:
        tasks, n_workers = _Pool(n_jobs), n_jobs
    else:
        tasks, n_workers = _Inline(), 1
    groups = [ix for g in stack_groups(models) for ix in g]  # resumed and refused sensors have no model
    bar = None
    if progress and todo:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(todo), unit="sensor", desc="fit_many")
    stopped = True
    writers = ThreadPoolExecutor(max_workers=8)
    try:
        for chunk in _chunks(groups, chunk_size, n_workers):
            items = [[(i, models[i], seeds[i]) for i in piece] for piece in chunk]
            tasks.submit(run_chunk, (items, quality, settings, fallback, stack_size))
        for part in tasks.completed():
            n_done, docs = 0, []
            for i, kind, value in part:
                if kind == "deferred":
                    tasks.submit(run_fallback, (i, models[i], seeds[i], value, settings))
                    continue
                if kind == "doc":
                    docs.append((i, (out, names[i], value, entries[i])))
                    report[i] = {"status": "fitted"}
                else:
                    report[i] = {"status": "error", "error": value}
                models[i] = None  # done: its memory can go
                n_done += 1
            # the chunk's files on a few threads: each is fsync'd, which waits on the disk, not the CPU
            # a result that cannot be written (a full disk, a name the file system refuses, a
            # folder in the way) is that sensor's error: the batch goes on
            for (i, _), err in zip(docs, writers.map(_write, [a for _, a in docs])):
                if err is not None:
                    report[i] = {"status": "error", "error": err}
            if bar is not None:
                bar.update(n_done)
            if on_chunk is not None:
                on_chunk([i for i, kind, _ in part if kind != "deferred"])
        stopped = False
    finally:
        tasks.close(cancel=stopped)
        writers.shutdown()
        if bar is not None:
            bar.close()
    try:
        write_summary(out)  # DIR/summary.csv (+ .parquet): every result of the folder, one row each
    except OSError as e:  # a full disk after the results: they stand; the table can be rebuilt
        warnings.warn(
            f"{out}/summary.csv not written ({e.strerror or e}); 'bayescap summary {out}' rebuilds it", stacklevel=2
        )
    return [dict(name=n, **r) for n, r in zip(names, report)]
