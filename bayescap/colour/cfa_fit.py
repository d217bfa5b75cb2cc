"""The four Bayer channels R, Gr, Gb, B of one sensor, fitted as one readout chain.

The four colour planes of a Bayer sensor share one readout chain: the same conversion gain ``K``,
read noise, dark current and clip level (ADC maximum or full well). What each plane owns is its
photon response (the colour filter times the quantum efficiency, which only scales the signal
reached at a given exposure), its PRNU and DSNU, the spread of its pixels' clip points, its
variance discrepancy and its response non-linearity.

**How the channels are combined: per-channel fits and a Gaussian consensus.** Each channel is
fitted alone by the single-channel fit (:func:`bayescap.fit`, the same model, likelihood and
sampler, seeded by the channel's child of :func:`bayescap.batch.sensor_seeds`). These are the
*separate fits*, reported beside the joint one. At ``fast`` the fast path's top-up and its gate on
the interval ends' Monte Carlo error judge the parameters this fit reports
(:data:`REPORTED_PARAMETERS`, :func:`channel_fast_settings`), not the monochrome derived quantities
(capacity, TR, DR, SNR at the channel's scene), which the colour result does not use and the
channel's result still checks: ~0.65 of a monochrome fast fit's CPU time each. The four run one
after the other in this process, a channel's MCMC ensembles in lockstep; ``n_jobs`` (or
``BAYESCAP_JOBS``) > 1 shares them out among worker processes, which shortens the wall time on
idle cores but costs CPU time (a worker's start, and the cores' contention: at ``standard`` 2.8×
the monochrome fit's CPU time in one process against 3.0× in two on the project's shared 2-core
VM, ``benchmarks/colour_cfa_speed.py``); the numbers do not depend on the process count.
Stacking the channels' ``log_prob`` calls gains nothing (their tables differ in their clip rows,
so at most Gr and Gb stack, and the fast path's calls are large). Nor
does starting R, Gb and B at the Gr fit's MAP (``benchmarks/colour_warm_start.py``): the MAP is
~15 % of a fast channel fit, and Newton from the Gr MAP took as many ``log_prob`` calls as from
each channel's own data-derived guess (141-264 against 147 over 12 channel fits).
The *joint* posterior of the shared coordinates (``log K``, ``log σ_read``, ``log D``, the clip
level in DN) is the product of the channels' marginal posteriors with the prior counted once,

    p(θ_s | all) ∝ Π_c p_c(θ_s) / π(θ_s)^(C_s − 1)        (C_s: channels that have coordinate s)

evaluated with each marginal's Gaussian approximation (mean and covariance of the channel's
draws in the sampling coordinates, where these marginals are close to normal with 10⁴–10⁶ pixels
per row) and the log prior's gradient at the consensus (a linearisation). Each channel's own
coordinates follow the shared ones by their conditional given them (linear-Gaussian transport of
the channel's draws: ``θ_own + B_c (θ_s' − θ_s)``, ``B_c = Cov(own, s) Cov(s)⁻¹``). A clip level
that only some channels reach (a blue plane that never saturates) comes from those channels, and
the others take it: the ADC and the readout clip every plane at the same DN.

The exact joint log-probability over the four tables (``JointCFAModel``: the four models'
densities with the shared coordinates tied) checks the consensus: its mode's K and read noise lie
within half a consensus sd of the consensus (tests/test_cfa.py). Sampling it directly was tried:
importance sampling from a Student-t around its Laplace fit failed the Pareto-k̂ check on a
simulated sensor (k̂ = 1.18 in ~35 dimensions; each channel's plain Laplace-IS failed there too,
without the fast path's coordinates and mixture); MCMC in those dimensions was not tried within the
time budget. Hence the consensus, which reuses the fast path's checked per-channel posteriors.

**The K check.** The separate fits' conversion gains must agree: digital per-channel scaling
inside the RAW, crosstalk between neighbours or a wrong black level make them disagree, and then
a shared ``K`` describes none of the channels. The check is a χ² of the four log K about their
precision-weighted mean (3 degrees of freedom) with the largest ratio between channels; it fails
when the p-value is below :data:`K_CHECK_P_MIN`, and then the separate fits are the ones to read.
The same χ² is reported for every shared coordinate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from bayescap.colour.agreement import K_CHECK_P_MIN, chi2_check
from bayescap.colour.agreement import k_check as _k_check
from bayescap.io.ptc_csv import PTCData
from bayescap.model.ptc_model import PTCModel
from bayescap.posterior import summarize

__all__ = ["CFA_CHANNELS", "SHARED_COORDS", "K_CHECK_P_MIN", "JointCFAModel", "CFAFit", "fit_cfa"]

CFA_CHANNELS = ("R", "Gr", "Gb", "B")
#: coordinates of :class:`PTCModel` that the four channels share
SHARED_COORDS = ("log_k", "log_read", "log_dark_noise", "log_dc", "clip_dn")
#: the physical parameter of each shared coordinate
SHARED_NAMES = {
    "log_k": "conversion_gain_e_per_dn",
    "log_read": "read_noise_e",
    "log_dark_noise": "dark_noise_e",
    "log_dc": "dark_current_e_per_s",
    "clip_dn": "clip_dn",
}
#: CS is computed on at most this many of the joint draws (exactly on 128 of them, by a checked linear
#: map of the draws' inputs on all: bayescap.colour.cs_emulator), with this many Gauss-Legendre nodes
#: per axis over the full raw cube (a smooth integrand: 24 nodes differ from 96 by < 2e-6 bits) and
#: where the domain is cut (clipping after M, a reflectance cone: the cut is not smooth in the
#: quadrature's plane; 40 nodes differ from 128 by < 4e-3 bits, a few per cent of a CS interval's width)
CS_DRAWS = 1000
CS_GRID = 24
CS_GRID_CUT = 40

_PARAMETER_UNITS = {
    "conversion_gain_e_per_dn": "e-/DN",
    "read_noise_e": "e-",
    "dark_noise_e": "e-",
    "dark_current_e_per_s": "e-/s",
    "full_well_e": "e-",
    "clip_dn": "DN",
    "prnu_percent": "%",
    "dsnu_e": "e-",
    "quantum_efficiency": "",
}
#: the parameters the colour fit reports per channel: what a channel fit's interval ends are judged on
REPORTED_PARAMETERS = tuple(_PARAMETER_UNITS)


class JointCFAModel:
    """The joint log density of the channels' models with the shared coordinates tied:
    ``Σ_c log p_c(θ_c) − (C − 1) log π(θ_shared)`` (coordinates every model has are tied)."""

    def __init__(self, models: list[PTCModel], shared=SHARED_COORDS):
        self.models = models
        self.shared = [c for c in shared if all(c in m.idx for m in models)]
        self.own = [[n for n in m.names if n not in self.shared] for m in models]
        self.ndim = len(self.shared) + sum(len(o) for o in self.own)
        starts = np.cumsum([len(self.shared)] + [len(o) for o in self.own])
        self.slices = [slice(a, b) for a, b in zip(starts[:-1], starts[1:])]
        self.ref_shared = None

    def columns(self, i: int) -> list[int]:
        """Joint coordinate index of each coordinate of channel ``i``'s model."""
        m, own, sl = self.models[i], self.own[i], self.slices[i]
        return [self.shared.index(n) if n in self.shared else sl.start + own.index(n) for n in m.names]

    def split(self, x) -> list[np.ndarray]:
        """Channel-wise coordinate arrays ``(n, ndim_c)`` of joint draws ``x`` ``(n, ndim)``."""
        x = np.atleast_2d(np.asarray(x, float))
        return [x[:, self.columns(i)] for i in range(len(self.models))]

    def log_prob(self, x):
        thetas = self.split(x)
        lp = sum(m.log_prob(th) for m, th in zip(self.models, thetas))
        if len(self.models) > 1 and self.shared:
            m, th0 = self.models[0], thetas[0]
            ref = th0.copy()
            for j, c in enumerate(self.shared):
                ref[:, m.idx[c]] = self.ref_shared[j]
            with np.errstate(invalid="ignore"):
                lp = lp - (len(self.models) - 1) * (m.log_prior(th0) - m.log_prior(ref))
        return np.where(np.isfinite(lp), lp, -np.inf)


@dataclass
class CFAFit:
    """The joint fit of the four channels and the separate fits beside it.

    ``draws[c]`` and ``separate[c]``: channel c's physical parameters (``PTCModel.physical``
    names), equal-weight draws of the joint (consensus) and of the separate posterior.
    ``black_dn[c]`` the channel's dark level (DN) that signals are counted from; ``adc_max_dn``
    the ADC maximum; ``results[c]`` the separate :class:`~bayescap.posterior.FitResult`.
    """

    channels: tuple
    shared: list
    draws: dict
    separate: dict
    k_check: dict
    consistency: dict
    black_dn: dict
    adc_max_dn: float | None
    converged: bool
    quality: str
    seed: int
    seconds: float
    results: dict = field(default_factory=dict, repr=False)
    #: ``results[c].parameter_summary()`` of each channel, computed once
    summaries: dict = field(default_factory=dict, repr=False)
    notes: list = field(default_factory=list)

    @property
    def n_draws(self) -> int:
        return int(next(iter(self.draws.values()))["conversion_gain_e_per_dn"].size)

    def clip_signal_dn(self) -> np.ndarray:
        """Per draw and channel, the signal (DN above the channel's dark level) where the pixel
        values clip: (n_draws, 4). Without a fitted clip, the ADC maximum (a bound, noted)."""
        out = np.empty((self.n_draws, len(self.channels)))
        for j, c in enumerate(self.channels):
            d = self.draws[c]
            top = d["clip_dn"] if "clip_dn" in d else np.full(self.n_draws, self.adc_max_dn or np.nan)
            out[:, j] = top - self.black_dn[c]
        return out

    def var_coeffs_dn2(self, exposure_time_s: float) -> np.ndarray:
        """Per draw and channel the noise σ²(S) = c0 + c1·S + c2·S² (DN², S in DN above dark) at
        ``exposure_time_s``: c0 = (σ_read² + D·t + DSNU²)/K² + 1/12, c1 = 1/K, c2 = PRNU². Shape
        (n_draws, 4, 3), channels in :attr:`channels` order: Eq. 1 in DN, the monochrome fit's
        noise coefficients (``FitResult._noise_coefficients``; the fixed patterns count as noise)."""
        out = np.empty((self.n_draws, len(self.channels), 3))
        for j, c in enumerate(self.channels):
            d = self.draws[c]
            k = d["conversion_gain_e_per_dn"]
            if "read_noise_e" in d:
                dark_e2 = d["read_noise_e"] ** 2 + d.get("dark_current_e_per_s", 0.0) * float(exposure_time_s)
            else:
                dark_e2 = d["dark_noise_e"] ** 2
            if "dsnu_e" in d:
                dark_e2 = dark_e2 + d["dsnu_e"] ** 2
            prnu = d["prnu_percent"] / 100.0 if "prnu_percent" in d else np.zeros(self.n_draws)
            out[:, j, 0] = dark_e2 / k**2 + 1.0 / 12.0
            out[:, j, 1] = 1.0 / k
            out[:, j, 2] = prnu**2
        return out

    def to_dict(self) -> dict:
        def block(draws):
            return {
                c: {n: summarize(v, _PARAMETER_UNITS[n]) for n, v in draws[c].items() if n in _PARAMETER_UNITS}
                for c in self.channels
            }

        first = self.draws[self.channels[0]]
        shared = {
            SHARED_NAMES[c]: summarize(first[SHARED_NAMES[c]], _PARAMETER_UNITS[SHARED_NAMES[c]]) for c in self.shared
        }
        return {
            "fit": "per-channel fits with a Gaussian consensus of the shared readout parameters ("
            + ", ".join(SHARED_NAMES[c] for c in self.shared)
            + ")",
            "channels": list(self.channels),
            "converged": self.converged,
            "quality": self.quality,
            "seed": self.seed,
            "seconds": self.seconds,
            "shared": shared,
            "joint": block(self.draws),
            "separate": {
                c: {
                    n: v
                    for n, v in (self.summaries.get(c) or self.results[c].parameter_summary()).items()
                    if n in _PARAMETER_UNITS
                }
                for c in self.channels
            }
            if self.results
            else block(self.separate),
            "separate_converged": {c: bool(r.diag.get("converged")) for c, r in self.results.items()},
            # each channel fit's own caveats (rows, shape, fallbacks, limits), as its monochrome fit reports them
            "separate_notes": {c: list(r.notes) for c, r in self.results.items()},
            "separate_flags": {c: dict(r.flags) for c, r in self.results.items()},
            "k_check": dict(self.k_check),
            "consistency": dict(self.consistency),
            "notes": list(self.notes),
        }


def channel_fast_settings():
    """A channel fit's fast-path settings: the defaults, the top-up and the interval-end gate judging
    :data:`REPORTED_PARAMETERS` (``FastSettings.end_parameters``; module docstring)."""
    from bayescap.inference import FastSettings

    return FastSettings(end_parameters=REPORTED_PARAMETERS)


def _fit_channel(args, n_jobs=None):
    """``bayescap.fit(data, seed=seed, quality=quality)`` of one channel (at ``fast`` with
    :func:`channel_fast_settings`; ``n_jobs``: its MCMC ensembles' processes) and its
    ``parameter_summary()`` (computed where the fit ran: in a worker, beside this process's fits)."""
    from bayescap.api import fit

    data, seed, quality = args
    fs = channel_fast_settings() if quality == "fast" else None
    res = fit(data, seed=seed, quality=quality, n_jobs=n_jobs, fast_settings=fs)
    return res, res.parameter_summary()


def _channel_jobs(n_jobs, n_channels: int) -> int:
    """Processes for the channel fits: ``n_jobs``, else ``BAYESCAP_JOBS``, else one (module
    docstring: more cost CPU time; at most one per channel)."""
    from bayescap.model.threads import _allowed

    if n_jobs is None:
        n_jobs = _allowed("BAYESCAP_JOBS", lambda: 1)
    return max(1, min(int(n_jobs), n_channels))


def _separate_fits(tables, channels, *, quality, seed, n_jobs=None):
    """:func:`_fit_channel` of each channel with child ``i`` of :func:`bayescap.batch.sensor_seeds`
    (``seed``): ({channel: FitResult}, {channel: its ``parameter_summary()``}). With ``n_jobs`` > 1
    the channels are shared out round-robin among this process and ``n_jobs − 1`` workers; every
    process runs a channel's MCMC ensembles in lockstep. The numbers are bit for bit the same
    (``tests/test_cfa.py``)."""
    from bayescap.batch import sensor_seeds

    tasks = [(tables[c], s, quality) for c, s in zip(channels, sensor_seeds(seed, len(channels)))]
    n_jobs = _channel_jobs(n_jobs, len(tasks))
    if n_jobs == 1:
        res = [_fit_channel(t, n_jobs=1) for t in tasks]  # one process: MCMC ensembles in lockstep
    else:
        res = _pooled(tasks, n_jobs)
    return {c: r for c, (r, _) in zip(channels, res)}, {c: s for c, (_, s) in zip(channels, res)}


def _pooled(tasks, n_jobs) -> list:
    """:func:`_fit_channel` of every task, shared out round-robin among this process and ``n_jobs − 1``
    worker processes (:func:`_separate_fits`)."""
    from bayescap.batch.workers import process_pool, stop_pool

    res: list = [None] * len(tasks)
    ex = process_pool(n_jobs - 1)  # workers end with this process
    try:
        futures = {i: ex.submit(_fit_channel, tasks[i]) for i in range(len(tasks)) if i % n_jobs}
        for i in range(0, len(tasks), n_jobs):
            res[i] = _fit_channel(tasks[i], n_jobs=1)
        for i, f in futures.items():
            res[i] = f.result()
    except BaseException:
        stop_pool(ex)  # an error or an interrupt: the workers' fits are not waited for
        raise
    # every result is in: the workers exit on their own, not waited for (~20 ms of a fast fit's ~250)
    ex.shutdown(wait=False)
    return res


def _consensus(models, xs, shared, rng, n_draws):
    """Draws of the shared coordinates from the product of the channels' Gaussian marginals, the
    prior counted once (linearised at the consensus): (n_draws, len(shared))."""
    n = len(shared)
    prec = np.zeros((n, n))
    rhs = np.zeros(n)
    count = np.zeros(n)
    for m, x in zip(models, xs):
        cols = [j for j, c in enumerate(shared) if c in m.idx]
        if not cols:
            continue
        s = x[:, [m.idx[shared[j]] for j in cols]]
        h = np.linalg.inv(np.atleast_2d(np.cov(s, rowvar=False)))
        prec[np.ix_(cols, cols)] += h
        rhs[cols] += h @ s.mean(axis=0)
        count[cols] += 1
    mean = np.linalg.solve(prec, rhs)
    # the prior of a coordinate entered once per channel that has it: take C_s − 1 copies off
    grad = np.zeros(n)
    for j, c in enumerate(shared):
        if count[j] > 1:
            i = next(i for i, mm in enumerate(models) if c in mm.idx)
            m = models[i]
            pts = np.repeat(xs[i].mean(axis=0)[None], 2, axis=0)
            h = 1e-4 * max(1.0, abs(mean[j]))
            pts[:, m.idx[c]] = mean[j] + np.array([h, -h])
            lp = m.log_prior(pts)
            if np.all(np.isfinite(lp)):
                grad[j] = (count[j] - 1) * (lp[0] - lp[1]) / (2 * h)
    mean = np.linalg.solve(prec, rhs - grad)
    cov = np.linalg.inv(prec)
    return rng.multivariate_normal(mean, 0.5 * (cov + cov.T), size=n_draws, method="cholesky")


def _transport(m, x, shared, s_new, rng):
    """Channel draws moved to the consensus ``s_new`` (n, len(shared)): the shared coordinates
    replaced, the own ones by their linear-Gaussian conditional (module docstring)."""
    n = s_new.shape[0]
    x = x[rng.choice(x.shape[0], size=n, replace=x.shape[0] < n)].copy()
    cols = [j for j, c in enumerate(shared) if c in m.idx]
    sc = [m.idx[shared[j]] for j in cols]
    oc = [i for i in range(m.ndim) if i not in sc]
    if cols and oc:
        c_all = np.cov(x[:, sc + oc], rowvar=False)
        k = len(sc)
        b = np.linalg.solve(c_all[:k, :k], c_all[:k, k:]).T  # (own, shared)
        x[:, oc] += (s_new[:, cols] - x[:, sc]) @ b.T
    x[:, sc] = s_new[:, cols]
    return x


def fit_cfa(
    tables: dict[str, PTCData], *, seed: int = 0, quality: str = "fast", n_draws: int = 4000, n_jobs: int | None = None
) -> CFAFit:
    """Fit the four channels' photon-transfer tables as one readout chain (module docstring).

    Parameters
    ----------
    tables : {"R", "Gr", "Gb", "B"} -> PTCData, one table per channel of one sensor.
    seed : the seed of every random draw (the same seed gives the same numbers).
    quality : the single-channel fit's preset ("fast", "standard", "accurate").
    n_draws : draws of the joint posterior.
    n_jobs : processes for the four channel fits (default ``BAYESCAP_JOBS``, else 1: every fit and
        MCMC ensemble in this process; 1 in a multiprocessing worker). The numbers do not depend
        on it.
    """
    missing = [c for c in CFA_CHANNELS if c not in tables]
    if missing:
        raise ValueError(f"the tables of channels {', '.join(missing)} are missing")
    t_start = time.perf_counter()
    channels = CFA_CHANNELS
    results, summaries = _separate_fits(tables, channels, quality=quality, seed=seed, n_jobs=n_jobs)
    models = [results[c].model for c in channels]
    xs = [results[c].chains.chain.reshape(-1, results[c].chains.chain.shape[-1]) for c in channels]
    separate = {c: results[c].draws for c in channels}
    notes: list = [
        f"channel {c}: the separate fit is NOT CONVERGED" for c in channels if not results[c].diag.get("converged")
    ]
    k_check = _k_check(separate, channels)
    if not k_check["passed"]:
        ks = ", ".join(f"{c} {v:.4g}" for c, v in k_check["k_e_per_dn"].items())
        notes.append(
            f"the channels' conversion gains disagree (K: {ks} e-/DN; p = {k_check['p_value']:.2g}): digital "
            "channel scaling in the RAW, crosstalk or a wrong black level; the shared K describes none of them, "
            "read the separate fits"
        )
    every = [c for c in SHARED_COORDS if all(c in m.idx for m in models)]
    # a coordinate some channel's data leave unconstrained (an upper limit) is not combined: the
    # product of prior-dominated marginals would pass for a measurement
    loose = [
        c for c in every if any(not summaries[ch].get(SHARED_NAMES[c], {}).get("constrained", True) for ch in channels)
    ]
    for c in loose:
        notes.append(
            f"{SHARED_NAMES[c]} is not combined across the channels: the data leave it unconstrained "
            "(an upper limit) in at least one channel; each channel keeps its own"
        )
    every = [c for c in every if c not in loose]
    some_clip = "clip_dn" not in every and any("clip_dn" in m.idx for m in models)
    shared = every + (["clip_dn"] if some_clip else [])
    consistency = {}
    for c in shared:
        have = [i for i, m in enumerate(models) if c in m.idx]
        v = [xs[i][:, models[i].idx[c]] for i in have]
        chi2, dof, p = chi2_check(np.array([np.median(a) for a in v]), np.array([np.std(a, ddof=1) for a in v]))
        consistency[SHARED_NAMES[c]] = {
            "channels": [channels[i] for i in have],
            "chi2": chi2,
            "dof": dof,
            "p_value": p,
            "passed": bool(p >= K_CHECK_P_MIN),
        }
    rng = np.random.default_rng(seed)
    s_new = _consensus(models, xs, shared, rng, n_draws)
    draws = {}
    for c, m, x in zip(channels, models, xs):
        d = m.physical(_transport(m, x, shared, s_new, rng))
        if "clip_dn" in shared and "clip_dn" not in m.idx:
            d["clip_dn"] = s_new[:, shared.index("clip_dn")]
            d["full_well_e"] = (d["clip_dn"] - m.black_dn) * d["conversion_gain_e_per_dn"]
        draws[c] = d
    if some_clip:
        lack = [c for c, m in zip(channels, models) if "clip_dn" not in m.idx]
        notes.append(f"channel(s) {', '.join(lack)} reach no saturation: their clip level is the other channels'")
    if "clip_dn" not in shared:
        notes.append("no channel reaches saturation: the clip is the ADC maximum, a bound")
    return CFAFit(
        channels=channels,
        shared=shared,
        draws=draws,
        separate=separate,
        k_check=k_check,
        consistency=consistency,
        black_dn={c: float(m.black_dn) for c, m in zip(channels, models)},
        adc_max_dn=tables[channels[0]].adc_max_dn,
        converged=all(bool(results[c].diag.get("converged")) for c in channels),
        quality=quality,
        seed=int(seed),
        seconds=time.perf_counter() - t_start,
        results=results,
        summaries=summaries,
        notes=notes,
    )


def cs_without_floor(var_coeffs_dn2, clip_dn) -> np.ndarray:
    """CS without the floor over the full raw cube, per draw (bits): the integrand is one there, so
    CS = Σ_c log2 ∫_{σ_c(0)}^{clip_c} dS / σ_c(S) over R, G, B (G the mean of Gr and Gb), Eq. 7's
    closed form (:func:`bayescap.physics.capacity.integral_inv_sqrt_quadratic`)."""
    from bayescap.colour.sensitivity import raw_rgb_coefficients
    from bayescap.physics.capacity import integral_inv_sqrt_quadratic

    rgb, clip3 = raw_rgb_coefficients(var_coeffs_dn2, clip_dn)
    a, b, c = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return np.sum(np.log2(integral_inv_sqrt_quadratic(a, b, c, np.sqrt(a), clip3)), axis=1)


def colour_summary(
    fit: CFAFit,
    ccm,
    wb_gains,
    *,
    exposure_time_s: float,
    n_pixels_sensor: float | None,
    metadata: dict | None = None,
    domain="cube",
    domain_name: str | None = None,
    floor: bool = True,
    out_bits: int = 8,
    clip_output: bool = True,
) -> dict:
    """CS per joint draw and what follows from it: the numbers of the ``colour`` JSON block.

    ``ccm``: a :class:`bayescap.colour.ccm.CCM` (its draws carry the matrix's stated uncertainty);
    ``wb_gains``: (3,) R, G, B; ``n_pixels_sensor``: the sensor's photosite count N (``None``: no
    capacity and no print normalisation); ``metadata``: the sensor's (pixel pitch, f-number, ...),
    for the MTF loss Δs of the capacities (:func:`bayescap.api.mtf_from_metadata`).
    ``domain``: ``"cube"`` or the ``(n, 3)`` raw responses of a reflectance set
    (:func:`bayescap.colour.spectral.reflectance_domain`), ``domain_name`` what to call it in the
    choices. ``clip_output`` (default True): only the colours inside ``[0, white]`` after M count,
    as in an output image (docs/colour.md: what DxOMark-like users expect); False counts the whole
    raw cube, where a noise-amplifying M raises CS.
    Capacities: :func:`bayescap.colour.capacity.colour_capacities`; scores:
    :mod:`bayescap.colour.scores`. Every value is summarised over the draws (median, 68 %, 95 %).
    """
    from bayescap.api import mtf_from_metadata
    from bayescap.colour.capacity import colour_capacities
    from bayescap.colour.cs_emulator import colour_sensitivity_emulated
    from bayescap.colour.scores import SCORE_DEFINITIONS, colour_depth, dynamic_range_ev, snr_18_db
    from bayescap.inference.end_errors import interval_end_mcse
    from bayescap.physics.capacity import mtf_loss_bits, tonal_range, tonal_range_bits
    from bayescap.physics.noise import NoiseCoefficients

    # CS on an evenly thinned subset of the joint draws: its 95 % ends to a Monte Carlo error of a few
    # per cent of the interval's width, reported (CS_GRID, CS_GRID_CUT: the quadrature's error); the
    # quadrature on 128 pilot draws, the rest by the linear map its leave-one-out check admits
    # (bayescap.colour.cs_emulator; else the quadrature on every draw)
    keep = np.linspace(0, fit.n_draws - 1, min(fit.n_draws, CS_DRAWS)).round().astype(int)
    coeffs = fit.var_coeffs_dn2(exposure_time_s)[keep]
    clip = fit.clip_signal_dn()[keep]
    n = keep.size
    cs = colour_sensitivity_emulated(
        coeffs,
        clip,
        ccm.as_draws(n, seed=fit.seed) if ccm.draws is not None else ccm.matrix,  # exact: one matrix
        wb_gains,
        domain=domain,
        floor=floor,
        out_bits=out_bits,
        clip_output=clip_output,
        n_grid=CS_GRID_CUT if (clip_output or not isinstance(domain, str)) else CS_GRID,
    )
    if domain_name:
        cs.choices["domain"] = f"{cs.choices['domain']}: {domain_name}"
    cs_nofloor = cs_without_floor(coeffs, clip)
    notes: list = []
    # the Monte Carlo error of the 95 % interval's ends, as for independent draws (the joint draws are)
    mc_frac = interval_end_mcse(cs.bits, np.full(n, 1.0 / n))
    out = {
        "cs_bits": summarize(cs.bits, "bits"),
        "cs_no_floor_bits": summarize(cs_nofloor, "bits"),
        "choices": {
            **cs.choices,
            "exposure_time_s": float(exposure_time_s),
            "wb_gains": np.asarray(wb_gains, float).tolist(),
            "n_draws": int(n),
            "cs_interval_end_mc_error_frac_of_width": mc_frac,
        },
        "scores": {},
        "capacity": {},
        "definitions": dict(SCORE_DEFINITIONS),
        "notes": notes,
    }
    sc = out["scores"]
    dr = dynamic_range_ev(coeffs, clip)
    snr = snr_18_db(coeffs, clip)
    channel_bits = tonal_range_bits(
        tonal_range(NoiseCoefficients(a=coeffs[..., 0], b=coeffs[..., 1], c=coeffs[..., 2]), clip)
    )
    if n_pixels_sensor:
        npx = float(n_pixels_sensor)
        for k, v in colour_depth(cs.bits, npx).items():
            sc[k] = summarize(v, "bits")
        md = dict(metadata or {})
        mtf_notes: list = []
        ds = float(np.median(mtf_loss_bits(mtf_from_metadata(md, notes=mtf_notes)).delta_s_bits))
        notes += mtf_notes
        caps = colour_capacities(cs.bits, npx, channel_bits, delta_s_channel_bits=ds, delta_s_lum_bits=ds)
        for k, v in caps.items():
            out["capacity"][k] = summarize(v["bits"], "bits")
            out["definitions"][f"capacity {k}"] = v["definition"]
        out["choices"]["delta_s_bits"] = ds
        out["choices"]["delta_s_source"] = (
            "the metadata's MTF (pixel aperture x diffraction lens), the same Δs for every channel and luminance"
        )
        out["n_pixels_sensor"] = npx
    else:
        sc["colour_depth_bits"] = summarize(cs.bits, "bits")
        notes.append("the sensor's pixel count is unknown: no capacity and no print normalisation")
    for j, c in enumerate(fit.channels):
        sc[f"dynamic_range_ev_{c}"] = summarize(dr[:, j], "EV")
        sc[f"snr_18_db_{c}"] = summarize(snr[:, j], "dB")
        sc[f"tonal_range_bits_{c}"] = summarize(channel_bits[:, j], "bits")
    out["definitions"]["tonal_range_bits"] = "b' = log2 TR of each CFA channel (Eq. 7, the floor on its own 256 levels)"
    out["definitions"]["cs_no_floor_bits"] = (
        "CS without the floor over the full raw cube, unclipped: Σ log2 TR of R, G, B without the floor "
        "(closed form; the CCM cancels), whatever the domain and clipping of cs_bits"
    )
    notes.append(
        "low-light ISO needs a gain series (one frame set per ISO; bayescap.colour.scores.low_light_iso): "
        "not computed from one frame set"
    )
    return out
