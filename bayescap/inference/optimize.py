"""The posterior's mode and a self-consistent Laplace covariance there: BFGS (:func:`find_map`,
:func:`find_map_scaled`) with :func:`polish_map`, and :func:`laplace_start`, the multi-start
shared by the fast path and the MCMC, which runs Newton's method (:mod:`bayescap.inference.newton`)
by default and the BFGS route on request."""

from __future__ import annotations

import time
import warnings

import numpy as np

from bayescap.inference.curvature import _proposal_cov, laplace_covariance, refine_covariance
from bayescap.inference.newton import newton_map
from bayescap.inference.starts import _map_starts, _no_finite_start, _restart_points
from bayescap.model import PTCModel


def _vectorised_grad(model: PTCModel, x, h=1e-5):
    """log-prob and its gradient by central differences, in one vectorised call."""
    n = x.size
    step = h * np.maximum(1.0, np.abs(x))
    pts = np.vstack([x, x + np.diag(step), x - np.diag(step)])
    lp = model.log_prob(pts)
    g = (lp[1 : n + 1] - lp[n + 1 :]) / (2 * step)
    return lp[0], g


#: :func:`_bfgs` stops once this many consecutive evaluations have not lowered the best value by
#: more than :data:`BFGS_STALL_NATS`. The finite-difference gradient carries the ~1e-5 jitter of
#: ``log_prob``, so ``gtol`` is never met: measured on 58 optimiser runs (29 sensors × 2 starts),
#: BFGS was within 1e-3 nats of its final value after 40 % of its evaluations and spent the rest in
#: failing line searches. Runs stalled for up to 13 evaluations and then climbed on (by up to 212
#: nats), so the window is 20: the value reached then differed from the full run's by ≤ 1e-4 nats
#: on all 58, with 41 % fewer evaluations.
BFGS_STALL_EVALS = 20


BFGS_STALL_NATS = 1e-3


class _Stalled(Exception):
    pass


def _bfgs(fun, x0):
    """``scipy.optimize.minimize(method="BFGS")`` on ``fun`` (value and gradient), stopped early
    when the value stalls (:data:`BFGS_STALL_EVALS`); returns (x, value): the best point seen when
    stopped early, scipy's result otherwise."""
    best = [np.inf, np.array(x0, float), 0]

    def watched(x):
        v, g = fun(x)
        if v < best[0] - BFGS_STALL_NATS:
            best[:] = [v, np.array(x, float), 0]
        else:
            if v < best[0]:
                best[0], best[1] = v, np.array(x, float)
            best[2] += 1
            if best[2] >= BFGS_STALL_EVALS:
                raise _Stalled
        return v, g

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from scipy import (
            optimize,  # here: it takes ~0.1 s to import, and Newton is the default
        )

        try:
            res = optimize.minimize(watched, x0, jac=True, method="BFGS", options=dict(maxiter=2000, gtol=1e-6))
        except _Stalled:
            return best[1], best[0]
    return res.x, res.fun  # ran to its own end: as scipy returns it


def find_map(model: PTCModel, x0=None, *, n_restarts: int = 2):
    """Maximum a posteriori point by L-BFGS on the unconstrained coordinates.

    Deterministic: starts from :meth:`PTCModel.initial_guess` and from fixed perturbations of
    it, keeps the best. Returns (x_map, log_prob_map)."""
    x0 = model.initial_guess() if x0 is None else np.asarray(x0, float)

    def fun(x):
        lp, g = _vectorised_grad(model, x)
        if not np.isfinite(lp):
            return 1e300, np.zeros_like(x)
        g = np.where(np.isfinite(g), g, 0.0)
        return -lp, -g

    starts = [x0] + _restart_points(x0, n_restarts)
    best = None
    for s in starts:
        if not np.isfinite(model.log_prob(s[None])[0]):
            continue
        x, v = _bfgs(fun, s)
        if best is None or v < best[1]:
            best = (x, v)
    if best is None:
        _no_finite_start(model, x0)
    return best[0], -best[1]


def polish_map(model, x, cov, *, max_iter=30, h=0.02):
    """Gradient ascent in whitened coordinates from ``x`` (a MAP estimate) with covariance ``cov``.

    :func:`find_map` (BFGS on central differences with 1e-5 relative steps) can
    stop at its starting point when ``log_prob`` jitters at the 1e-5–1e-4 level (the
    latent-mean Newton iteration stops at a tolerance): measured on a simulated 12-bit sensor,
    it returned the initial guess 115 below the maximum in log posterior. Here the gradient is
    taken with steps of ``h`` posterior sd along the Cholesky axes of ``cov`` (far above the
    jitter), and a line search over 15 step lengths runs in one vectorised call; the covariance
    is refreshed by one :func:`refine_covariance` iteration per step. When ``x`` is already the
    maximum this costs two ``log_prob`` calls. Returns (x, log_prob(x), cov).
    """
    n = x.size
    with np.errstate(all="ignore"):
        lp = float(model.log_prob(x[None])[0])
    ts = np.concatenate([2.0 ** -np.arange(0, 12), [1.5, 2.0, 3.0]])
    for _ in range(max_iter):
        L = np.linalg.cholesky(cov)
        E = h * L.T
        with np.errstate(all="ignore"):
            v = model.log_prob(np.vstack([x + E, x - E]))
            g = (v[:n] - v[n:]) / (2 * h)
        g = np.where(np.isfinite(g), g, 0.0)
        cand = x + (ts[:, None] * g[None, :]) @ L.T
        with np.errstate(all="ignore"):
            lc = model.log_prob(cand)
        lc = np.where(np.isfinite(lc), lc, -np.inf)
        j = int(np.argmax(lc))
        if not lc[j] > lp + 1e-6:
            break
        x, lp = cand[j], float(lc[j])
        cov = refine_covariance(model, x, cov, max_iter=1)
    return x, lp, cov


def find_map_scaled(model: PTCModel, x0=None, *, h: float = 1e-3):
    """MAP by BFGS in coordinates scaled by the curvature at the start: ``x = x0 + D y`` with
    ``D_i = (−∂²log p/∂x_i²)^(−1/2)`` from one vectorised call of ``2n + 1`` points (relative step
    ``h``), capped at 1 (a log unit). In the raw coordinates the clip level (thousands of DN) and
    the log scales differ by 10³-10⁵ in curvature, and BFGS's first step, the raw gradient, can
    leave the support: on two simulated Gpixel ROIs it then stopped after 0 iterations, 60 nats
    below the mode. Returns (x, log_prob(x))."""
    x0 = model.initial_guess() if x0 is None else np.asarray(x0, float)
    n = x0.size
    step = h * np.maximum(1.0, np.abs(x0))
    with np.errstate(all="ignore"):
        lp = model.log_prob(np.vstack([x0, x0 + np.diag(step), x0 - np.diag(step)]))
        hd = (lp[1 : n + 1] + lp[n + 1 :] - 2.0 * lp[0]) / step**2
    D = np.where(np.isfinite(hd) & (hd < 0), 1.0 / np.sqrt(np.abs(hd)), 1.0)
    D = np.clip(D, 1e-8, 1.0)

    def fun(y):
        lpv, g = _vectorised_grad(model, x0 + D * y)
        if not np.isfinite(lpv):
            return 1e300, np.zeros_like(y)
        return -lpv, -np.where(np.isfinite(g), g, 0.0) * D

    y, v = _bfgs(fun, np.zeros(n))
    return x0 + D * y, -float(v)


def _refine_and_polish(target, x_map, lp_map, refine_iter, polish):
    """Laplace covariance at an optimum, refined in whitened coordinates, then :func:`polish_map`
    (and a second refinement when the polish climbs). Returns (x, log p, covariance)."""
    cov = laplace_covariance(target, x_map)
    cov = refine_covariance(target, x_map, cov, max_iter=refine_iter)
    if polish:
        x_pol, lp_pol, cov_pol = polish_map(target, x_map, cov)
        if lp_pol > lp_map + 1e-6:
            x_map, lp_map = x_pol, lp_pol
            cov = refine_covariance(target, x_map, cov_pol, max_iter=refine_iter)
    return x_map, lp_map, cov


#: the optimiser of :func:`laplace_start`: ``"newton"`` (:func:`newton_map`) or ``"bfgs"``
#: (:func:`find_map` / :func:`find_map_scaled`, then :func:`refine_covariance` and
#: :func:`polish_map`: kept for comparison in the benchmarks).
LAPLACE_OPTIMIZER = "newton"


def laplace_start(
    model: PTCModel,
    *,
    n_restarts: int = 2,
    refine_iter: int = 6,
    polish: bool = True,
    multi_start: bool = True,
    coords=None,
    polish_both: bool = False,
    optimizer: str | None = None,
):
    """MAP and a self-consistent Laplace covariance: where both the MCMC walkers and the fast path's
    importance proposals start.

    With ``optimizer="newton"`` (the default, :data:`LAPLACE_OPTIMIZER`): :func:`newton_map` from
    the initial guess, ``n_restarts`` fixed perturbations of it (:func:`find_map`'s) and, with
    ``multi_start``, the starts of :func:`_map_starts`, all at once; the highest end point and its
    covariance are returned. With ``coords`` the starts are mapped by ``start_from_x`` and Newton
    runs in those coordinates; with ``polish_both`` it runs in the model's coordinates first and
    again in ``coords`` from there. ``refine_iter`` and ``polish`` apply to the BFGS route only
    (Newton's covariance is self-consistent by its stopping rule).

    With ``optimizer="bfgs"``: :func:`find_map` (BFGS, ``n_restarts`` extra starts) and, with ``multi_start``,
    :func:`find_map_scaled` from the starts of :func:`_map_starts`; each optimum not within 2 sd of
    one already refined gets :func:`laplace_covariance`, then
    :func:`refine_covariance` in whitened coordinates and :func:`polish_map` from there (with a
    second refinement when the polish climbs); the highest is returned. Walkers drawn from the raw covariance (eigenvalue
    floor, sd capped at 1 in log units) landed in regions of negligible mass on simulated sensors
    (e.g. 55-74 of 80 walkers per ensemble on the 2.80 µm benchmark sensor needed moving in burn-in;
    none with this start on two of three sensors). Returns (x_map, lp_map, cov, seconds spent in
    :func:`find_map`).

    ``coords``: other coordinates for the refinement (an object with ``log_prob``, ``ndim`` and
    ``start_from_x(x)``, e.g. :class:`SamplerCoordinates`). The optimisers still run
    on ``model``; each optimum is mapped by ``start_from_x`` and the covariance, polish and the
    returned (point, log p, covariance) are in those coordinates, log p with their Jacobian. With
    ``polish_both`` each optimum is first refined and polished in the model's coordinates, then in
    ``coords`` (twice the work; :func:`bayescap.inference.fast.fast_posterior` does this on its retry)."""
    optimizer = LAPLACE_OPTIMIZER if optimizer is None else optimizer
    if optimizer == "newton":
        return _laplace_start_newton(model, n_restarts, multi_start, coords, polish_both)
    if optimizer != "bfgs":
        raise ValueError(f"optimizer must be 'newton' or 'bfgs', not {optimizer!r}")
    target = model if coords is None else coords
    t_map = 0.0
    found = []
    t0 = time.perf_counter()
    found.append(find_map(model, n_restarts=n_restarts))
    t_map += time.perf_counter() - t0
    if multi_start:
        for x0 in _map_starts(model):
            t0 = time.perf_counter()
            x, lp = find_map_scaled(model, x0)
            t_map += time.perf_counter() - t0
            if np.isfinite(lp):
                found.append((x, lp))
    best = None
    done = []  # (x, Cholesky factor of its covariance) of the optima refined so far
    for x_map, lp_map in sorted(found, key=lambda r: -r[1]):
        if coords is not None and polish_both:
            x_map, lp_map, _ = _refine_and_polish(model, x_map, lp_map, refine_iter, polish)
        if coords is not None:
            x_map = coords.start_from_x(x_map)
            with np.errstate(all="ignore"):
                lp_map = float(coords.log_prob(x_map[None])[0])
        # within 2 posterior sd (Mahalanobis, that optimum's covariance) of one already refined:
        # the same mode, and polishing it again would only cost time
        if any(np.sum(np.linalg.solve(L, x_map - x) ** 2) < 4.0 for x, L in done):
            continue
        x_map, lp_map, cov = _refine_and_polish(target, x_map, lp_map, refine_iter, polish)
        try:
            done.append((x_map, np.linalg.cholesky(_proposal_cov(cov, 1.0))))
        except np.linalg.LinAlgError:
            pass
        if best is None or lp_map > best[1]:
            best = (x_map, lp_map, cov)
    return best[0], best[1], best[2], t_map


def _laplace_start_newton(model, n_restarts, multi_start, coords, polish_both):
    """:func:`laplace_start` with :func:`newton_map` (see there). The fourth value returned is the
    time of the whole start (the MAP and the covariance come out of the same iterations)."""
    t0 = time.perf_counter()
    x0 = np.asarray(model.initial_guess(), float)
    starts = [x0] + _restart_points(x0, n_restarts) + (_map_starts(model, x0) if multi_start else [])
    if coords is not None and polish_both:
        starts = [o.x for o in newton_map(model, starts)[0]]
    target = model
    if coords is not None:
        starts = [coords.start_from_x(s) for s in starts]
        target = coords
    ends, _ = newton_map(target, starts)
    best = max(ends, key=lambda o: o.lp)
    return best.x, best.lp, best.cov, time.perf_counter() - t0
