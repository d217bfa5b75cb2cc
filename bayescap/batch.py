"""Many sensors at once with the fast path (issue 7): :func:`fit_many`, and the Gpixel
GSPRINT4521 per-ROI results turned into simulated photon-transfer data (:func:`gpixel_sensors`).

What is shared across sensors: the imports, the MTF (one per distinct metadata), the cached
Gauss–Legendre nodes and the PSIS smoothing. What is not: the log-posterior, which
:class:`bayescap.model.PTCModel` evaluates for one sensor per call, so the MAP, the Laplace
Hessian and the importance draws run per sensor; ``n_jobs > 1`` spreads sensors over processes.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .fast import FastSettings

__all__ = ["fit_many", "gpixel_truths", "gpixel_sensors", "GPIXEL_CSV"]

GPIXEL_CSV = Path(__file__).resolve().parents[1] / "data" / "gpixel_gsprint4521" / "roi_results.csv"


def _summary(res):
    dg = res.diag
    out = {"accepted": bool(dg.get("fast_path_accepted", dg.get("converged"))),   # the fast path's own check
           "converged": bool(dg.get("converged")),                                 # of the result returned
           "khat": dg.get("khat", dg.get("fast_path_khat")), "method": dg.get("method", "")}
    for n, x in res.draws.items():
        out[n] = tuple(float(v) for v in np.quantile(x, [0.025, 0.5, 0.975]))
    for n in ("capacity_bits", "capacity_bits_per_pixel"):
        if n in res.derived:
            out[n] = tuple(float(v) for v in np.quantile(res.derived[n], [0.025, 0.5, 0.975]))
    return out


def _mtf_key(md):
    return tuple(md.get(k) for k in ("fill_factor", "f_number", "wavelength_nm", "pixel_pitch_um"))


def _fit_chunk(args):
    datas, seeds, settings, fallback, summary_only = args
    from .api import fit, load, mtf_from_metadata
    from .ptc import PTCData

    mtfs, out = {}, []
    for d, s in zip(datas, seeds):
        try:
            d = d if isinstance(d, PTCData) else load(d)
            key = _mtf_key(d.metadata)
            if key not in mtfs:
                mtfs[key] = mtf_from_metadata(d.metadata)
            r = fit(d, seed=s, quality="fast", fast_settings=settings, mtf=mtfs[key], fallback=fallback)
        except Exception as e:  # one bad sensor must not stop a batch: report it
            out.append({"error": f"{type(e).__name__}: {e}"} if summary_only else e)
            continue
        out.append(_summary(r) if summary_only else r)
    return out


def fit_many(datas, *, quality: str = "fast", seed, n_jobs: int = 1, fallback: bool = True,
             settings: FastSettings = FastSettings(), summary_only: bool = False):
    """Fit many sensors with the Laplace–IS fast path (MCMC fallback per sensor if ``fallback``).

    Parameters
    ----------
    datas : sequence of PTCData (or contract CSV paths).
    quality : only ``"fast"`` is batched; other presets call :func:`bayescap.fit` per sensor.
    seed : base seed; sensor ``i`` uses an independent child of ``SeedSequence(seed)``.
    n_jobs : worker processes (1 = in this process).
    summary_only : return per-sensor dicts ``{name: (q2.5, q50, q97.5), "accepted", "converged",
        "khat", "method"}`` (``accepted``: the Laplace–IS check passed; ``converged``: the
        returned result, MCMC after a fallback, passed its checks)
        instead of :class:`~bayescap.posterior.FitResult` objects (smaller to pass between
        processes). A sensor whose input is refused gives ``{"error": message}`` (or the
        exception object when not ``summary_only``) instead of stopping the batch.
    """
    datas = list(datas)
    seeds = [int(c.generate_state(1)[0]) for c in np.random.SeedSequence(seed).spawn(len(datas))]
    if quality != "fast":
        import bayescap

        res = [bayescap.fit(d, seed=s, quality=quality) for d, s in zip(datas, seeds)]
        return [_summary(r) for r in res] if summary_only else res
    if n_jobs <= 1 or len(datas) < 2:
        return _fit_chunk((datas, seeds, settings, fallback, summary_only))
    from concurrent.futures import ProcessPoolExecutor

    n_chunks = min(len(datas), 4 * n_jobs)
    idx = np.array_split(np.arange(len(datas)), n_chunks)
    jobs = [([datas[i] for i in ix], [seeds[i] for i in ix], settings, fallback, summary_only) for ix in idx]
    with ProcessPoolExecutor(max_workers=n_jobs) as ex:
        parts = list(ex.map(_fit_chunk, jobs))
    return [r for p in parts for r in p]


def gpixel_truths(path=GPIXEL_CSV):
    """Sensor truths from the Gpixel GSPRINT4521 per-ROI results (one per ROI and gain).

    Truth = the measured conversion gain S (e⁻/DN), temporal dark noise (as read noise, e⁻) and
    full well (e⁻) of each ROI; 12-bit ADC ("12NOR" mode); QE 0.6, no dark current, PRNU 0.5 %
    (not in the table: assumed). Returns a list of ((roi_index, gain_index), SensorTruth)."""
    from .simulate import SensorTruth

    out = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            t = SensorTruth(conversion_gain_e_per_dn=float(row["S_e_per_DN"]),
                            read_noise_e=float(row["temporal_dark_noise_e"]),
                            full_well_e=float(row["full_well_e"]), quantum_efficiency=0.6,
                            prnu_frac=0.005, full_well_spread_frac=0.005, adc_bits=12)
            out.append(((int(row["roi_index"]), int(row["gain_index"])), t))
    return out


def gpixel_sensors(*, n_max=None, seed=0, shape=(32, 32), n_levels=30):
    """Simulated photon-transfer data for the Gpixel ROIs×gains: (list of PTCData, list of truths).

    Small frames (``shape``) keep the simulation of 1 024 sensors near a minute; every sensor
    gets its own seed (children of ``SeedSequence(seed)``)."""
    from .simulate import simulate_ptc

    tr = gpixel_truths()
    if n_max is not None:
        tr = tr[:n_max]
    kids = np.random.SeedSequence(seed).spawn(len(tr))
    datas = []
    for ((roi, g), t), k in zip(tr, kids):
        datas.append(simulate_ptc(t, n_levels=n_levels, shape=shape, seed=k,
                                  metadata={"sensor": f"Gpixel GSPRINT4521 ROI {roi} gain {g} (simulated)",
                                            "pixel_pitch_um": 4.5, "width_px": 5120, "height_px": 4096}))
    return datas, [t for _, t in tr]
