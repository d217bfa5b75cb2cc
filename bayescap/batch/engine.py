"""Many sensors at once with the fast path, in one process or a local process pool, every result
kept in memory: :func:`fit_in_memory` (behind :func:`bayescap.batch.fit_many`), and the tasks the
chunked runners share (:func:`_fit_groups`, :func:`_finish`).

**Vectorised across fits.** A fast-path fit makes ~200 ``log_prob`` calls, most on 1–50 points,
where a call costs ~0.6 ms whatever its size (17 points 0.7–0.8 ms, 1 000 points 6–8 ms).
:func:`fit_many` therefore runs the fast paths of up to ``stack_size`` sensors in lockstep: each
sensor's unchanged fast path (:func:`bayescap.inference.fast.fast_posterior`) runs in a greenlet whose model
hands its ``log_prob`` requests to a :class:`Lockstep` evaluator; once every running path is
waiting, all requests are evaluated in one :class:`bayescap.model.PTCModelStack` call and each
path resumes with its own values. Sensors stack when their models have the same structure
(:meth:`~bayescap.model.PTCModelStack.signature`; 200 simulated Gpixel ROIs form 4 groups); a
stacked call returns each sensor's ``log_prob`` bit for bit, so a sensor's result does not depend
on the batch, on ``stack_size`` or on ``n_jobs``. The paths take turns on one core: the gain is
the per-call overhead paid once per stacked call instead of once per sensor. ``n_jobs > 1`` shares
each group of stackable sensors out among processes.

What else is shared across sensors: the imports, the MTF (one per distinct metadata), the cached
Gauss–Legendre nodes. After the fast path, each sensor's result is built, and an MCMC fallback
run where the fast path rejected its draws, one sensor at a time (:func:`bayescap.api.fit` with
``fast_result``). With ``n_jobs > 1`` each fallback is a task of its own, handed to whichever process
is free once the process that rejected it has run its fast paths: the rejections fall unevenly between
the processes' shares (on the 1 000-ROI batch, 9 of one process's 501 sensors and 16 of the other's 499).
"""

from __future__ import annotations

import numpy as np

from bayescap._blas import one_blas_thread
from bayescap.inference import FastSettings
from bayescap.inference.lockstep import _fast_paths, stack_groups

__all__ = ["fit_in_memory", "sensor_seeds"]


def sensor_seeds(seed, n):
    """The seeds :func:`fit_many` gives ``n`` sensors: sensor ``i`` gets the ``i``-th child of
    ``SeedSequence(seed)``, whatever the batch's size beyond ``i``, its order of fitting or processes."""
    return [int(c.generate_state(1)[0]) for c in np.random.SeedSequence(seed).spawn(n)]


def _summary(res):
    dg = res.diag
    out = {
        "accepted": bool(dg.get("fast_path_accepted", dg.get("converged"))),  # the fast path's own check
        "converged": bool(dg.get("converged")),  # of the result returned
        "khat": dg.get("khat", dg.get("fast_path_khat")),
        "method": dg.get("method", ""),
    }
    if not out["accepted"]:
        # why the fast path refused (its reason; with the fallback, the reason it fell back)
        out["reason"] = dg.get("fallback_reason") or "; ".join(dg.get("failed_checks") or [])
    if res.flags.get("imprecise_interval_ends"):
        # an MCMC result (the fallback) whose interval ends' Monte Carlo error is above 0.1 of the width
        out["imprecise_interval_ends"] = dict(res.flags["imprecise_interval_ends"])
    n_prop = dg.get("n_proposals")
    if n_prop is not None and dg.get("method") == "laplace-is":
        out["n_proposals"] = int(n_prop)
    for n, x in res.draws.items():
        out[n] = tuple(float(v) for v in np.quantile(x, [0.025, 0.5, 0.975]))
    for n in ("capacity_bits", "capacity_bits_per_pixel"):
        if n in res.derived:
            out[n] = tuple(float(v) for v in np.quantile(res.derived[n], [0.025, 0.5, 0.975]))
    return out


def _mtf_key(md):
    return tuple(md.get(k) for k in ("fill_factor", "f_number", "wavelength_nm", "pixel_pitch_um"))


class _Deferred:
    """A sensor whose fast path was rejected, its MCMC fallback left for later (:func:`fit_many`
    with ``n_jobs > 1``): the fast path's diagnostics, all the fallback needs of it."""

    def __init__(self, diag):
        self.diag = diag


def _mtf_cache():
    mtfs = {}

    def mtf_of(m):
        from bayescap.api import mtf_from_metadata

        key = _mtf_key(m.data.metadata)
        if key not in mtfs:
            mtfs[key] = mtf_from_metadata(m.data.metadata)
        return mtfs[key]

    return mtf_of


def _finish(m, seed, settings, mtf, fallback, fast_result, summary_only):
    """``bayescap.fit`` of one sensor from its fast path's result (the MCMC fallback where it was
    rejected and ``fallback``): the result, its summary, or the error it raised (one bad sensor must
    not stop a batch)."""
    from bayescap.api import fit

    try:
        if isinstance(fast_result, BaseException):
            raise fast_result
        r = fit(
            m, seed=seed, quality="fast", fast_settings=settings, mtf=mtf, fallback=fallback, fast_result=fast_result
        )
    except Exception as e:
        return {"error": f"{type(e).__name__}: {e}"} if summary_only else e
    return _summary(r) if summary_only else r


def _fallback_fit(args):
    """A deferred MCMC fallback: (model, seed, the fast path's diagnostics, settings, summary_only)."""
    m, seed, diag, settings, summary_only = args
    return _finish(m, seed, settings, _mtf_cache()(m), True, (None, diag), summary_only)


def _fit_groups(args):
    models, seeds, groups, settings, fallback, summary_only, stack_size, defer = args
    from bayescap.api import _result_kw
    from bayescap.posterior import FitResult

    mtf_of, out = _mtf_cache(), {}

    for ix in groups:
        dfs = None
        if settings.end_mcse_max is not None:
            # the gate's top-up covers the derived quantities, as bayescap.fit's fast path does
            dfs = []
            for i in ix:
                try:
                    dfs.append(
                        FitResult.derived_values_fn(
                            models[i], **_result_kw(models[i].data, mtf=mtf_of(models[i]), scene=None, seed=seeds[i])
                        )
                    )
                except Exception:  # reported by fit() below, as without the gate
                    dfs.append(None)
        fast = _fast_paths([models[i] for i in ix], [seeds[i] for i in ix], settings, stack_size, dfs)
        for i, fr in zip(ix, fast):
            if defer and fallback and isinstance(fr, tuple) and not fr[1]["accepted"]:
                out[i] = _Deferred(fr[1])
            else:
                out[i] = _finish(models[i], seeds[i], settings, mtf_of(models[i]), fallback, fr, summary_only)
    return out


@one_blas_thread
def fit_in_memory(
    datas,
    *,
    quality: str = "fast",
    seed,
    n_jobs: int = 1,
    fallback: bool = True,
    settings: FastSettings = FastSettings(),
    summary_only: bool = False,
    stack_size: int = 64,
):
    """:func:`bayescap.batch.fit_many` without an output folder: every result kept in memory and
    returned at the end. Fit many sensors with the Laplace–IS fast path (MCMC fallback per sensor if
    ``fallback``), vectorised across sensors (module docstring).

    Parameters
    ----------
    datas : sequence of PTCData (or contract CSV paths).
    quality : only ``"fast"`` is batched; other presets call :func:`bayescap.fit` per sensor.
    seed : base seed; sensor ``i`` uses an independent child of ``SeedSequence(seed)``, and its
        result is ``bayescap.fit(data_i, seed=child_i, quality="fast")``'s whatever the batch,
        ``stack_size`` or ``n_jobs``.
    n_jobs : worker processes (1 = in this process); each group of stackable sensors is shared
        out among them.
    stack_size : at most this many sensors in lockstep (1: one at a time, no stacking).
    summary_only : return per-sensor dicts ``{name: (q2.5, q50, q97.5), "accepted", "converged",
        "khat", "method"}`` (``accepted``: the Laplace–IS check passed; ``converged``: the
        returned result, MCMC after a fallback, passed its checks; ``imprecise_interval_ends`` where the
        result flags it, :data:`bayescap.posterior.IMPRECISE_END_MCSE`)
        instead of :class:`~bayescap.posterior.FitResult` objects (smaller to pass between
        processes). A sensor whose input is refused gives ``{"error": message}`` (or the
        exception object when not ``summary_only``) instead of stopping the batch.
    """
    datas = list(datas)
    seeds = sensor_seeds(seed, len(datas))
    if quality != "fast":
        import bayescap

        res = []
        for d, s in zip(datas, seeds):
            try:
                r = bayescap.fit(d, seed=s, quality=quality)
            except Exception as e:  # one bad sensor must not stop a batch: report it
                res.append({"error": f"{type(e).__name__}: {e}"} if summary_only else e)
                continue
            res.append(_summary(r) if summary_only else r)
        return res
    from bayescap.api import load
    from bayescap.io.ptc_csv import PTCData
    from bayescap.model import PTCModel

    models, out = [], [None] * len(datas)
    for i, d in enumerate(datas):
        try:
            models.append(PTCModel.for_fit(d if isinstance(d, PTCData) else load(d)))
        except Exception as e:  # one bad sensor must not stop a batch: report it
            models.append(None)
            out[i] = {"error": f"{type(e).__name__}: {e}"} if summary_only else e
    n_jobs = max(1, int(n_jobs))
    parts = stack_groups(models, n_jobs)  # [group][part] -> indices
    stack_size = max(1, int(stack_size))
    if n_jobs == 1 or sum(len(g) for g in parts) < 2:
        done = _fit_groups(
            (models, seeds, [ix for g in parts for ix in g], settings, fallback, summary_only, stack_size, False)
        )
    else:
        from concurrent.futures import as_completed

        from bayescap.batch.workers import process_pool

        # process w gets part w of every group, and only those models
        shares = [[g[w] for g in parts if w < len(g)] for w in range(n_jobs)]
        jobs = []
        for share in shares:
            ids = {i for ix in share for i in ix}
            sub = [models[i] if i in ids else None for i in range(len(models))]
            jobs.append((sub, seeds, share, settings, fallback, summary_only, stack_size, True))
        done = {}
        with process_pool(n_jobs) as ex:  # workers end with this process
            # each fallback is a task of its own, submitted as soon as the process that rejected it
            # returns: whichever process is free takes it (the fast paths' rejections fall unevenly
            # between the processes' shares, and the first process done would otherwise idle)
            firsts = [ex.submit(_fit_groups, j) for j in jobs]
            fallbacks = []
            for fut in as_completed(firsts):
                part = fut.result()
                done.update(part)
                for i in sorted(i for i, r in part.items() if isinstance(r, _Deferred)):
                    fallbacks.append(
                        (i, ex.submit(_fallback_fit, (models[i], seeds[i], part[i].diag, settings, summary_only)))
                    )
            for i, fut in fallbacks:
                done[i] = fut.result()
    for i, r in done.items():
        out[i] = r
    return out
