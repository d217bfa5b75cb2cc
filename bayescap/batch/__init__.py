"""Many sensors at once (docs/batch.md): :func:`fit_many`, vectorised across sensors, in this
process, a local process pool or on a ``dask.distributed`` cluster; with ``out`` every result is
written as its chunk finishes and a rerun resumes. Also the Gpixel GSPRINT4521 ROIs as simulated
photon-transfer data (:func:`gpixel_sensors`).

Modules: :mod:`~bayescap.batch.engine` (the lockstep fast paths, results in memory),
:mod:`~bayescap.batch.runner` (chunks as tasks, written as they finish), :mod:`~bayescap.batch.store`
(the output folder and resume key), :mod:`~bayescap.batch.cluster` (Dask, optional),
:mod:`~bayescap.batch.gpixel`.
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Sequence

from bayescap._blas import one_blas_thread
from bayescap.batch.engine import _summary, fit_in_memory, sensor_seeds
from bayescap.batch.gpixel import GPIXEL_CSV, gpixel_sensors, gpixel_truths
from bayescap.exceptions import InputError
from bayescap.inference import FastSettings
from bayescap.io.ptc_csv import PTCData

__all__ = ["fit_many", "gpixel_truths", "gpixel_sensors", "GPIXEL_CSV", "sensor_seeds", "_summary"]


@one_blas_thread
def fit_many(
    datas: Sequence[PTCData | str | os.PathLike],
    *,
    quality: str = "fast",
    seed: int,
    n_jobs: int = 1,
    fallback: bool = True,
    settings: FastSettings = FastSettings(),
    summary_only: bool = False,
    stack_size: int = 64,
    out: str | os.PathLike | None = None,
    client=None,
    chunk_size: int = 128,
    progress: bool = False,
) -> list:
    """Fit many sensors with the Laplace–IS fast path (MCMC fallback per sensor if ``fallback``),
    vectorised across sensors (:mod:`bayescap.batch.engine`).

    Parameters
    ----------
    datas : sequence of PTCData (or contract CSV paths).
    quality : only ``"fast"`` is batched; other presets call :func:`bayescap.fit` per sensor.
    seed : base seed; sensor ``i`` uses an independent child of ``SeedSequence(seed)``
        (:func:`sensor_seeds`), and its result is ``bayescap.fit(data_i, seed=child_i,
        quality="fast")``'s whatever the batch, ``stack_size``, ``n_jobs``, ``chunk_size`` or ``client``.
    n_jobs : worker processes on this machine (1 = in this process).
    stack_size : at most this many sensors in lockstep (1: one at a time, no stacking).
    summary_only : (without ``out``) return per-sensor dicts ``{name: (q2.5, q50, q97.5),
        "accepted", "converged", "khat", "method"}`` (``accepted``: the Laplace–IS check passed;
        ``converged``: the returned result, MCMC after a fallback, passed its checks;
        ``imprecise_interval_ends`` where the result flags it,
        :data:`bayescap.posterior.IMPRECISE_END_MCSE`) instead of
        :class:`~bayescap.posterior.FitResult` objects. A sensor whose input is refused gives
        ``{"error": message}`` (or the exception object when not ``summary_only``) instead of
        stopping the batch.
    out : a folder: each sensor's fit JSON is written to ``out/<name>/result.json`` as its chunk
        finishes (:mod:`bayescap.batch.store`), sensors already there with the same seed, data and
        settings are skipped, and the return value is one ``{"name", "status"}`` dict per input
        (status ``"fitted"``, ``"resumed"`` or ``"error"`` with ``"error"``) instead of the results:
        read them from the folder.
    client : a ``dask.distributed.Client``: run the chunks on its cluster (needs ``out``;
        ``n_jobs`` is then unused). Dask is optional: ``pip install 'bayescap[dask]'``.
    chunk_size : (with ``out``) at most this many sensors per task; smaller where a batch would
        have fewer than four tasks per worker (:mod:`bayescap.batch.runner`).
    progress : (with ``out``) a progress bar of sensors done.
    """
    if client is not None and out is None:
        raise InputError("fit_many(client=...) writes its results as they finish: give out=<folder>")
    for name, v in (("n_jobs", n_jobs), ("stack_size", stack_size), ("chunk_size", chunk_size)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 1:
            raise InputError(f"fit_many: {name} must be a whole number >= 1, got {v!r}")
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise InputError(f"fit_many: seed must be a whole number >= 0 (the batch's seeds derive from it), got {seed!r}")
    if not isinstance(settings, FastSettings):
        raise InputError(f"fit_many: settings must be a FastSettings, got {type(settings).__name__}")
    if out is None:
        return fit_in_memory(
            datas,
            quality=quality,
            seed=seed,
            n_jobs=n_jobs,
            fallback=fallback,
            settings=settings,
            summary_only=summary_only,
            stack_size=stack_size,
        )
    from bayescap.batch.runner import fit_to_folder

    return fit_to_folder(
        datas,
        out=out,
        quality=quality,
        seed=seed,
        n_jobs=max(1, int(n_jobs)),
        fallback=fallback,
        settings=settings,
        stack_size=max(1, int(stack_size)),
        chunk_size=chunk_size,
        client=client,
        progress=progress,
    )
