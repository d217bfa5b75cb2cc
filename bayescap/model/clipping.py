"""Saturation: the moments of a clipped normal averaged over the spread of the pixel means about
the clip (closed forms), and the latent (unclipped) mean of a row near the clip, found by
inverting the clipped-mean relation with a monotone Newton iteration
(:class:`_ClipMixin`, methods of :class:`~bayescap.model.PTCModel`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import erfcx, ndtr, owens_t


def _log_shortfall(h):
    """log ψ(h), ψ(h) = h Φ(h) + φ(h): the clipped normal's shortfall below the clip in units of its
    sd, E[(c − X)⁺]/s' for X ~ N(c − h s', s'²). Written as ψ(h) = e^{−h²/2} (φ(0) + ½ h
    erfcx(−h/√2)), the form :meth:`PTCModel._latent_clip_rows` evaluates inline: its logarithm
    stays finite where ψ itself underflows (h < −38), and the bracket's cancellation for h < 0
    costs a relative error of only ~h²·1e-16 (1e-13 at h = −37); ψ = h to double precision above
    h = 30, where erfcx would overflow."""
    h = np.asarray(h, float)
    hc = np.minimum(h, 30.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = -0.5 * hc * hc + np.log(0.3989422804014327 + 0.5 * hc * erfcx(-0.7071067811865476 * hc))
    return np.where(h > 30.0, np.log(np.maximum(h, 30.0)), out)


# ψ⁻¹ tabulated on a uniform grid of log ψ from −60 (h ≈ −10.8) to 2.5 (h ≈ 12), for the first
# guess of the latent clip solver: an index computed, not searched (np.interp on a table uniform in
# h cost 80 µs for 700 elements); outside the grid the guess is the end's h, and Newton goes on
_PSI_L0, _PSI_DL = -60.0, 0.01


def _psi_inverse_table():
    h = np.linspace(-11.0, 12.5, 200001)
    L = _log_shortfall(h)
    grid = _PSI_L0 + _PSI_DL * np.arange(int(round((2.5 - _PSI_L0) / _PSI_DL)) + 1)
    return np.interp(grid, L, h)


_PSI_INV = []  # [the table], made on the first clip row solved (~15 ms: not at import)


def _psi_inverse_guess(L):
    """h with log ψ(h) ≈ L by linear interpolation in :func:`_psi_inverse_table` (clamped to its range;
    NaN gives its upper end)."""
    if not _PSI_INV:
        _PSI_INV.append(_psi_inverse_table())
    table = _PSI_INV[0]
    t = np.fmax(np.fmin((L - _PSI_L0) / _PSI_DL, table.size - 1.000001), 0.0)  # fmin: NaN → top
    i = t.astype(np.intp)
    lo = table[i]
    return lo + (t - i) * (table[i + 1] - lo)


def _ndtr_upper(x):
    """``ndtr(x)``, evaluated only where x ≤ 8.5: above, Φ(x) is 1.0 exactly (1 − Φ(8.5) = 9.5e-18
    rounds away against 1, and ``ndtr`` returns 1.0 there), so the same numbers at less cost where
    many elements lie far below the clip."""
    x = np.asarray(x, float)
    w = ~(x > 8.5)
    if w.all():
        return ndtr(x)
    out = np.ones(x.shape)
    if w.any():
        out[w] = ndtr(x[w])
    return out


def _clip_var_slope(s, tau, d):
    """The variance and the unclipped fraction Φ(h) of :meth:`_ClipMixin._clip_moments` (its
    formula, element by element the same numbers), for ``d`` = c − mu, without the clipped mean;
    also h and s'² (``s``, ``tau``, ``d`` broadcast against each other).

    More than 8.5 s' below the clip nothing is clipped to double precision: the variance is the
    temporal variance s² itself (the difference of the formula loses digits as h² grows), and Φ(h)
    is 1 exactly (1 − Φ(8.5) = 9.5e-18 rounds away against 1; ``ndtr`` returns 1.0 there). The
    special functions (``ndtr``, Owen's T at ~85 ns an element, ``exp``) are evaluated only where
    h ≤ 8.5: on a focal-plane amplifier's rows near the clip, about 40 % of the elements are above."""
    # (the operands broadcast by the ufuncs themselves: arrays of np.broadcast_arrays, strided with
    # zeros, take numpy's slow loops)
    s2 = np.asarray(s * s, float)
    sp2 = np.maximum(s2 + tau * tau, 1e-300)
    h = d / np.sqrt(sp2)
    shape = h.shape
    var = np.array(np.broadcast_to(s2, shape), dtype=float, order="C")  # a copy, also for 0-d input
    Ph = np.ones(shape)
    w = ~(h > 8.5)
    if w.all():
        hw, sp2w, tw = h, np.broadcast_to(sp2, shape), np.broadcast_to(tau, shape)
    elif w.any():
        hw, sp2w, tw = h[w], np.broadcast_to(sp2, shape)[w], np.broadcast_to(tau, shape)[w]
    else:
        return var, Ph, h, sp2
    Phw = ndtr(hw)
    phw = np.exp(-0.5 * hw * hw) * 0.3989422804014327
    rho = tw * tw / sp2w
    k = np.sqrt((1.0 - rho) / (1.0 + rho))
    P2 = Phw - 2.0 * owens_t(hw, k)
    M = (
        (hw * hw + rho) * P2
        + 2.0 * hw * phw * ndtr(hw * k)
        + np.sqrt(1.0 - rho * rho) * 0.15915494309189535 * np.exp(-hw * hw / (1.0 + rho))
    )
    vw = np.maximum(sp2w * ((hw * hw + 1.0) * Phw + hw * phw - M), 0.0)
    if w.all():
        var, Ph = np.asarray(vw, float).reshape(h.shape), np.asarray(Phw, float).reshape(h.shape)
    else:
        var[w], Ph[w] = vw, Phw
    return var, Ph, h, sp2


def _gather(a, shape, mask, flat, out):
    """``np.broadcast_to(a, shape)[mask]`` into ``out``, for an ``a`` that broadcasts to the 2-D
    ``shape``, with ``flat`` = ``np.flatnonzero(mask)``: a data row (rows,) or a per-draw column
    (n, 1) by its index instead of a boolean mask on a broadcast view (the same values)."""
    a = np.asarray(a)
    n, r = shape
    if a.shape == shape:
        np.take(a.reshape(-1), flat, out=out)
    elif a.shape in ((r,), (1, r)):
        np.take(a.reshape(-1), flat % r, out=out)
    elif a.shape == (n, 1):
        np.take(a.reshape(-1), flat // r, out=out)
    else:
        out[...] = np.broadcast_to(a, shape)[mask]
    return out


class _ClipMixin:
    """The clipped-moment methods of :class:`~bayescap.model.PTCModel` (the latent solver reads
    the model's row arrays ``m`` and ``dm``)."""

    def _clip_moments(self, mu, s, tau, c):
        """Mean, within-pixel variance and unclipped fraction of clip(N(mu + τξ, s²), c), averaged
        over the well spread ξ ~ N(0, 1), all in closed form. Shapes broadcast.

        The mean and the unclipped fraction (= dmean/dmu) are :meth:`_clip_mean`'s. The variance
        within a pixel (its temporal noise, clipped), averaged over pixels, is
        E_ξ[E_ε m²] − E_ξ[(E_ε m)²]; the first term is a clipped second moment of N(mu, s'²),
        s'² = s² + τ², and the second the clipped product moment of two readings of one pixel, a
        bivariate normal with correlation ρ = τ²/s'². With h = (c − mu)/s' and
        k = √((1 − ρ)/(1 + ρ)):

            var = s'² [(h² + 1) Φ(h) + h φ(h) − (h² + ρ) Φ₂(h, h; ρ) − 2 h φ(h) Φ(h k)
                       − √(1 − ρ²)/(2π) exp(−h²/(1 + ρ))],   Φ₂(h, h; ρ) = Φ(h) − 2 T(h, k)

        (T: Owen's T function). The 9-node Gauss–Hermite sum over ξ used before was off by
        5.3e-3 s² at τ = 2 s and 0.12 s² at τ = 10 s; this agrees with an 8 001-point sum to
        1e-10 s² for τ/s up to 100 (``tests/test_model.py``) and costs a third. Returns (mean,
        var, unclipped fraction)."""
        mu, s, tau, c = np.broadcast_arrays(mu, s, tau, c)
        d = c - mu
        var, Ph, h, sp2 = _clip_var_slope(s, tau, d)
        sp = np.sqrt(sp2)
        mean = c - d * Ph - sp * (np.exp(-0.5 * h * h) * 0.3989422804014327)  # _clip_mean's, from the same h
        return mean, var, Ph

    @staticmethod
    def _clip_mean(mu, s, tau, c):
        """Mean of clip(N(mu + τξ, s²), c) averaged over ξ ~ N(0, 1), and its derivative in mu.

        Closed form: mu + τξ + sε is N(mu, s² + τ²), and min(a, c − τξ) = min(a + τξ, c) − τξ, so
        the average is the clipped mean of N(mu, s² + τ²) and the derivative its unclipped
        fraction Φ((c − mu)/√(s² + τ²)). The 9-node Gauss–Hermite sum used before was off by
        1.3e-3 s at τ = 2 s and 0.22 s at τ = 10 s (a large well spread, a huge full well; docs/
        performance.md), and cost nine normal CDFs per element."""
        sp = np.sqrt(s * s + tau * tau)
        d = c - mu
        alpha = d / sp
        Phi = _ndtr_upper(alpha)
        phi = np.exp(-0.5 * alpha * alpha) * 0.3989422804014327
        return c - d * Phi - sp * phi, Phi

    def _latent_clip_rows(self, k, pre_var_dn2, tau, c, rows):
        """Latent unclipped row means (DN) of the clip rows: solve E[clip(μ)] = measured mean.

        The clipped quantity has variance ``(μ − dark)/K + pre_var_dn2`` (shot noise plus what
        is added before the clip). Written as its shortfall below the clip, the equation is
        ``s' ψ((c − μ)/s') = c − measured mean`` (s'² that variance plus τ², ψ of
        :func:`_log_shortfall`), and its logarithm is concave and decreasing in μ: a Newton step on
        it overshoots the root at most once, from below, and then converges from above (plain
        Newton steps on the clipped mean, used before commit d00d849, approach from below but
        crawl where the root lies deep in the clip: 12 passes on the simulated 1.75 µm sensor,
        now 4).
        The first guess inverts ψ from a table at the variance of the measured mean; steps that
        leave the bracket of the points seen so far bisect it. Returns (μ, variance of the clipped
        values, unclipped fraction = dE/dμ)."""
        m_obs = self.m[..., rows]
        dm = self.dm[..., rows]
        K = k[:, None] if np.ndim(k) == 1 else k  # per row: an effective gain (a non-linear response)
        shape = pre_var_dn2.shape
        cc, tt_ = c[:, None], tau[:, None]
        # first pass, on every element: the clipped mean at the measured mean (:meth:`_clip_mean`'s
        # formula on the broadcast arrays: the same numbers as on full copies, without making them)
        s0 = np.broadcast_to(np.sqrt(np.maximum(m_obs - dm, 0.0) / K + pre_var_dn2), shape)
        mean, _ = _ClipMixin._clip_mean(m_obs, s0, tt_, cc)
        # elements already within 1e-9 of the noise of it (the unclipped rows) stay there
        todo = ~(m_obs - mean < 1e-9 * s0)
        mu = np.array(np.broadcast_to(m_obs, shape), dtype=float, order="C")
        s_all = np.array(s0, dtype=float, order="C")
        if todo.any():
            idx = np.flatnonzero(todo)
            mu_f, s_f = mu.reshape(-1), s_all.reshape(-1)  # views (C order): updates land in mu and s_all
            # the fixed inputs of each element to solve, one row each, so that dropping the
            # converged elements is one fancy-indexing call; with the per-element constants of the
            # iteration (the measured shortfall, τ², 1e-6 of the shortfall) as rows too
            P = np.empty((9, idx.size))
            for i, a in enumerate((m_obs, dm, K, pre_var_dn2, tt_, cc)):
                _gather(a, shape, todo, idx, out=P[i])
            P_all = P
            mu_a, s = P[0].copy(), s_f[idx]
            mo_a, dm_a, k_a, pre_a, tau_a, c_a = P[:6]
            g_obs = np.subtract(c_a, mo_a, out=P[6])  # the measured shortfall (≤ 0: no root, μ → ∞)
            np.multiply(tau_a, tau_a, out=P[7])
            np.multiply(1e-6, g_obs, out=P[8])
            pos = g_obs > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                # first guess: ψ inverted at the variance of the measured mean, never below it
                sp = np.sqrt(s * s + P[7])
                guess = c_a - sp * _psi_inverse_guess(np.log(g_obs / sp))
            mu_a = np.where(pos & (guess > mu_a), guess, mu_a)
            lo, hi = mo_a.copy(), np.full(mu_a.size, np.inf)  # the clipped mean is below / above
            sub = idx
            with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
                for _ in range(30):
                    mo_a, dm_a, k_a, pre_a, tau_a, c_a, g_obs, tau2, g_tol = P
                    s = np.sqrt(np.maximum(mu_a - dm_a, 0.0) / k_a + pre_a)
                    sp = np.sqrt(s * s + tau2)
                    h = np.minimum((c_a - mu_a) / sp, 30.0)
                    hh = 0.5 * h * h  # (−0.5·h·h is −hh exactly)
                    # Φ(h) = ½ erfcx(−h/√2) e^{−h²/2} and ψ(h) = e^{−h²/2} (φ(0) + ½ h erfcx(−h/√2)):
                    # one erfcx gives both, without cancellation for h < 0 (:func:`_log_shortfall`)
                    e2 = np.exp(-hh)
                    X = erfcx(-0.7071067811865476 * h)
                    B = 0.3989422804014327 + 0.5 * h * X
                    short = sp * e2 * B
                    gap = short - g_obs  # = measured mean − clipped mean
                    # converged within 1e-9 of the noise and 1e-6 of the shortfall itself (a row
                    # deep in the clip has a shortfall far below the noise; the step taken after
                    # convergence squares that relative error)
                    tol = 1e-9 * s
                    done = np.abs(gap) < np.where(pos, np.minimum(tol, g_tol), tol)
                    below = gap > 0
                    lo = np.where(below, np.maximum(lo, mu_a), lo)
                    hi = np.where(below, hi, np.minimum(hi, mu_a))
                    # d(clipped mean)/dμ, with the growth of the shot noise with μ
                    slope = np.maximum(e2 * (0.5 * X - 0.3989422804014327 * (mu_a > dm_a) * 0.5 / (k_a * sp)), 1e-300)
                    step_lin = np.minimum(np.maximum(gap / slope, 0.0), 50.0 * (s + tau_a))
                    step_log = (np.log(B) - hh + np.log(sp / g_obs)) * short / slope
                    new = mu_a + np.where(pos, step_log, step_lin)
                    # a step from within the tolerance is taken too (it lands on the root to
                    # rounding, so the result does not depend on the pass at which an element
                    # converged); one leaving the bracket bisects it, or without an upper end takes
                    # the plain Newton step (which never passes the root)
                    out = ~((new > lo) & (new < hi)) & pos & ~done
                    new = np.where(out, np.where(hi < np.inf, 0.5 * (lo + hi), mu_a + step_lin), new)
                    mu_a = np.where(np.isfinite(new), new, mu_a)
                    if done.all():
                        break
                    if done.any():  # drop the converged elements (their last iterate written back)
                        mu_f[sub[done]] = mu_a[done]
                        keep = ~done
                        sub, mu_a, P, lo, hi, pos = sub[keep], mu_a[keep], P[:, keep], lo[keep], hi[keep], pos[keep]
                mu_f[sub] = mu_a
            # the solved elements' noise at their latent mean (the others' is s0)
            mo_a, dm_a, k_a, pre_a = P_all[:4]
            s_f[idx] = np.sqrt(np.maximum(mu_f[idx] - dm_a, 0.0) / k_a + pre_a)
        var, slope, _, _ = _clip_var_slope(s_all, tt_, cc - mu)
        return mu, var, slope
