"""The model's prediction of every observation block (:meth:`_PredictionMixin.predict`): the
Eq. 1 variances in DN, temporal and spatial apart, with the ROI's realised fixed patterns, the
rounding to integer DN and the clip near saturation.
"""

from __future__ import annotations

import numpy as np

from bayescap.model.pixel_quantization import _quantized_pixel_moments
from bayescap.model.quantization import _rounded_offset
from bayescap.model.response import _h_table, bf_factor, linearise, linearise_at, linearise_weights

#: below this s² + σ_o² (DN²) the rounded-normal moments replace Sheppard's σ² + 1/12
_QUANT_EXACT_S2 = 0.5
#: Sheppard's s² + 1/12 is the variance of rounded values over *all* offsets; a pixel's temporal
#: variance about its own mean is smaller by Q(s) = Σₖ e^{−4π²k²s²}/(2π²k²) (the rounding bias of
#: its mean, h of :func:`~bayescap.model.pixel_quantization._quantized_pixel_moments`, averaged):
#: Q < 2e-5 DN² (relative < 1e-4) only for s² ≥ 0.2 DN²
_QUANT_TEMPORAL_S2 = 0.2


def _chi2_over_nu(z, nu):
    """χ²_ν/ν as a function of a standard normal z (Wilson–Hilferty; relative error of the
    quantiles < 1e-4 for ν ≥ 10, far below the ~√(2/ν) spread it describes)."""
    a = 2.0 / (9.0 * nu)
    return np.maximum(1.0 - a + z * np.sqrt(a), 1e-3) ** 3


class _PredictionMixin:
    """:meth:`predict` and its parts, methods of :class:`~bayescap.model.PTCModel` (which sets
    the data arrays and the rows of each block they read)."""

    # ------------------------------------------------------------------ fixed patterns
    def _pattern_moments(self, th, p):
        """Sample (co)variances of the ROI's *realised* fixed patterns, for draws ``th``.

        The PRNU map p_i (fraction) and the DSNU map d_i (e⁻) are one realisation, shared by
        every spatial row. Over n pixels (ν = n − 1) their sample covariance matrix is
        Wishart(ν, diag(PRNU², DSNU²))/ν; by Bartlett's decomposition with standard-normal
        latents z₁ (``z_roi_prnu``), z₂ (``z_roi_dsnu``), z₃ (``z_roi_cross``):

            var_s(p)   = PRNU² · χ²_ν/ν (z₁)
            var_s(d)   = DSNU² · [(ν−1)·χ²_{ν−1}/(ν−1) (z₂) + z₃²]/ν
            cov_s(p,d) = PRNU·DSNU · √(χ²_ν/ν (z₁)) · z₃/√ν

        Returns (var_s(p), var_s(d) [e⁻²], cov_s(p, d) [e⁻]), each (n_draws, 1)."""
        nu = self.nu_pattern
        n = th.shape[0]
        zero = np.zeros((n, 1))
        a = b = c = zero
        if self.terms.dsnu:
            dsnu2 = (p["dsnu_e"] ** 2)[:, None]
            z2 = th[:, self.idx["z_roi_dsnu"]][:, None]
            if self.terms.prnu:
                prnu = (p["prnu_percent"] / 100.0)[:, None]
                z1 = th[:, self.idx["z_roi_prnu"]][:, None]
                z3 = th[:, self.idx["z_roi_cross"]][:, None]
                q1 = _chi2_over_nu(z1, nu)
                a = prnu**2 * q1
                # (χ²₀ = 0: with two pixels, ν = 1, the DSNU's sample variance is z₃² alone; ν is an
                # array of one per sensor in a PTCModelStack)
                rest = np.where(nu > 1.0, (nu - 1.0) * _chi2_over_nu(z2, np.maximum(nu - 1.0, 1.0)), 0.0)
                b = dsnu2 * (rest + z3 * z3) / nu
                c = prnu * np.sqrt(dsnu2) * np.sqrt(q1) * z3 / np.sqrt(nu)
            else:
                b = dsnu2 * _chi2_over_nu(z2, nu)
        return a, b, c

    def _quantized_var(self, s2, frac, spread2):
        """Quantization of the temporal variance, and of the fixed pattern, for every draw and row.

        ``s2`` (n_draws, rows): temporal variance before rounding (DN²); ``frac`` (rows,): the
        measured mean's offset from the nearest integer DN; ``spread2`` (n_draws, 1 or rows):
        variance σ_o² of the per-pixel mean offsets (fixed patterns, well spread).

        Returns ``(var, phi, excess)``: the pixel-averaged temporal variance of the rounded values,
        the factor φ of its sampling variance (relative variance of a pair estimate over n pixels
        = φ/ν; 2 for a normal), and the excess of the per-pixel means' spatial variance over σ_o²
        that rounding adds (what a spatial variance of frame averages sees besides σ_o²).
        Sheppard's s² + 1/12, φ = 2 and no excess where s² ≥ 0.2 DN² and s² + σ_o² ≥ ½ DN²
        (relative errors < 3e-4, below the ≥ 0.4 % sampling error of a variance over ≤ 10⁵
        pixels); elsewhere the exact moments of :func:`_quantized_pixel_moments`."""
        var = s2 + 1.0 / 12.0
        if np.ndim(spread2) == 0:  # one σ_o² for all (0 without patterns): s² + σ_o² as a scalar sum
            sp2 = max(float(spread2), 0.0)
            need = (s2 < _QUANT_TEMPORAL_S2) | (s2 + sp2 < _QUANT_EXACT_S2)
            if not np.any(need):  # Sheppard everywhere: φ = 2 and no excess (read-only views)
                return var, np.broadcast_to(2.0, var.shape), np.broadcast_to(0.0, var.shape)
            sp2 = np.full(s2.shape, sp2)
        elif s2.size and s2.min() >= _QUANT_EXACT_S2:
            # every s² + σ_o² ≥ s² ≥ ½ DN² (σ_o² ≥ 0): Sheppard everywhere, as below, without the
            # σ_o² array (NaN s² takes the path below, where it needs nothing either)
            return var, np.broadcast_to(2.0, var.shape), np.broadcast_to(0.0, var.shape)
        else:
            sp2 = np.maximum(np.broadcast_to(spread2, s2.shape), 0.0)
            need = (s2 < _QUANT_TEMPORAL_S2) | (s2 + sp2 < _QUANT_EXACT_S2)
        phi = np.full_like(var, 2.0)
        excess = np.zeros_like(var)
        if not np.any(need):
            return var, phi, excess
        s = np.sqrt(np.maximum(s2[need], 1e-8))
        so = np.sqrt(sp2[need])
        fr = np.broadcast_to(frac, s2.shape)[need]
        delta = _rounded_offset(fr, np.sqrt(s * s + so * so))
        V, E4, H = _quantized_pixel_moments(delta, s, so)
        # the measured variances are floored at 1e-6 DN² (a sample with no differing pixel): so is
        # the model, which otherwise penalises a ratio 1e-6/1e-12 for identical "zero" data
        # At the floor the moments are the floor's: φ is the normal's 2 there, as E4/(2·floor²) would
        # fall with the noise and reward ever smaller noise through the gamma's normalisation
        floored = V < 1e-6
        V = np.maximum(V, 1e-6)
        var[need] = V
        phi[need] = np.where(floored, 2.0, E4 / (2.0 * V * V))
        excess[need] = H
        return var, phi, excess

    # ------------------------------------------------------------------ prediction
    def predict(self, th):
        """Model predictions per observation block, for draws ``th`` (n, ndim).

        Returns ``{block: (observed, model, spread, kind)}``: for ``kind == "gamma"`` the
        spread is the shape ``k`` (the observed value ~ Gamma(k, model/k)); for
        ``"normal"`` it is the standard deviation. Blocks: ``dark_var`` (every row),
        ``bright_var`` and ``mean`` (rows not fully clipped), ``clip_mean`` (fully clipped rows,
        sampled clip), ``spatial_var``/``dark_spatial_var`` (rows with spatial columns),
        ``dark_mean`` (every row, where the dark means' ramp enters: :mod:`bayescap.model.dark_ramp`),
        ``saturated`` (rows near an ADC clip with ``frac_saturated``: kind ``"upper_probit"``, the
        spread the probit tolerance; the model's clipped fraction may not exceed the measured one)."""
        p = self.physical(th, derived=False)
        k = p["conversion_gain_e_per_dn"]
        K = k[:, None]
        K2 = K * K
        if self.terms.discrepancy:
            f2 = np.exp(2.0 * th[:, self.idx["log_f"]])[:, None]
        else:
            f2 = np.zeros((th.shape[0], 1))
        rd2_ok = self.dark_var_e2(p, self.tt)  # (n, rows)
        rd2_all = self.dark_var_e2(p, self.t)
        out = {}
        pa, pb, pc = self._pattern_moments(th, p)  # realised ROI patterns (zeros without the terms)
        pbk = pb / K2  # the DSNU's realised pattern in DN²
        # spread of the pixels' mean offsets about the DN grid not described by the patterns
        # (fitted when no spatial column tells it, see select_terms)
        so2 = p["pixel_offset_spread_dn"][:, None] ** 2 if "pixel_offset_spread_dn" in p else 0.0
        # dark temporal variances (all rows); rounding at the measured offset below 1 DN
        if getattr(self, "dark_rows", True):  # (a mean/variance table has no dark pairs)
            vdm, phi_d, hd = self._quantized_var(rd2_all / K2, self.dark_frac_dn, pbk + so2)
            out["dark_var"] = (self.vd, vdm, 1.0 / (phi_d / self.nu_d + f2), "gamma")
        if getattr(self.terms, "dark_mean", False):  # the dark means' ramp, the black level profiled
            slope = (p["dark_current_e_per_s"] / k)[:, None]
            out["dark_mean"] = (self.dmn, self.dmn_mbar + slope * self.dmn_tc, self.dmn_sd, "normal")
        # bright temporal variances, unclipped rows: S from the measured mean
        S = np.broadcast_to(self.s_obs, rd2_ok.shape).copy()
        bent = getattr(self.terms, "nonlinearity", False)
        bf = getattr(self.terms, "brighter_fatter", False)
        theta = self.response_theta(th) if bent else None
        if bent:
            # the response (bayescap.model.response): x = h(S), g'(x) = 1/h'(S); shot noise
            # g'(x)²·x/K, patterns g'(x)·x
            table = _h_table(theta)  # one per call: the clipped rows' latent signals below use it too
            if np.ndim(self.s_obs) == 1:  # the measured signals' interpolation weights, once per model
                w = self._memoized("linearise_weights", lambda: linearise_weights(self.s_obs, self.response_ref_dn))
                x_lin, hp = linearise_at(w, table, self.response_ref_dn)
            else:  # (a stacked view: every draw its sensor's signals)
                x_lin, hp = linearise(S, theta, self.response_ref_dn, table=table)
            Sx = x_lin / hp
            shot = np.where(x_lin > 0, Sx / hp, S) / K
        else:
            # (the measured signal broadcast by the ufuncs: the same numbers as from the copy S)
            x_lin, Sx, shot = S, S, self.s_obs / K
        if bf:
            # brighter-fatter (Astier et al. 2019 Eq. 16): the charge's variance (e^{2a₀₀μ} − 1)/(2a₀₀)
            xp = np.maximum(x_lin if bent else self.s_obs, 0.0)
            z = 2.0 * th[:, self.idx["bf"]][:, None] * xp / self.response_ref_dn
            shot = shot * bf_factor(z)
        shaped = bent or bf
        if self.terms.prnu or self.terms.dsnu or "pixel_offset_spread_dn" in p:
            spread2 = pa * Sx * Sx + pbk + 2.0 * pc * Sx / K + so2
        else:  # no fixed pattern and no offset spread: σ_o² is 0 (as the sum of zeros above)
            spread2 = 0.0
        vm, phi_b, hb = self._quantized_var(shot + rd2_ok / K2, self.bright_frac_dn, spread2)
        slope = np.ones_like(vm)
        if self.clip_rows.size:
            c = p["clip_dn"]
            tau = p["clip_spread_dn"]
            # rows more than 8.5 sd of N(mean, s² + τ²) below the clip for every draw are unclipped
            # to double precision (_clip_mean): keep only the others. (The rule of the 9-node
            # quadrature, 8.5 s + 4.52 τ, let rows with τ ≫ s in at h ≈ 4.5: a clipped fraction 3e-6)
            # (bounds over each sensor's draws: over all draws here, per request in a PTCModelStack)
            k_min, c_min, tau_max = (
                self._per_draw(self._request_reduce(f, a))
                for f, a in ((np.minimum, k), (np.minimum, c), (np.maximum, tau))
            )
            cr = self.clip_rows
            s_est = np.sqrt(self.v[..., cr] + self.s_obs[..., cr] / k_min)
            alpha_min = (c_min - self.m[..., cr]) / np.sqrt(s_est**2 + tau_max**2)
            need = alpha_min < 8.5
            needed = need if need.ndim == 1 else need.any(axis=0)
            rows = cr[needed]
        if self.clip_rows.size and rows.size:
            # stacked sensors: a row one sensor needs is computed for all, kept where needed
            keep = None if need.ndim == 1 else need[:, needed]
            keep = None if keep is None or keep.all() else keep
            put = (lambda new, old: new) if keep is None else (lambda new, old: np.where(keep, new, old))
            if self.terms.clip == "well":
                # the well clips the collected charge; read noise and quantization come after
                dc_e2 = (
                    p["dark_current_e_per_s"][:, None] * self.tt[..., rows]
                    if self.terms.dark_current
                    else np.zeros((k.size, rows.size))
                )
                pre = dc_e2 / K2
                post = (rd2_ok[:, rows] - dc_e2) / K2 + 1.0 / 12.0
                mu, var_c, sl = self._latent_clip_rows(
                    self._clip_gain(k, S, shot if shaped else None, rows), pre, tau, c, rows
                )
                vm[:, rows] = put(var_c + post, vm[:, rows])
            else:
                # the ADC clips everything; quantization survives only for the unclipped pixels
                mu, var_c, sl = self._latent_clip_rows(
                    self._clip_gain(k, S, shot if shaped else None, rows), rd2_ok[:, rows] / K2, tau, c, rows
                )
                vm[:, rows] = put(var_c + sl / 12.0, vm[:, rows])
            S[:, rows] = put(mu - self.dm[..., rows], S[:, rows])
            if bent:  # the latent signal's linearisation, for the means
                xr, hr = linearise(S[:, rows], theta, self.response_ref_dn, table=table)
                x_lin, hp = x_lin.copy(), hp.copy()
                x_lin[:, rows], hp[:, rows] = xr, hr
            slope[:, rows] = put(sl, slope[:, rows])
        out["bright_var"] = (self.v, np.maximum(vm, 1e-12), 1.0 / (phi_b / self.nu + f2), "gamma")
        if getattr(self, "sat_rows", np.zeros(0)).size:
            # the fraction of one frame's pixel values at the ADC maximum, 1 − the unclipped fraction:
            # the measured one bounds it from above (_block_loglik, kind "upper_probit")
            r = self.sat_rows
            out["saturated"] = (self.sat_fs[..., r], 1.0 - slope[:, r], self.sat_sd[..., r], "upper_probit")
        self._last_latent_signal_dn = S
        if self.terms.quantum_efficiency:
            qe = p["quantum_efficiency"][:, None]
            g2 = p["mean_discrepancy"][:, None] ** 2
            s_model = qe * self.mu_p / K
            if bent:
                # g(x) by one Newton step from the row's (latent) signal S, whose h(S) and h'(S) are
                # at hand: exact to second order in the residual (a relative error of ~ the residual
                # times the response's relative curvature, far below the means' scatter)
                s_model = S + (s_model - x_lin) / hp
            m_err2 = (self.v + self.vd_ok) / (self.nu + 1.0) + self.mean_rounding_var
            sd = np.sqrt(g2 * s_model**2 + m_err2 / np.maximum(slope, 1e-6) ** 2)
            out["mean"] = (S, s_model, sd, "normal")
        if self.terms.clip == "well" and self.full_means.size:
            # plateau rows: charge at the (spread) well; read noise and quantization remain
            post_full = self.dark_var_e2(p, self.t_full)
            if self.terms.dark_current:
                post_full = post_full - p["dark_current_e_per_s"][:, None] * self.t_full
            tau_full = np.broadcast_to(p["clip_spread_dn"][:, None], post_full.shape)
            # rounding of the plateau values: exact below the quantization floor (offsets spread by
            # the well spread τ), Sheppard above
            vfull, phi_pl, _ = self._quantized_var(post_full / K2, self.full_frac_dn, tau_full**2)
            cmean = np.broadcast_to(p["clip_dn"][:, None], vfull.shape)
            if self.adc is not None:
                # the ADC clips the plateau's read noise too (wells just below the ADC maximum):
                # moments of clip(N(c + τξ, σ²_post), ADC) over the well spread ξ
                cm, cv, unclipped = self._clip_moments(
                    np.array(cmean),
                    np.sqrt(post_full) / K,
                    tau_full,
                    np.broadcast_to(self._per_draw(self.adc), vfull.shape).astype(float),
                )
                # only where the ADC clips a measurable part (keeps the exact rounding otherwise)
                clipped = unclipped < 1.0 - 1e-9
                vfull = np.where(clipped, cv + unclipped / 12.0, vfull)
                cmean = cm
            out["plateau_var"] = (
                np.maximum(self.full_v, 1e-6),
                np.maximum(vfull, 1e-6),
                1.0 / (phi_pl / self.full_nu + f2),
                "gamma",
            )
        else:
            cmean = None
        if self.terms.clip in ("adc_sampled", "well") and self.full_means.size:
            if cmean is None:
                cmean = np.broadcast_to(p["clip_dn"][:, None], (k.size, self.full_means.size))
            out["clip_mean"] = (self.full_means, cmean, np.atleast_2d(self.full_sd), "normal")
        # spatial variances of L-frame averages: the ROI's realised pattern P (the same in every
        # row, see _pattern_moments) plus the averaged temporal noise T. Given the pattern, only
        # T's sample variance and its sample covariance with the pattern scatter:
        # var = (2T² + 4PT)/ν (+ f² relative)
        if self.sp_rows.size:
            r = self.sp_rows
            Sr = S[:, r]
            # realised pattern, plus what rounding adds to it below the quantization floor
            Sxr = Sx[:, r] if bent else Sr
            P = pa * Sxr * Sxr + pbk + 2.0 * pc * Sxr / K + hb[:, r]
            out["spatial_var"] = self._spatial_block(
                self.sp[..., r], P, vm[:, r], self.L_ok[..., r], self.v[..., r], self.nu[..., r], f2, phi_b[:, r]
            )
        if self.spd_rows.size:
            r = self.spd_rows
            P = pbk + hd[:, r]
            out["dark_spatial_var"] = self._spatial_block(
                np.maximum(self.spd[..., r], 1e-9),
                P,
                vdm[:, r],
                self.L_all[..., r],
                self.vd[..., r],
                self.nu_d[..., r],
                f2,
                phi_d[:, r],
            )
        return out

    @staticmethod
    def _clip_gain(k, S, shot, rows):
        """The gain the clip rows' latent solver uses for their shot noise: K itself for a linear
        response, else the effective K·S/(g'²·x) at the measured signal (the response's bend of the
        shot noise, evaluated at the measured mean, where the latent mean lies within the clip's
        roll-off)."""
        if shot is None:
            return k
        keff = S[:, rows] / np.maximum(shot[:, rows], 1e-300)
        lin = k[:, None] * np.ones_like(keff)
        return np.where(S[:, rows] > 0, keff, lin)

    @classmethod
    def _spatial_block(cls, obs, P, v1, L, v_pair, nu, f2, phi=2.0):
        """The spatial-variance block of L-frame averages: pattern P plus temporal part T = v₁/L
        (v₁ the one-frame temporal variance, φ the factor of its pair estimate's sampling variance,
        2 for a normal: the rounded values of noise below a DN are far from normal, and their fourth
        cumulant κ₄ = (2φ − 4)·v₁² widens every sample variance below).

        L ≥ 2 frames averaged are independent of the pair difference, and the average's fourth
        cumulant is κ₄/L³: Var(s²_T) = (2 + (2φ − 4)/L)·T²/ν. A single frame (L = 1) is the pair's
        first frame A, whose noise the pair's temporal estimate s²_D (D = (A − B)/√2) shares:
        Var(s²_A) = (2φ − 2)·T²/ν, Cov(s²_A, s²_D) = (φ − 1)·T²/ν, Var(s²_D) = φ·T²/ν, so given the
        measured s²_D the spatial variance has mean P + T + (1 − 1/φ)(s²_D − T) and variance
        ((2φ − 2) − (φ − 1)²/φ)·T²/ν + 4PT/ν (for a normal, P + T + (s²_D − T)/2 and (1.5 T² + 4PT)/ν)."""
        T = v1 / L
        phi = np.maximum(np.broadcast_to(phi, np.shape(T)), 1.0)  # φ ≥ 1: a variance's variance ≥ 0
        shape = cls._pattern_shape(P, T, nu, f2, 2.0 + (2.0 * phi - 4.0) / L)
        one = L == 1
        if not np.any(one):
            return obs, np.maximum(P + T, 1e-12), shape, "gamma"
        Pp = np.maximum(P, 0.0)
        mean_c = Pp + T + (1.0 - 1.0 / phi) * (v_pair - T)
        mean_c = np.maximum(mean_c, 1e-12)
        rel_c = ((2.0 * phi - 2.0 - (phi - 1.0) ** 2 / phi) * T * T + 4.0 * Pp * T) / (nu * mean_c**2)
        mean = np.where(one, mean_c, P + T)
        shape = np.where(one, 1.0 / (rel_c + f2), shape)
        return obs, np.maximum(mean, 1e-12), shape, "gamma"

    @staticmethod
    def _pattern_shape(P, T, nu, f2, rel_t=2.0):
        """Gamma shape of a spatial variance given the realised pattern P and temporal part T, whose
        sample variance has relative variance ``rel_t``/ν (2 for a normal)."""
        P = np.maximum(P, 0.0)
        rel = (rel_t * T * T + 4.0 * P * T) / (nu * (P + T) ** 2)
        return 1.0 / (rel + f2)
