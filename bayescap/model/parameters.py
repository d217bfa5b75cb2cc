"""The parameters of :class:`~bayescap.model.PTCModel`: their physical meaning
(:data:`PARAMETER_INFO`, :meth:`~_ParametersMixin.physical`), their prior
(:meth:`~_ParametersMixin.log_prior`, scales in ``PTCModel.PRIOR``) and the deterministic start
point of a fit (:meth:`~_ParametersMixin.initial_guess`).

Sampling coordinates are unconstrained (logs of scales) with the Jacobians in the priors.
"""

from __future__ import annotations

import numpy as np

from bayescap.model.likelihood import _norm_logpdf
from bayescap.model.quantization import _rounded_normal_moments, _rounded_offset
from bayescap.model.response import BF_BOUND, N_BASIS, RICH_BASIS, SHAPE_BOUND, deviation_at_ref, linearise
from bayescap.physics.noise import dark_variance_e2

__all__ = ["PARAMETER_INFO", "response_share"]

#: fixed irrational weights of :func:`response_share` (square roots of primes)
_SHARE_WEIGHTS = np.sqrt(np.array([2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53, 59, 61, 67, 71], float))


def response_share(th) -> np.ndarray:
    """Per draw, the share (0 or 1) of the photon-transfer curve's bend that is the response's, where
    the data cannot say (no photon counts: a response and a brighter-fatter variance loss bend the
    curve alike, and only the charge at the clip depends on which it is: K·x(c) for a bent response,
    K·(c − black) for straight means). The two readings are equally likely, a prior the data do not
    update: half the draws take each (a two-model average; a sensor that is partly both lies between
    the two). Which reading a draw takes is a deterministic function of the draw (the fractional part
    of a large multiple of a fixed irrational combination of its coordinates, below or above ½), so
    the same draw reads the same way in every call and chunk."""
    th = np.atleast_2d(np.asarray(th, float))
    w = np.resize(_SHARE_WEIGHTS, th.shape[1])
    z = (th @ w) * 1.0e5
    return (z - np.floor(z) >= 0.5).astype(float)


# physical parameter -> (unit, description)
PARAMETER_INFO = {
    "conversion_gain_e_per_dn": ("e-/DN", "conversion gain K"),
    "read_noise_e": ("e-", "temporal read noise"),
    "dark_current_e_per_s": ("e-/s", "dark current (from the dark-noise growth with time)"),
    "dark_noise_e": ("e-", "read noise and dark-current shot noise combined at the single exposure time"),
    "full_well_e": ("e-", "charge at which the pixel output clips"),
    "quantum_efficiency": ("", "quantum efficiency"),
    "prnu_percent": ("%", "photo-response non-uniformity"),
    "dsnu_e": ("e-", "dark-signal non-uniformity"),
    "clip_spread_dn": ("DN", "spread of the pixel means about the clip level"),
    "variance_discrepancy": ("", "fractional discrepancy of the variances (systematics)"),
    "mean_discrepancy": ("", "fractional discrepancy of the means (non-linearity)"),
    "response_nonlinearity": (
        "",
        "fractional deviation of the response from linearity at the largest unclipped signal",
    ),
    **{
        f"response_shape_{k}": (
            "",
            f"coefficient {k} of the response's log-slope (Bernstein or spline basis, docs/model.md)",
        )
        for k in range(1, RICH_BASIS + 1)
    },
    "brighter_fatter_a00_per_e": (
        "1/e-",
        "brighter-fatter a00 (Astier et al. 2019 Eq. 16): the shot variance is (exp(2 a00 mu) - 1)/(2 a00)",
    ),
    "pixel_offset_spread_dn": ("DN", "spread of the pixels' mean offsets about the DN grid (rounding average)"),
}


def _halfnormal_log_prior(u, scale):
    """log density of u = log x when x ~ HalfNormal(scale) (Jacobian included)."""
    x = np.exp(u)
    return u - 0.5 * (x / scale) ** 2


def _scale_log_prior(u, scale, log_bounds=None):
    """log prior of u = log x: half-normal of ``scale`` in x, or, with ``log_bounds = (lo, hi)``
    (natural values), log-uniform on [lo, hi] (uniform in u, normalised)."""
    if log_bounds is None:
        return _halfnormal_log_prior(u, scale)
    a, b = np.log(log_bounds[0]), np.log(log_bounds[1])
    return np.where((u >= a) & (u <= b), -np.log(b - a), -np.inf)


class _ParametersMixin:
    """Parameters, prior and start point of :class:`~bayescap.model.PTCModel` (which sets the
    attributes these methods read: ``idx``, ``names``, ``terms``, ``PRIOR``, the data arrays)."""

    # ------------------------------------------------------------------ parameters
    def physical(self, theta, derived: bool = True) -> dict:
        """Named physical parameters for draws ``theta`` (n, ndim); ``derived=False`` leaves out what
        the likelihood does not read (the response's deviation and the full well)."""
        th = np.atleast_2d(theta)
        g = lambda n: th[:, self.idx[n]]
        k = np.exp(g("log_k"))
        out = {"conversion_gain_e_per_dn": k}
        if self.terms.dark_current:
            out["read_noise_e"] = np.exp(g("log_read"))
            out["dark_current_e_per_s"] = np.exp(g("log_dc"))
        else:
            out["dark_noise_e"] = np.exp(g("log_dark_noise"))
        if self.terms.clip in ("adc_sampled", "well"):
            c = g("clip_dn")
        elif self.terms.clip == "adc":
            c = np.full(th.shape[0], self.adc)
        else:
            c = None
        bent = getattr(self.terms, "nonlinearity", False)
        if bent:
            theta = self.response_theta(th)
            for j in range(theta.shape[1]):
                out[f"response_shape_{j + 1}"] = theta[:, j]
            if derived:
                out["response_nonlinearity"] = deviation_at_ref(theta, self.response_ref_dn)
        if getattr(self.terms, "brighter_fatter", False):
            out["brighter_fatter_a00_per_e"] = g("bf") / (k * self.response_ref_dn)
        if c is not None:
            out["clip_dn"] = c
            if not derived:
                pass
            elif bent:  # the charge at the clip: its linear signal h(c − black) times K
                if self.response_share_unknown:  # the bend read as the response's or as brighter-fatter's
                    theta = theta * response_share(th)[:, None]
                xc, _ = linearise((c - self.black_dn)[:, None], theta, self.response_ref_dn, per_point=True)
                out["full_well_e"] = xc[:, 0] * k
            else:
                out["full_well_e"] = (c - self.black_dn) * k
        if self.terms.clip_spread:
            out["clip_spread_dn"] = np.exp(g("log_tau"))
        if self.terms.quantum_efficiency:
            out["quantum_efficiency"] = g("qe")
            out["mean_discrepancy"] = np.exp(g("log_g"))
        if self.terms.prnu:
            out["prnu_percent"] = 100.0 * np.exp(g("log_prnu"))
        if self.terms.dsnu:
            out["dsnu_e"] = np.exp(g("log_dsnu"))
        out["variance_discrepancy"] = np.exp(g("log_f")) if self.terms.discrepancy else np.zeros(th.shape[0])
        if getattr(self.terms, "offset_spread", False):
            out["pixel_offset_spread_dn"] = np.exp(g("log_offset_dn"))
        return out

    def _extra_names(self) -> list:
        """Sampling coordinates of the response and pixel-offset terms (after the others)."""
        out = []
        if getattr(self.terms, "nonlinearity", False):
            out += [f"nl_{k}" for k in range(1, self.n_basis + 1)]
        if getattr(self.terms, "brighter_fatter", False):
            out.append("bf")
        if getattr(self.terms, "offset_spread", False):
            out.append("log_offset_dn")
        return out

    @property
    def response_share_unknown(self) -> bool:
        """Whether the response term's bend may be brighter-fatter instead: without photon counts
        the two bend the photon-transfer curve alike (:func:`response_share`)."""
        return getattr(self.terms, "nonlinearity", False) and self.data.photons_per_pixel is None

    @property
    def n_basis(self) -> int:
        """Degree of the response's log-slope (:attr:`ModelTerms.response_degree`)."""
        return int(getattr(self.terms, "response_degree", N_BASIS))

    def response_theta(self, th):
        """The response's log-slope coefficients θ (n, :attr:`n_basis`) of draws ``th``."""
        th = np.atleast_2d(th)
        j = self.idx["nl_1"]
        return th[:, j : j + self.n_basis]

    @property
    def response_ref_dn(self) -> float:
        """S_ref of the response (:mod:`bayescap.model.response`): the largest unclipped signal (DN)."""
        return max(float(self.max_mean_ok - self.black_dn), 1e-9)

    def dark_var_e2(self, p, t):
        """σ_read² + D·t (e⁻²) for each draw at exposure times t: shape (n_draws, n_t) (Eq. 1's
        :func:`~bayescap.physics.noise.dark_variance_e2`; ``dark_noise_e²`` when only the sum is
        identifiable)."""
        t = np.atleast_1d(np.asarray(t, float))
        if self.terms.dark_current:
            return dark_variance_e2(p["read_noise_e"][:, None], p["dark_current_e_per_s"][:, None], t)
        return np.broadcast_to(
            dark_variance_e2(dark_noise_e=p["dark_noise_e"][:, None]), (p["dark_noise_e"].size, t.shape[-1])
        )

    # ------------------------------------------------------------------ prior
    def _clip_reference_dn(self, th):
        """The clip level the clip spread's prior refers to, per draw: the sampled ``clip_dn``, or
        the ADC maximum when the ADC clips at a known level."""
        if "clip_dn" in self.idx:
            return th[:, self.idx["clip_dn"]]
        return np.full(th.shape[0], self.adc, dtype=float)

    #: spatial rows within reach of the clip at a spread of this fraction of the clip level are left
    #: out of the spatial block (its pattern model is unclipped); the clip spread itself may reach
    #: ``tau_max_frac``, where the prior has put it 2 sd above its centre
    PATTERN_CLIP_FRAC = 0.02

    def _pattern_clip_rows(self):
        """Rows (of the unclipped set) within 8 sd of the clip at a spread of
        :attr:`PATTERN_CLIP_FRAC` of the clip level (all of :attr:`clip_rows` when there is no clip)."""
        if self.clip_bounds is None:
            return self.clip_rows
        tau = self.PATTERN_CLIP_FRAC * self.clip_bounds[1]
        return np.nonzero(self.m + 8.0 * np.sqrt(self.v + tau**2) >= self.clip_bounds[0])[0]

    def tau_cap_dn(self, th):
        """Upper bound of the clip spread τ (DN) in the prior, per draw: ``tau_max_frac`` of
        :meth:`_clip_reference_dn` (a wall: log prior −∞ beyond it)."""
        return self.PRIOR["tau_max_frac"] * self._clip_reference_dn(np.atleast_2d(th))

    def parameter_bounds(self) -> dict:
        """The hard bounds (walls: log prior −∞ beyond) of the physical parameters of this model:
        ``{name: {"lower": x or None, "upper": x or None, "relative_to": name or None, "why": str}}``.
        A ``relative_to`` bound is that fraction of the named parameter, per draw (the clip
        spread's cap is a fraction of the clip level). :meth:`binding_bounds` says which of them
        the posterior presses against; the reporting side flags those."""
        P = self.PRIOR
        lk0, lk1 = P["log_k_bounds"]
        out = {
            "conversion_gain_e_per_dn": {
                "lower": float(np.exp(lk0)),
                "upper": float(np.exp(lk1)),
                "relative_to": None,
                "why": "the gain's prior range",
            }
        }
        if self.terms.clip in ("adc_sampled", "well"):
            lo, hi = self.clip_bounds
            out["clip_dn"] = {
                "lower": float(lo),
                "upper": float(hi),
                "relative_to": None,
                "why": "the clip lies above the largest unclipped mean and below the ADC maximum (+½ DN) "
                "or the plateau",
            }
        if self.terms.clip_spread:
            out["clip_spread_dn"] = {
                "lower": None,
                "upper": float(P["tau_max_frac"]),
                "relative_to": "clip_dn",
                "why": "the rows modelled as partly clipped are those within reach of the clip at this spread",
            }
        if getattr(self.terms, "nonlinearity", False):
            for j in range(1, self.n_basis + 1):
                out[f"response_shape_{j}"] = {
                    "lower": -SHAPE_BOUND,
                    "upper": SHAPE_BOUND,
                    "relative_to": None,
                    "why": "the response's slope stays within a factor e^8 of its small-signal slope",
                }
        if self.terms.quantum_efficiency:
            q0, q1 = P["qe_bounds"] if P["qe_bounds"] is not None else (0.0, 1.0)
            out["quantum_efficiency"] = {"lower": q0, "upper": q1, "relative_to": None, "why": "a probability"}
        for name, key, on in (
            ("read_noise_e", "read_log_bounds", self.terms.dark_current),
            ("dark_current_e_per_s", "dark_current_log_bounds", self.terms.dark_current),
            ("dsnu_e", "dsnu_log_bounds", self.terms.dsnu),
        ):
            if P[key] is not None and on:
                out[name] = {"lower": P[key][0], "upper": P[key][1], "relative_to": None, "why": "prior override"}
        return out

    def binding_bounds(self, p: dict, tol: float = 0.01, min_fraction: float = 0.05) -> dict:
        """The bounds of :meth:`parameter_bounds` the posterior presses against: those with at
        least ``min_fraction`` of the draws ``p`` (physical parameters, :meth:`physical`) within
        ``tol`` of the bound, measured as a fraction of the bounded range (in log for a range over
        a factor 10 or more, and for a bound relative to another parameter, where 1 % of the bound
        itself): ``{name: {"side": "upper"|"lower", "bound": value, "fraction_near": f}}``."""
        out = {}
        for name, b in self.parameter_bounds().items():
            if name not in p:
                continue
            x = np.asarray(p[name], float)
            lo, hi = b["lower"], b["upper"]
            scale = np.asarray(p[b["relative_to"]], float) if b["relative_to"] else 1.0
            log = b["relative_to"] is not None or (lo is not None and lo > 0 and hi / lo >= 10.0)
            for side, v in (("upper", hi), ("lower", lo)):
                if v is None:
                    continue
                edge = v * scale
                with np.errstate(divide="ignore", invalid="ignore"):
                    if log:
                        width = tol * (np.log(hi / lo) if lo is not None and lo > 0 else 1.0)
                        near = np.abs(np.log(x / edge)) <= width
                    else:
                        near = np.abs(x - edge) <= tol * (hi - lo)
                f = float(np.mean(near))
                if f >= min_fraction:
                    out[name] = {"side": side, "bound": float(np.median(edge)), "fraction_near": f}
        return out

    def log_prior(self, th):
        P = self.PRIOR
        g = lambda n: th[:, self.idx[n]]
        lk = g("log_k")
        lp = np.where((lk > P["log_k_bounds"][0]) & (lk < P["log_k_bounds"][1]), 0.0, -np.inf)
        if self.terms.dark_current:
            lp = lp + _scale_log_prior(g("log_read"), P["read_scale_e"], P["read_log_bounds"])
            lp = lp + _scale_log_prior(g("log_dc"), P["dark_current_scale_e_per_s"], P["dark_current_log_bounds"])
        else:
            lp = lp + _halfnormal_log_prior(g("log_dark_noise"), P["read_scale_e"])
        if self.terms.clip in ("adc_sampled", "well"):
            c = g("clip_dn")
            lo, hi = self.clip_bounds
            lp = lp + np.where((c > lo) & (c < hi), -np.log(hi - lo), -np.inf)
        if self.terms.clip_spread:
            cref = self._clip_reference_dn(th)
            lt = g("log_tau")
            center = np.log(0.005 * np.maximum(cref - self.black_dn, 1.0))
            lp = lp + _norm_logpdf(lt, center, P["tau_log_sd"])
            lp = lp + np.where(np.exp(lt) < self.tau_cap_dn(th), 0.0, -np.inf)
        if self.terms.quantum_efficiency:
            qe = g("qe")
            qlo, qhi = P["qe_bounds"] if P["qe_bounds"] is not None else (0.0, 1.0)
            lp = lp + np.where((qe > qlo) & (qe <= qhi), 0.0, -np.inf)
            lp = lp + _norm_logpdf(g("log_g"), np.log(P["g_center"]), P["g_log_sd"])
        if self.terms.prnu:
            lp = lp + _scale_log_prior(g("log_prnu"), P["prnu_scale"], P["prnu_log_bounds"])
        if self.terms.dsnu:
            lp = lp + _scale_log_prior(g("log_dsnu"), P["dsnu_scale_e"], P["dsnu_log_bounds"])
        for n in self.pattern_latents:
            lp = lp - 0.5 * g(n) ** 2  # standard normal (constant dropped)
        if self.terms.discrepancy:
            lp = lp + _norm_logpdf(g("log_f"), np.log(P["f_center"]), P["f_log_sd"])
        if getattr(self.terms, "nonlinearity", False):
            theta = self.response_theta(th)
            if self.n_basis == RICH_BASIS:
                # the spline's values: a random walk from L(0) = 0 with Cauchy steps of scale
                # response_step_scale: neighbouring intervals agree unless the data bend them, and
                # then a step as large as a kink's costs little (heavy tails), so a knee or a kink
                # near the top does not drag the low rows' log-slope (which pin K) with it
                steps = np.diff(theta, axis=1, prepend=0.0) / P["response_step_scale"]
                lp = lp - np.sum(np.log1p(steps * steps), axis=1)
            else:
                # independent normals shrinking the log-slope towards 0 (the linear response)
                lp = lp + np.sum(_norm_logpdf(theta, 0.0, P["response_shape_sd"]), axis=1)
            lp = lp + np.where(np.all(np.abs(theta) < SHAPE_BOUND, axis=1), 0.0, -np.inf)
        if getattr(self.terms, "brighter_fatter", False):
            b = g("bf")
            lp = lp + _norm_logpdf(b, 0.0, P["brighter_fatter_sd"]) + np.where(np.abs(b) < BF_BOUND, 0.0, -np.inf)
        if getattr(self.terms, "offset_spread", False):
            # log-uniform on [1e-3, 2] DN: as much prior mass for one offset shared by every pixel
            # (below 1e-3 DN the rounded moments do not change, relative 4e-5) as for a fully
            # averaged grid (above ~0.5 DN); no wall that binds in effect at either end
            lp = lp + _scale_log_prior(g("log_offset_dn"), None, P["offset_spread_log_bounds"])
        return lp

    # ------------------------------------------------------------------ start point
    def initial_guess(self, projections: bool = False):
        """A deterministic starting point from EMVA-1288-style linear fits (no randomness), inside
        the prior's bulk (:meth:`_project_into_prior`).

        Computed once per model (a copy returned each time): it costs ~1.3 ms with its scan of the
        clip spread, and a fast fit asks for it three times (the Newton start, the sampler
        coordinates, the observation count). With ``projections`` also the list of coordinates
        whose data-driven guess lay beyond the prior's bulk and was moved into it (dicts with
        ``parameter``, ``guess``, ``start``, ``unit``, ``prior_scale_sd``)."""
        x = self._memoized("initial_guess", self._initial_guess).copy()
        if projections:
            return x, [dict(p) for p in self._memo.get("start_projections", [])]
        return x

    #: the prior mass a start may lie beyond, per coordinate and side: the start is moved to the
    #: prior's 99.9 % quantile (0.1 % beyond). A half-normal scale is bounded above only: in log
    #: coordinates its density falls linearly towards 0 (a start far below costs a few nats) but
    #: as x² above the scale, where a start 1 000 prior sd out leaves walkers stranded
    START_TAIL_MASS = 1e-3

    def _project_into_prior(self, th: dict) -> list:
        """Move the start ``th`` (name -> sampling coordinate) into the prior's bulk, in place, and
        return what was moved: half-normal scales (read noise, dark current, dark noise, PRNU,
        DSNU) to at most their :data:`START_TAIL_MASS` upper quantile, the log-normal
        discrepancies to their central range, bounded ones strictly inside their bounds (the clip
        spread, scanned afterwards, is kept inside its prior's range by :meth:`_initial_guess`)."""
        from scipy.special import erfinv, ndtri

        P = self.PRIOR
        half_hi = float(np.sqrt(2.0) * erfinv(1.0 - self.START_TAIL_MASS))  # 3.29 scales
        z_hi = float(-ndtri(0.5 * self.START_TAIL_MASS))  # 3.29 sd
        moved = []
        scales = {
            "log_read": ("read_noise_e", "e-", P["read_scale_e"], P["read_log_bounds"]),
            "log_dark_noise": ("dark_noise_e", "e-", P["read_scale_e"], None),
            "log_dc": ("dark_current_e_per_s", "e-/s", P["dark_current_scale_e_per_s"], P["dark_current_log_bounds"]),
            "log_prnu": ("prnu_percent", "%", P["prnu_scale"], P["prnu_log_bounds"]),
            "log_dsnu": ("dsnu_e", "e-", P["dsnu_scale_e"], P["dsnu_log_bounds"]),
        }
        for name, (phys, unit, scale, bounds) in scales.items():
            if name not in th:
                continue
            if bounds is not None:
                a, b = np.log(bounds[0]), np.log(bounds[1])
                th[name] = float(np.clip(th[name], a + 1e-3 * (b - a), b - 1e-3 * (b - a)))
                continue
            hi = np.log(half_hi * scale)
            if th[name] > hi:
                f = 100.0 if name == "log_prnu" else 1.0
                moved.append(
                    {
                        "parameter": phys,
                        "guess": f * float(np.exp(th[name])),
                        "start": f * float(np.exp(hi)),
                        "unit": unit,
                        "prior_scale_sd": float(np.exp(th[name]) / scale),
                    }
                )
                th[name] = float(hi)
        for name, center, sd in (
            ("log_f", np.log(P["f_center"]), P["f_log_sd"]),
            ("log_g", np.log(P["g_center"]), P["g_log_sd"]),
        ):
            if name in th:
                th[name] = float(np.clip(th[name], center - z_hi * sd, center + z_hi * sd))
        lk0, lk1 = P["log_k_bounds"]
        th["log_k"] = float(np.clip(th["log_k"], lk0 + 1e-3 * (lk1 - lk0), lk1 - 1e-3 * (lk1 - lk0)))
        if "qe" in th and P["qe_bounds"] is not None:
            q0, q1 = P["qe_bounds"]
            th["qe"] = float(np.clip(th["qe"], q0 + 1e-3 * (q1 - q0), q1 - 1e-3 * (q1 - q0)))
        return moved

    def _initial_guess(self) -> np.ndarray:
        from scipy.special import erfinv

        tm = self.terms
        s, v = self.s_obs, self.v
        vd_ok = self.vd[~self.full_sat]
        lin = s <= 0.7 * s.max()
        if lin.sum() < 2:
            lin = np.ones_like(s, bool)
        y = v[lin] - vd_ok[lin]
        x = s[lin]
        slope = np.sum(x * y) / max(np.sum(x * x), 1e-300)
        if len(x) >= 3:
            A = np.vstack([x, np.ones_like(x)]).T
            slope = np.linalg.lstsq(A, y, rcond=None)[0][0]
        slope = slope if np.isfinite(slope) and slope > 0 else 1.0
        k0 = float(np.clip(1.0 / slope, 2e-3, 5e2))
        vd0 = float(np.median(self.vd))
        sig0_e2 = max((vd0 - 1.0 / 12.0) * k0 * k0, (0.05 * k0) ** 2)
        if vd0 < 1.0 / 12.0 + 0.25:
            # near or below the quantization floor: invert the exact rounded-normal variance at the
            # median dark row's measured offset (Sheppard's σ² + 1/12 would put σ near 0, where the
            # likelihood is flat and a local optimiser strays)
            i = int(np.argsort(self.vd)[self.vd.size // 2])
            s_grid = np.geomspace(0.03, 1.0, 200)
            frac = np.full(s_grid.size, self.dark_frac_dn[i])
            _, vg, _ = _rounded_normal_moments(_rounded_offset(frac, s_grid), s_grid)
            s0 = float(s_grid[np.argmin(np.abs(vg - vd0))])
            sig0_e2 = max((s0 * k0) ** 2, (0.05 * k0) ** 2)
        bf0 = 0.0
        if not getattr(self, "dark_rows", True) and "bf" in self.idx:
            start = self._mean_variance_start(lin)
            if start is not None:
                k0, sig0_e2, bf0 = start
        th = {"log_k": np.log(k0), "bf": bf0}
        if tm.dark_current:
            t = self.t
            if np.ptp(t) > 0:
                b = np.polyfit(t, self.vd, 1)[0] * k0 * k0
            else:
                b = 0.0
            tmax = max(t.max(), 1e-9)
            dc0 = b if b > 0 else 0.05 * sig0_e2 / tmax
            dc0 = min(dc0, 0.5 * sig0_e2 / tmax) if b <= 0 else dc0
            # the read noise from the dark current inside the prior's bulk (the charge D·t a far-tail
            # dark current would take out of the dark variance is not there either)
            dc_in = min(
                dc0, np.sqrt(2.0) * erfinv(1.0 - self.START_TAIL_MASS) * self.PRIOR["dark_current_scale_e_per_s"]
            )
            r2 = max(sig0_e2 - dc_in * np.median(t), 0.25 * sig0_e2)
            th["log_read"] = 0.5 * np.log(r2)
            th["log_dc"] = np.log(max(dc0, 1e-6))
        else:
            th["log_dark_noise"] = 0.5 * np.log(sig0_e2)
        if tm.clip in ("adc_sampled", "well"):
            lo, hi = self.clip_bounds
            if self.full_means.size:
                th["clip_dn"] = float(np.clip(self.full_means.mean(), lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo)))
            else:
                th["clip_dn"] = lo + 0.02 * (hi - lo)
        if tm.clip_spread:
            cref = th.get("clip_dn", self.adc if self.adc is not None else self.max_mean_ok)
            th["log_tau"] = np.log(max(0.005 * (cref - self.black_dn), 0.5))
        if tm.quantum_efficiency:
            x = self.mu_p[lin]
            r = np.sum(x * s[lin]) / max(np.sum(x * x), 1e-300)
            th["qe"] = float(np.clip(r * k0, 0.01, 0.99))
            th["log_g"] = np.log(0.005)
        if tm.prnu or tm.dsnu:
            dsnu_dn2 = 1e-4
            if self.spd_rows.size:
                r = self.spd_rows
                dsnu_dn2 = max(np.median(self.spd[r] - self.vd[r] / self.L_all[r]), 1e-4)
            if tm.dsnu:
                th["log_dsnu"] = 0.5 * np.log(dsnu_dn2 * k0 * k0)
            if tm.prnu:
                pr2 = 1e-6
                if self.sp_rows.size:
                    r = self.sp_rows
                    est = (self.sp[r] - v[r] / self.L_ok[r] - dsnu_dn2) / np.maximum(s[r], 1e-9) ** 2
                    pr2 = max(np.median(est), 1e-8)
                th["log_prnu"] = 0.5 * np.log(pr2)
        for n in self.pattern_latents:
            th[n] = 0.0
        if tm.discrepancy:
            th["log_f"] = np.log(0.01)
        # every coordinate inside the prior's bulk; what was moved is reported with the result
        self.__dict__.setdefault("_memo", {})["start_projections"] = self._project_into_prior(th)
        x = np.array([th.get(n, 0.0) for n in self.names], float)
        if tm.clip_spread:
            # the clip spread: a deterministic scan of log_prob over τ from 10⁻³ DN to the prior's cap.
            # Below the quantization floor the plateau variance depends on τ only for τ ≲ 0.7 DN
            # (exact rounding), flat above (Sheppard): a start in the flat part leaves the
            # optimiser there, thousands of nats below the mode
            cref = th.get("clip_dn", self.adc if self.adc is not None else self.max_mean_ok)
            hi = np.log(0.999 * self.PRIOR["tau_max_frac"] * cref)
            grid = np.linspace(np.log(1e-3), hi, 16) if hi > np.log(1e-3) else np.array([th["log_tau"]])
            cand = np.repeat(x[None, :], grid.size + 1, axis=0)
            cand[1:, self.idx["log_tau"]] = grid
            lp = self.log_prob(cand)
            if np.any(np.isfinite(lp)):
                x = cand[int(np.nanargmax(np.where(np.isfinite(lp), lp, -np.inf)))]
            # and inside the prior's bulk: within 3.29 sd of the log-normal's centre (and below the cap)
            from scipy.special import ndtri

            z = float(-ndtri(0.5 * self.START_TAIL_MASS)) * self.PRIOR["tau_log_sd"]
            center = np.log(0.005 * max(cref - self.black_dn, 1.0))
            j = self.idx["log_tau"]
            x[j] = float(np.clip(x[j], center - z, min(center + z, hi)))
        x = self._extra_starts(x, bf0)
        return x

    def _mean_variance_start(self, lin):
        """K (e⁻/DN), the dark noise² (e⁻²) and the brighter-fatter coordinate of a mean/variance
        table (no dark rows), from a quadratic fit of the temporal variance against the signal over
        the rows ``lin`` (below 70 % of the largest), weighted by 1/variance (each variance's
        sampling error is proportional to it): the read noise is the curve's intercept (read²/K² +
        1/12), K the inverse of its slope at 0 and the bend its curvature (the model's shot noise
        S/K · (e^z − 1)/z, z = 2·bf·S/S_ref, is S/K + bf·S²/(K·S_ref) to first order). A straight
        line would not do here: a brighter-fatter bend of −10 to −20 % biases its slope, and without
        dark rows nothing else gives the read noise. None where the fit is not usable (fewer than 4
        rows, a slope ≤ 0)."""
        x, y = self.s_obs[lin], self.v[lin]
        if x.size < 4:
            return None
        with np.errstate(all="ignore"):
            try:
                a2, a1, a0 = np.polyfit(x, y, 2, w=1.0 / np.maximum(y, 1e-12))
            except (np.linalg.LinAlgError, ValueError):
                return None
        if not (np.isfinite(a0) and np.isfinite(a1) and np.isfinite(a2) and a1 > 0):
            return None
        k0 = float(np.clip(1.0 / a1, 2e-3, 5e2))
        sig0_e2 = max((a0 - 1.0 / 12.0) * k0 * k0, (0.05 * k0) ** 2)
        bf0 = float(np.clip(a2 * k0 * self.response_ref_dn, -0.5 * BF_BOUND, 0.5 * BF_BOUND))
        return k0, float(sig0_e2), bf0

    def _extra_starts(self, x, bf0=0.0):
        """Start values of the response, brighter-fatter and pixel-offset terms: the response's
        log-slope from the means against the photons (:func:`~bayescap.model.response.shape_start`,
        with the responsivity it implies for QE; without photons 0, the linear response), the
        brighter-fatter coordinate ``bf0`` (0 but for a mean/variance table,
        :meth:`_mean_variance_start`), and an offset spread of 0.3 DN (mid-way between one offset
        and a fully averaged grid)."""
        x = np.array(x, float)
        if "nl_1" in self.idx:
            from bayescap.model.response import shape_start
            from bayescap.model.terms import _unclipped_rows

            d = self.data
            j = self.idx["nl_1"]
            x[j : j + self.n_basis] = 0.0
            if d.photons_per_pixel is not None:
                sig = d.mean_dn - d.dark_mean_dn
                rows = _unclipped_rows(d, self.full_sat)
                st = shape_start(
                    sig, np.asarray(d.photons_per_pixel, float), rows, self.response_ref_dn, m=self.n_basis
                )
                if st is not None:
                    x[j : j + self.n_basis] = st[0]
                    if "qe" in self.idx:
                        k0 = float(np.exp(x[self.idx["log_k"]]))
                        x[self.idx["qe"]] = float(np.clip(st[1] * k0, 0.01, 0.99))
        if "bf" in self.idx:
            x[self.idx["bf"]] = bf0
        if "log_offset_dn" in self.idx:
            x[self.idx["log_offset_dn"]] = np.log(0.3)
        return x
