"""The photon-transfer noise model (Tisse et al. 2008, Eq. 1) and its posterior density.

Everything is in electrons with the conversion gain ``K`` (e⁻/DN). For a bright row at mean
signal ``S`` (DN above the dark level) and exposure time ``t`` the temporal variance of the
pixel values is, before clipping,

    σ²_y(S) = S/K + (σ_read² + D·t)/K² + 1/12          [DN²]

(photon shot noise, dark-current shot noise, read noise, quantization), and for the dark row
``σ²_dark = (σ_read² + D·t)/K² + 1/12``. Pair differences cancel fixed-pattern noise, so DSNU and
PRNU enter only through the spatial columns: ``spatial_var = (PRNU·S)² + DSNU²/K² + σ²_y/L``.

Eq. 1 in electrons, σ²(S) = a + b·S + c·S², has its home in :mod:`bayescap.physics.noise`, whose
:func:`~bayescap.physics.noise.dark_variance_e2` gives the model its σ_read² + D·t
(:meth:`PTCModel.dark_var_e2`). The model writes the rest in DN, temporal and spatial variances
apart, because that is what frame pairs and frame averages measure: below the quantization floor
the rounded normal's exact moments replace Sheppard's 1/12 DN² (K²/12 e⁻²), the ROI's realised
fixed pattern replaces PRNU²·S² + DSNU², and near saturation the clip bends the curve.

**Saturation.** Pixel values clip at a level ``c`` (DN): the ADC maximum or the full well,
whichever comes first. Across the ROI, pixels approach the clip at different light levels
(PRNU, per-pixel well depth), described by a spread ``τ`` (DN) of the pixel means. The mean and
temporal variance of a clipped Gaussian, averaged over that spread (closed forms, ``_clip_moments``),
give the smooth roll-off of the measured variance; the latent (unclipped) signal of each row
near the clip is found by inverting the clipped-mean relation with a monotone Newton iteration.
Fully clipped rows (variance ≈ 0) locate the clip level only: they enter through their mean.
With no row near saturation no clip term is fitted and the full well is reported as a lower
bound.

**Likelihood.** A temporal variance from a frame pair over ``n`` pixels follows a scaled χ²
with ``ν = n − 1`` degrees of freedom around the *model* variance: Gamma(ν/2, 2σ²/ν). Real
data carry systematics (illumination drift, non-linearity) far above the 0.4 % statistical
error of a 10⁵-pixel variance; a fitted fractional discrepancy ``f`` widens the distribution
to an effective ``ν_eff`` with ``2/ν_eff = 2/ν + f²`` (same mean, relative variance
``2/ν + f²``), so the intervals stay honest. ``f`` is reported: a large value says the model
or the data are inadequate. With ``photons_per_pixel`` the means are fitted jointly:
``S = QE·μ_p/K`` with a fractional mean discrepancy ``g`` (non-linearity).

**Terms enter only when the data can inform them** (:func:`select_terms`); the reasons for
every left-out term are recorded.

**Code.** :class:`PTCModel` holds the data and the posterior; its methods come in groups from
:mod:`~bayescap.model.parameters` (parameters, prior, start point),
:mod:`~bayescap.model.prediction` (the predicted blocks), :mod:`~bayescap.model.clipping`
(saturation) and :mod:`~bayescap.model.likelihood` (the blocks' densities); the rounding is in
:mod:`~bayescap.model.quantization` and :mod:`~bayescap.model.pixel_quantization`.
"""

from __future__ import annotations

import numpy as np

from bayescap.io.ptc_csv import PTCData
from bayescap.model.clipping import _ClipMixin
from bayescap.model.dark_ramp import dark_mean_line
from bayescap.model.likelihood import _LikelihoodMixin
from bayescap.model.parameters import _ParametersMixin
from bayescap.model.prediction import _PredictionMixin
from bayescap.model.terms import ModelTerms, intercept_variance_dn2, rows_to_fit, saturation_flags, select_terms
from bayescap.model.threads import SPLIT_MIN_ELEMENTS, _split_rows

__all__ = ["PTCModel", "CHUNK_ELEMENTS", "CHUNK_MIN_DRAWS"]

#: a ``log_prob`` call evaluates its likelihood in chunks of draws of at most this many draws ×
#: observations (:meth:`PTCModel._chunked_loglik`): ~25 MB at the peak, whatever the rows. Smaller
#: chunks keep a chunk's (draws, rows near the clip) arrays in the core's cache: on a simulated
#: focal-plane amplifier (326 rows, 172 near the clip) the calls of ≥ 2 000 draws took 0.78 s
#: against 1.09 s with 2²⁰ (2¹⁷: 0.86 s, 2¹⁶: 1.17 s); the Basler's and the benchmark sensors'
#: 4 000-draw calls were the same within the machine's noise
CHUNK_ELEMENTS = 1 << 18
#: ... and of at least this many draws (a call on very many rows: memory then grows with the rows)
CHUNK_MIN_DRAWS = 4


class PTCModel(_ParametersMixin, _PredictionMixin, _ClipMixin, _LikelihoodMixin):
    """Posterior density of the noise-model parameters for one PTCData.

    Sampling coordinates are unconstrained (logs of scales) with the Jacobians in the priors;
    :meth:`log_prob` takes an array ``(n_walkers, n_dim)`` and returns ``(n_walkers,)``.
    :meth:`physical` maps draws to named physical parameters.
    """

    #: prior scales (see docs/model.md, "Priors"). The ``*_log_bounds`` / ``qe_bounds`` entries are
    #: ``None`` in production (half-normal scale priors, QE uniform on (0, 1]); a pair
    #: ``(lo, hi)`` of *natural* values replaces the half-normal by a log-uniform prior on
    #: [lo, hi] (QE: uniform on [lo, hi]). Override per model with ``PTCModel(data, prior={...})``
    #: or ``bayescap.fit(..., prior={...})``; ``benchmarks/sbc.py`` does so to fit with exactly
    #: the prior it draws its true sensors from (classic SBC).
    PRIOR = dict(
        log_k_bounds=(np.log(1e-4), np.log(1e4)),
        read_scale_e=1000.0,
        dark_current_scale_e_per_s=1e4,
        prnu_scale=0.05,
        dsnu_scale_e=100.0,
        f_center=0.01,
        f_log_sd=1.5,
        g_center=0.005,
        g_log_sd=1.5,
        tau_log_sd=1.5,
        tau_max_frac=0.1,
        response_shape_sd=1.0,
        response_step_scale=0.05,
        brighter_fatter_sd=0.5,
        offset_spread_log_bounds=(1e-3, 2.0),
        read_log_bounds=None,
        dark_current_log_bounds=None,
        prnu_log_bounds=None,
        dsnu_log_bounds=None,
        qe_bounds=None,
    )

    @classmethod
    def for_fit(cls, data: PTCData, prior: dict | None = None) -> "PTCModel":
        """The model a fit builds from ``data``: the rows :func:`~bayescap.model.terms.rows_to_fit`
        leaves out removed, the terms chosen by :func:`select_terms` on the rest, and the note on
        what was left out in ``data_notes`` (the result carries it)."""
        data, left_out = rows_to_fit(data)
        model = cls(data, terms=select_terms(data), prior=prior)
        model.data_notes = [left_out] if left_out else []
        return model

    def __init__(self, data: PTCData, terms: ModelTerms | None = None, prior: dict | None = None):
        self.data = data
        self.terms = terms or select_terms(data)
        # results computed once per model (initial_guess, the observation count), shared by its
        # shallow copies (bayescap.inference.lockstep._with_log_prob; a PTCModelStack view gets its own)
        self._memo = {}
        if prior:
            unknown = set(prior) - set(PTCModel.PRIOR)
            if unknown:
                raise ValueError(f"unknown prior keys {sorted(unknown)}; known: {sorted(PTCModel.PRIOR)}")
            self.PRIOR = {**PTCModel.PRIOR, **prior}  # instance attribute: the class default stays
        d, tm = data, self.terms
        self.full_sat, self.saturation_reached = saturation_flags(d)
        ok = ~self.full_sat
        self.rows = np.nonzero(ok)[0]
        self.t = d.exposure_time_s
        self.adc = d.adc_max_dn
        self.black_dn = float(d.dark_mean_dn[np.argmin(d.exposure_time_s)])
        names = ["log_k"]
        names.append("log_read" if tm.dark_current else "log_dark_noise")
        if tm.dark_current:
            names.append("log_dc")
        m_ok = d.mean_dn[ok]
        v_ok = d.temporal_var_dn2[ok]
        self.max_mean_ok = float(m_ok.max())
        if tm.clip in ("adc_sampled", "well"):
            names.append("clip_dn")
            lo = self.max_mean_ok + 1e-6 * max(1.0, self.max_mean_ok)
            if np.any(self.full_sat):
                hi = float(d.mean_dn[self.full_sat].max()) + 10.0 * np.sqrt(max(v_ok.max(), 1.0))
            else:
                hi = self.adc if self.adc is not None else 2.0 * self.max_mean_ok
                hi = max(hi, lo * 1.05)
            if self.adc is not None:
                hi = min(hi, self.adc + 0.5)
            self.clip_bounds = (lo, max(hi, lo + 1e-3))
        elif tm.clip == "adc":
            self.clip_bounds = (self.adc, self.adc)
        else:
            self.clip_bounds = None
        if tm.clip_spread:
            names.append("log_tau")
        if tm.quantum_efficiency:
            names += ["qe", "log_g"]
        if tm.prnu:
            names.append("log_prnu")
        if tm.dsnu:
            names.append("log_dsnu")
        # the ROI's realised fixed patterns (see _pattern_moments): standard-normal latents
        self.pattern_latents = []
        if tm.dsnu:
            self.pattern_latents.append("z_roi_dsnu")
        if tm.prnu:
            self.pattern_latents += ["z_roi_prnu", "z_roi_cross"]
        names += self.pattern_latents
        if tm.discrepancy:
            names.append("log_f")
        names += self._extra_names()
        self.names = names
        self.ndim = len(names)
        self.idx = {n: i for i, n in enumerate(names)}
        # data arrays (non-fully-clipped rows)
        self.m = d.mean_dn[ok]
        self.v = np.maximum(d.temporal_var_dn2[ok], 1e-6)
        # without dark pairs (a mean/variance table) there is no dark block: the PTC's intercept
        # stands in for the dark variance where a start point or a mean's error needs one
        self.dark_rows = d.has_dark_rows
        self.vd = np.maximum(d.dark_temporal_var_dn2, 1e-6) if self.dark_rows else intercept_variance_dn2(d)
        self.dm = d.dark_mean_dn[ok]
        self.tt = self.t[ok]
        self.nu = d.n_pixels[ok] - 1.0
        self.nu_d = d.n_pixels - 1.0
        self.s_obs = self.m - self.dm
        # rows near enough to a possible clip level to need the clipped-moment model
        if self.clip_bounds is not None:
            tau_max = self.PRIOR["tau_max_frac"] * self.clip_bounds[1]
            reach = self.m + 8.0 * np.sqrt(self.v + tau_max**2)
            self.clip_rows = np.nonzero(reach >= self.clip_bounds[0])[0]
        else:
            self.clip_rows = np.zeros(0, int)
        self.lin_rows = np.setdiff1d(np.arange(self.m.size), self.clip_rows)
        self._saturated_rows(d, ok)
        if tm.quantum_efficiency:
            self.mu_p = d.photons_per_pixel[ok]
        # fully clipped rows: their mean locates a sampled clip level
        self.full_means = d.mean_dn[self.full_sat]
        self.full_v = d.temporal_var_dn2[self.full_sat]
        self.full_nu = d.n_pixels[self.full_sat] - 1.0
        self.t_full = self.t[self.full_sat]
        self.vd_ok = self.vd[~self.full_sat]
        self.full_sd = np.sqrt(
            d.temporal_var_dn2[self.full_sat] / d.n_pixels[self.full_sat]
            + (1e-4 * np.maximum(self.full_means, 1.0)) ** 2
            + 0.01**2
        )
        # spatial rows
        self.sp_rows = np.zeros(0, int)
        self.spd_rows = np.zeros(0, int)
        if tm.prnu and d.spatial_var_dn2 is not None:
            sp = d.spatial_var_dn2[ok]
            self.sp_rows = np.setdiff1d(np.nonzero(np.isfinite(sp))[0], self._pattern_clip_rows())
            self.sp = sp
        if tm.dsnu and d.dark_spatial_var_dn2 is not None:
            self.spd_rows = np.nonzero(np.isfinite(d.dark_spatial_var_dn2))[0]
            self.spd = d.dark_spatial_var_dn2
        nfr = d.n_frames if d.n_frames is not None else np.full(d.n_levels, 2.0)
        nfr = np.where(np.isfinite(nfr), nfr, 2.0)
        self.L_ok = nfr[ok]
        self.L_all = nfr
        # degrees of freedom of the ROI's pattern sample variance (one ROI for every spatial row)
        sp_any = np.zeros(d.n_levels, bool)
        for col in (d.spatial_var_dn2, d.dark_spatial_var_dn2):
            if col is not None:
                sp_any |= np.isfinite(col)
        self.nu_pattern = (
            float(np.median(d.n_pixels[sp_any]) - 1.0) if np.any(sp_any) else float(np.median(d.n_pixels) - 1.0)
        )
        # the means' rounding error: below ~0.5 DN of noise a pixel's rounded mean is off its true mean
        # by up to ~(1/π)·exp(−2π²σ²) (the first harmonic; its phase, the mean's offset from the DN
        # grid, unknown), less where the pixels' offsets spread over the grid (a measured dark spatial
        # variance); bright and dark rows each: a variance allowance on the mean block
        spread2 = 0.0
        if d.dark_spatial_var_dn2 is not None and np.any(np.isfinite(d.dark_spatial_var_dn2)):
            spread2 = float(np.nanmedian(d.dark_spatial_var_dn2))
        s2b = np.maximum(self.v - 1.0 / 12.0, 0.0) + spread2
        s2d = np.maximum(self.vd[ok] - 1.0 / 12.0, 0.0) + spread2
        self.mean_rounding_var = (np.exp(-4.0 * np.pi**2 * s2b) + np.exp(-4.0 * np.pi**2 * s2d)) / (2.0 * np.pi**2)
        # the dark means' ramp (bayescap.model.dark_ramp), where it enters: every dark row
        if getattr(tm, "dark_mean", False):
            line = dark_mean_line(d)
            self.dmn = np.asarray(d.dark_mean_dn, float)
            self.dmn_mbar = np.full(d.n_levels, line.mbar)
            self.dmn_tc = line.tc
            self.dmn_sd = line.sd
            self.dark_mean_birge = line.birge
        # fractional offsets of the measured means from the nearest integer DN (quantization)
        self.dark_frac_dn = d.dark_mean_dn - np.round(d.dark_mean_dn)
        self.bright_frac_dn = self.m - np.round(self.m)
        self.full_frac_dn = self.full_means - np.round(self.full_means)

    #: the tolerance of the model's clipped fraction against the measured one, in probit units
    #: beyond the count's binomial error: the model takes the pixels near the clip as normal
    SATURATED_PROBIT_SD = 0.3

    def _saturated_rows(self, d: PTCData, ok):
        """The rows of the ``saturated`` block (:meth:`~bayescap.model.prediction._PredictionMixin.predict`):
        with an ADC clip and a ``frac_saturated`` column, the rows within reach of the clip. The
        measured fraction of pixels at the ADC maximum bounds the model's from above (a defective
        pixel can only add saturated pixels); 0 counts as half a pixel."""
        self.sat_rows = np.zeros(0, int)
        if self.terms.clip != "adc" or d.frac_saturated is None or not self.clip_rows.size:
            return
        from scipy.special import ndtri

        fs = np.asarray(d.frac_saturated, float)[ok]
        n = np.maximum(d.n_pixels[ok], 2.0)
        self.sat_rows = self.clip_rows[np.isfinite(fs[self.clip_rows])]
        self.sat_fs = np.clip(np.where(np.isfinite(fs), fs, 0.0), 0.5 / n, 1.0 - 0.5 / n)
        f = self.sat_fs
        binomial = np.sqrt(f * (1.0 - f) / n) / (np.exp(-0.5 * ndtri(f) ** 2) * 0.3989422804014327)
        self.sat_sd = np.sqrt(binomial**2 + self.SATURATED_PROBIT_SD**2)

    # ------------------------------------------------------------------ stacked views
    #: request ids of the draws in a call (a PTCModelStack's view sets them): reductions over
    #: "the draws of this call" are then per request, so a sensor's numbers do not depend on which
    #: other sensors share the call
    _request_ids = None
    _request_segments = None

    def _request_reduce(self, ufunc, a):
        """``ufunc.reduce`` of ``a`` (n,) over the draws of one request: a scalar for a single
        model; per draw (n,) for a stacked view."""
        if self._request_ids is None:
            return ufunc.reduce(a)
        if self._request_segments is None:  # the requests' starts and sizes, once per view
            ids = self._request_ids
            starts = np.flatnonzero(np.concatenate(([True], ids[1:] != ids[:-1])))
            self._request_segments = (starts, np.diff(np.append(starts, ids.size)))
        starts, sizes = self._request_segments
        return np.repeat(ufunc.reduceat(a, starts), sizes)

    @staticmethod
    def _per_draw(x):
        """A per-sensor number as a column for (n_draws, rows) arithmetic: scalars unchanged,
        per-draw arrays (n,) of a stacked view as (n, 1)."""
        return x if np.ndim(x) == 0 else np.asarray(x)[:, None]

    # ------------------------------------------------------------------ posterior
    def log_prob(self, theta):
        """log prior + log likelihood of draws ``theta`` (n, ndim) or one draw (ndim,): (n,).
        Calls of :data:`~bayescap.model.threads.SPLIT_MIN_ELEMENTS` (draws × observations) or more
        are evaluated in two halves, on two threads where :func:`~bayescap.model.threads.n_threads`
        allows (:func:`~bayescap.model.threads._split_rows`)."""
        th = np.atleast_2d(np.asarray(theta, float))
        if th.shape[0] >= 1000 and th.shape[0] * self._observations() >= SPLIT_MIN_ELEMENTS:
            return _split_rows(lambda part: _log_posterior(part, lambda good: self, self._chunked_loglik), th)
        return _log_posterior(th, lambda good: self, self._chunked_loglik)

    def _chunk_plan(self, th):
        """Draws per chunk for the draws ``th`` (n, ndim), and the indices of the draws holding the
        call's extremes of the conversion gain, clip level and clip spread (those that choose the
        rows near the clip in :meth:`predict`; none without clip rows)."""
        # observations per draw, counted from the data (an upper bound of the blocks' columns)
        obs = 2 * self.vd.size + 3 * self.m.size + 2 * self.full_means.size
        per = max(CHUNK_MIN_DRAWS, CHUNK_ELEMENTS // obs)
        extremes = np.zeros(0, int)
        if self.clip_rows.size and th.shape[0] > per:
            cols = [self.idx[c] for c in ("log_k", "clip_dn", "log_tau") if c in self.idx]
            extremes = np.unique([f(th[:, j]) for j in cols for f in (np.argmin, np.argmax)]).astype(int)
        return per, extremes

    def predict(self, th):
        """The predicted blocks (:meth:`_PredictionMixin.predict`), for many draws in chunks of
        draws (as :meth:`_chunked_loglik`), the same numbers bit for bit: memory is the result's
        arrays plus one chunk's intermediates, not ~12 (draws, observations) arrays."""
        th = np.atleast_2d(np.asarray(th, float))
        n = th.shape[0]
        if self._request_ids is not None:
            return super().predict(th)
        per, extremes = self._chunk_plan(th)
        if n <= per + 6:  # (the chunks of _chunked_loglik, extremes included, stay whole)
            return super().predict(th)
        out, latent = {}, None
        for lo in range(0, n, per):
            part = th[lo : lo + per]
            k = part.shape[0]
            m = k + extremes.size
            pred = super().predict(np.concatenate([part, th[extremes]]) if extremes.size else part)
            if not out:  # (draws, observations) arrays are filled chunk by chunk; broadcast ones kept
                out = {
                    b: [np.empty((n,) + np.shape(x)[1:], np.asarray(x).dtype) if _draw_rows(x, m) else x for x in v]
                    for b, v in pred.items()
                }
                latent = np.empty((n,) + self._last_latent_signal_dn.shape[1:])
            for b, v in pred.items():
                for i, x in enumerate(v):
                    if _draw_rows(x, m):
                        out[b][i][lo : lo + k] = x[:k]
            latent[lo : lo + k] = self._last_latent_signal_dn[:k]
        self._last_latent_signal_dn = latent
        return {b: tuple(v) for b, v in out.items()}

    def _chunked_loglik(self, th):
        """:meth:`log_likelihood` of draws ``th`` (n, ndim), in chunks of draws of at most
        :data:`CHUNK_ELEMENTS` draws × observations (at least :data:`CHUNK_MIN_DRAWS` draws), so
        that a call's memory is bounded whatever the number of rows (the blocks' intermediates are
        (draws, observations) arrays, ~100 bytes per element alive at the peak).

        The same numbers as one call, bit for bit: every operation of the likelihood is elementwise
        over (draw, observation) except the choice of rows near the clip, which uses the minimum
        and maximum over the call's draws of the conversion gain, the clip level and the clip
        spread (:meth:`predict`). Each chunk is evaluated together with the draws holding those
        extremes over the whole call (at most six draws, their values discarded), so it makes the
        same choice."""
        n = th.shape[0]
        per, extremes = self._chunk_plan(th)
        if n <= per:
            return self.log_likelihood(th)
        out = np.empty(n)
        for lo in range(0, n, per):
            part = th[lo : lo + per]
            if extremes.size:
                ll = self.log_likelihood(np.concatenate([part, th[extremes]]))
                out[lo : lo + part.shape[0]] = ll[: part.shape[0]]
            else:
                out[lo : lo + part.shape[0]] = self.log_likelihood(part)
        return out

    def _observations(self) -> int:
        """Observations per draw (the likelihood blocks' columns), counted once from one draw."""

        def count():
            with np.errstate(all="ignore"):
                pred = self.predict(np.atleast_2d(self.initial_guess()))
            return int(sum(np.shape(v[1])[-1] for v in pred.values()))

        return self._memoized("observations", count)

    def _memoized(self, key, compute):
        """``compute()``, once per model (:attr:`_memo`, shared by its shallow copies)."""
        memo = self.__dict__.setdefault("_memo", {})  # (a model unpickled from before _memo)
        if key not in memo:
            memo[key] = compute()
        return memo[key]


def _draw_rows(x, m):
    """Whether a predicted block's element is a per-draw array of ``m`` draws (not a broadcast one)."""
    return np.ndim(x) == 2 and np.shape(x)[0] == m


def _log_posterior(theta, model_for, loglik=None):
    """log prior + log likelihood of draws ``theta`` (n, ndim): the likelihood only where the prior
    is finite. ``model_for(good)`` gives the model to evaluate the draws ``good`` (a boolean mask;
    None: all draws) with: the model itself, or a :class:`~bayescap.model.PTCModelStack` view
    of those draws. ``loglik``: the function of the good draws that gives their log-likelihood
    (default: that model's ``log_likelihood``)."""
    th = np.atleast_2d(np.asarray(theta, float))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # far-out draws (a walker at log τ = 800) overflow exp() in the prior: −inf, as meant
        lp = model_for(None).log_prior(th)
    good = np.isfinite(lp)
    out = np.full(th.shape[0], -np.inf)
    if np.any(good):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            ll = (loglik or model_for(good).log_likelihood)(th[good])
        ll = np.where(np.isfinite(ll), ll, -np.inf)
        out[good] = lp[good] + ll
    return out
