"""The posterior's mode and curvature: BFGS and Newton optimisers, the Laplace covariance, its
refinement and the multi-start Laplace start shared by the fast path and the MCMC."""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from bayescap.model import PTCModel


def _vectorised_grad(model: PTCModel, x, h=1e-5):
    """log-prob and its gradient by central differences, in one vectorised call."""
    n = x.size
    step = h * np.maximum(1.0, np.abs(x))
    pts = np.vstack([x, x + np.diag(step), x - np.diag(step)])
    lp = model.log_prob(pts)
    g = (lp[1:n + 1] - lp[n + 1:]) / (2 * step)
    return lp[0], g


#: :func:`_bfgs` stops once this many consecutive evaluations have not lowered the best value by
#: more than :data:`BFGS_STALL_NATS`. The finite-difference gradient carries the ~1e-5 jitter of
#: ``log_prob``, so ``gtol`` is never met: measured on 58 optimiser runs (29 sensors × 2 starts),
#: BFGS was within 1e-3 nats of its final value after 40 % of its evaluations and spent the rest in
#: failing line searches. Runs stalled for up to 13 evaluations and then climbed on (by up to 212
#: nats), so the window is 20: the value reached then differed from the full run's by ≤ 1e-4 nats
#: on all 58, with 41 % fewer evaluations (docs/performance.md, "fewer evaluations in the start").
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
    return res.x, res.fun             # ran to its own end: as scipy returns it


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


def laplace_covariance(model: PTCModel, x, h=1e-4):
    """Inverse of the negative Hessian of log-prob at ``x`` (finite differences, one
    vectorised call), made positive definite by eigenvalue clipping.

    Central differences on ``n² + n + 1`` points: ``x``, ``x ± e_i`` and ``x ± (e_i + e_j)``
    (``i < j``), with ``e_i`` the step ``h·max(1, |x_i|)`` along axis ``i``::

        H_ii = [f(+i) − 2 f(0) + f(−i)] / e_i²
        H_ij = [f(+i+j) + f(−i−j) − f(+i) − f(−i) − f(+j) − f(−j) + 2 f(0)] / (2 e_i e_j)

    (Abramowitz & Stegun 25.3.23/25.3.27; both exact for a quadratic, error O(e²)). The four-point
    stencil ``f(x±e_i±e_j)`` used before 2026-11-23 took ``2n² + 2n`` points (144 for n = 8, 73
    now), a third of the fast path's ``log_prob`` points (docs/performance.md, "2026-11-23 (day)")."""
    step = h * np.maximum(1.0, np.abs(x))
    Y, iu, ju = _unit_stencil(x.size)
    with np.errstate(all="ignore"):   # the stencil may leave the prior support: -inf, handled below
        H = _stencil_derivatives(model.log_prob(x + Y * step), step, iu, ju)[2]
    if not np.all(np.isfinite(H)):
        return np.diag(np.full(x.size, 1e-4))
    return _clipped_inverse(H)


class _Whitened:
    """``log_prob`` in coordinates ``y`` with ``x = x0 + L y`` (for a well-conditioned Hessian)."""

    def __init__(self, model, x0, L):
        self.model, self.x0, self.L, self.ndim = model, x0, L, model.ndim

    def log_prob(self, y):
        with np.errstate(all="ignore"):
            return self.model.log_prob(self.x0 + np.atleast_2d(y) @ self.L.T)


def refine_covariance(model, x_map, cov, *, max_iter=6, alpha=4.0, h=0.05):
    """Re-evaluate the Laplace covariance in whitened coordinates until it is self-consistent.

    :func:`bayescap.fit.laplace_covariance` differentiates with steps of 1e-4 (relative) in the
    raw coordinates, floors the Hessian's eigenvalues at 1e-8 of the largest and caps every sd
    at 1. With a condition number ~1e11 (the saturation plateau ties gain and clip level) the
    floor narrows the weakly identified directions (log f, log g, log D: sd stuck near 0.26),
    the small steps pick up the ~1e-5 jitter of ``log_prob`` (the latent-mean Newton iteration
    stops at a tolerance), which inflated the gain's sd up to 20× on clipped sensors, and a MAP
    within one step of a bound (the clip level at its lower bound) makes the Hessian non-finite,
    whereupon it returns ``diag(1e-4)`` (measured: ``benchmarks/speed_accuracy.py``).

    Here the Hessian is taken again in ``y = (x − x_map)/(α L)``, ``L`` the Cholesky factor of
    the current estimate, with steps ``h`` (0.05·α = 0.2 sd; ten and a hundred times smaller
    when the stencil leaves the support). There it is well conditioned and far above the
    jitter, and ``laplace_covariance``'s cap becomes α times the current sd. Iterates until the
    whitened Hessian is the identity to ±25 % (every direction consistent with the estimate)
    or ``max_iter``.
    """
    n = x_map.size
    c = _proposal_cov(cov, 1.0) if np.all(np.isfinite(cov)) else np.eye(n) * 1e-4
    failed = np.diag(np.full(n, 1e-4))
    for _ in range(max_iter):
        L = alpha * np.linalg.cholesky(c)
        w = _Whitened(model, x_map, L)
        for hh in (h, 0.1 * h, 0.01 * h):
            with np.errstate(all="ignore"):
                cy = laplace_covariance(w, np.zeros(n), h=hh)
            if not np.array_equal(cy, failed):
                break
        else:
            break
        c_new = _proposal_cov(L @ cy @ L.T, 1.0)
        if not np.all(np.isfinite(c_new)):
            break
        c = c_new
        ev = np.linalg.eigvalsh(0.5 * (cy + cy.T)) * alpha * alpha
        if ev.min() > 0.8 and ev.max() < 1.25:
            break
    return c


def polish_map(model, x, cov, *, max_iter=30, h=0.02):
    """Gradient ascent in whitened coordinates from ``x`` (a MAP estimate) with covariance ``cov``.

    :func:`bayescap.fit.find_map` (BFGS on central differences with 1e-5 relative steps) can
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


def _proposal_cov(cov, scale):
    cov = 0.5 * (cov + cov.T)
    w, V = np.linalg.eigh(cov)
    w = np.maximum(w, 1e-14 * max(w.max(), 1e-300))
    return (V * (w * scale * scale)) @ V.T


def _unit_stencil(n):
    """The ``n² + n + 1`` unit offsets of :func:`laplace_covariance`'s stencil: 0, ±e_i, ±(e_i + e_j)
    (i < j), and the pair indices."""
    iu, ju = np.triu_indices(n, 1)
    eye = np.eye(n)
    return np.vstack([np.zeros((1, n)), eye, -eye, eye[iu] + eye[ju], -eye[iu] - eye[ju]]), iu, ju


def _stencil_derivatives(q, step, iu, ju):
    """Value, gradient and Hessian from ``log_prob`` on the stencil of :func:`_unit_stencil` scaled by
    ``step`` (per axis): central differences, A&S 25.3.23/25.3.27 (exact for a quadratic)."""
    n = step.size
    f0, fp, fm = q[0], q[1:n + 1], q[n + 1:2 * n + 1]
    fpp, fmm = q[2 * n + 1:2 * n + 1 + iu.size], q[2 * n + 1 + iu.size:]
    H = np.empty((n, n))
    H[np.arange(n), np.arange(n)] = (fp - 2.0 * f0 + fm) / step**2
    off = (fpp + fmm - fp[iu] - fm[iu] - fp[ju] - fm[ju] + 2.0 * f0) / (2.0 * step[iu] * step[ju])
    H[iu, ju] = off
    H[ju, iu] = off
    return f0, (fp - fm) / (2.0 * step), H


def _clipped_inverse(H):
    """``(−H)⁻¹`` with the eigenvalues of ``−H`` floored at 1e-8 of the largest and at 1 (no direction
    wider than sd 1 in the units of ``H``'s coordinates): :func:`laplace_covariance`'s rule."""
    w, V = np.linalg.eigh(-0.5 * (H + H.T))
    w = np.clip(w, 1e-8 * max(w.max(), 1e-8), None)
    w = np.maximum(w, 1.0)
    return (V / w) @ V.T


#: :func:`newton_map`'s knobs. The stencil's half-width in whitened units (``h·α`` = 0.2 posterior sd,
#: far above the 1e-5-1e-4 jitter of ``log_prob``, as in :func:`refine_covariance`); α, the whitening
#: scale (the coordinates ``y`` have ``x = x_k + α L_k y``, ``L_k`` the Cholesky factor of the current
#: covariance, so a self-consistent Hessian is ``−α² I``); the stopping rule: predicted gain
#: ``gᵀ(−H)⁻¹g/2`` below 1e-3 nats (the optimum then within ~0.05 sd: one iteration fewer than 1e-4 on
#: the Basler, the same k̂) with every whitened curvature within the ±25 % of
#: :func:`refine_covariance`; the step lengths tried along each Newton step in the same call.
NEWTON_H = 0.05


NEWTON_ALPHA = 4.0


NEWTON_GAIN_TOL = 1e-3


NEWTON_STEPS = (1.0, 0.5, 0.25, 0.125, 1.0 / 16, 1.0 / 64, 2.0)


@dataclass
class NewtonOptimum:
    """One start's end point in :func:`newton_map`: the point ``x``, ``log_prob`` there, the
    covariance ``(−H)⁻¹`` from the last whitened Hessian, iterations, whether the stopping rule was
    met (``converged``) and why it stopped (``reason``)."""

    x: np.ndarray
    lp: float
    cov: np.ndarray
    iterations: int
    converged: bool
    reason: str


#: a start is dropped once it is within this many posterior sd (Mahalanobis, in its own covariance
#: or the higher start's) of a higher start: the same mode. On the 29 sensors of
#: benchmarks/local_optima.py, 3 sd (either covariance) reached the same optima as 2 sd (the higher
#: start's), with 19 % fewer points; 4 sd ended 0.07 nats lower on one.
NEWTON_MERGE_SD = 3.0


def _same_mode(a, b):
    """Start ``a`` (lower) is within :data:`NEWTON_MERGE_SD` posterior sd of start ``b``, and its log p
    within what a Gaussian would put there (``NEWTON_MERGE_SD²/2`` nats, + 1): a start's own early
    covariance can be wide enough to take in points of another mode."""
    if b["lp"] - a["lp"] > 0.5 * NEWTON_MERGE_SD ** 2 + 1.0:
        return False
    for c in (b["cov"], a["cov"]):
        r = np.linalg.solve(np.linalg.cholesky(c), a["x"] - b["x"])
        if float(r @ r) < NEWTON_MERGE_SD ** 2:
            return True
    return False


def _no_finite_start(target, x0):
    """Raise the error for an optimiser none of whose starts has a finite log posterior: a
    :class:`~bayescap.ptc.PTCInputError` naming the file, row and column of the first observation
    whose likelihood is not finite at ``x0`` when ``target`` is (or wraps) a :class:`PTCModel` that
    finds one (a zero spatial variance, an exposure time of 1e308 s: values the reader accepts and no
    parameter can explain); a RuntimeError otherwise."""
    model = target if hasattr(target, "nonfinite_observations") else getattr(target, "model", None)
    bad = []
    if model is not None and hasattr(model, "nonfinite_observations"):
        x = np.asarray(x0, float)
        if model is not target and hasattr(target, "to_x"):
            x = target.to_x(x)
        bad = model.nonfinite_observations(x)
    if not bad:
        raise RuntimeError("no finite starting point for the optimiser: the data may be inconsistent "
                           "with the model (check the units of the columns)")
    from bayescap.exceptions import PTCInputError

    block, row, column, obs, mod = bad[0]
    others = sorted({r for _, r, _, _, _ in bad[1:] if r != row})
    more = (f"; rows {', '.join(map(str, others[:10]))}{' ...' if len(others) > 10 else ''} likewise"
            if others else "")
    raise PTCInputError(f"the model gives the value {obs:.6g} no finite likelihood at the optimiser's start "
                        f"(its prediction there: {mod:.6g}), so nothing was fitted: check this row's values "
                        f"and their units{more}", path=model.data.source, row=row, column=column)


def newton_map(target, starts, *, max_iter: int = 60, h: float = NEWTON_H, alpha: float = NEWTON_ALPHA,
               raw_h: float = 1e-4, max_stalls: int = 3):
    """Maximise ``target.log_prob`` from several starts at once by Newton's method on
    finite-difference Hessians in whitened coordinates; returns one :class:`NewtonOptimum` per
    finite start (in the order given) and the number of ``log_prob`` calls.

    Why: a ``log_prob`` call costs ~0.6 ms whatever its size up to a few hundred points (Python
    overhead), so what counts is the number of calls. BFGS on central-difference gradients
    (:func:`find_map`) made ~90-150 calls per sensor and then needed :func:`refine_covariance` and
    :func:`polish_map` for a usable covariance. Here all starts move together: one call takes
    the step lengths of :data:`NEWTON_STEPS` along every start's Newton step, and once Newton is
    in its quadratic phase (the last full step was the best) also the Hessian stencil (``n² + n +
    1`` points, :func:`laplace_covariance`'s) at the full step, which is then the next iteration's;
    otherwise one more call takes the stencils at the steps chosen. Basler: 11 calls, ~2 000
    points, against ~90 calls for BFGS.

    1. One call: the raw stencil (relative steps ``raw_h``) at every start, whose covariance
       (eigenvalues floored as in :func:`laplace_covariance`) sets the first whitening, and whose
       gradient and Hessian, carried into that frame, give the first step (but never the stop).
    2. Each iteration: gradient ``g`` and Hessian ``H`` in ``y`` (step ``h``; ``h/10``, ``h/100`` if
       the stencil leaves the support); Newton step ``d = V diag(1/max(|w|, 1/4)) Vᵀ g`` (``w`` the
       eigenvalues of ``−H``: directions of positive curvature are climbed, not descended), at most
       2 whitened units long; the new covariance ``L (−H)⁻¹ Lᵀ`` with :func:`laplace_covariance`'s
       floor in ``y`` (so a sd grows at most α-fold an iteration). Stop when ``gᵀd/2 <``
       :data:`NEWTON_GAIN_TOL` and the whitened Hessian is consistent with the covariance it was
       taken in (±25 %, as :func:`refine_covariance`), or when no step length improves
       ``log_prob`` ``max_stalls`` times in a row (the covariance is still refined then).
    3. A start that comes within :data:`NEWTON_MERGE_SD` sd of a higher one is dropped: the same
       mode (:func:`_same_mode`).

    The covariance returned is the last whitened Hessian's, taken at the returned point: what
    :func:`refine_covariance` would give there."""
    starts = [np.asarray(s, float) for s in starts]
    n = starts[0].size
    Y, iu, ju = _unit_stencil(n)
    m = Y.shape[0]
    ts = np.asarray(NEWTON_STEPS, float)
    n_calls = [0]

    def lp_of(X):
        n_calls[0] += 1
        with np.errstate(all="ignore"):
            return np.asarray(target.log_prob(X), float)

    with np.errstate(all="ignore"):
        lp0 = np.asarray(target.log_prob(np.vstack(starts)), float)
    n_calls[0] += 1
    keep = [i for i in range(len(starts)) if np.isfinite(lp0[i])]
    if not keep:
        _no_finite_start(target, starts[0])
    states = [dict(i=i, x=starts[i], lp=float(lp0[i]), it=0, stalls=0, walls=0, done=False, reason="", conv=False,
                   spec=False)
              for i in keep]

    def raw_stencil(group):
        """The raw stencil at each state's point, one call: it sets the whitening (covariance with
        laplace_covariance's floor) and, where finite, the derivatives of the next step, carried into
        that frame. Returns whether each was finite."""
        steps = [raw_h * np.maximum(1.0, np.abs(s["x"])) for s in group]
        Q = lp_of(np.vstack([s["x"] + Y * st for s, st in zip(group, steps)])).reshape(len(group), m)
        finite = []
        for s, q, st in zip(group, Q, steps):
            s["Q"], s["raw"] = None, None
            f0, g, H = _stencil_derivatives(q, st, iu, ju) if np.all(np.isfinite(q)) else (None, None, None)
            ok = H is not None and np.all(np.isfinite(H)) and np.all(np.isfinite(g))
            if ok or "cov" not in s:
                s["cov"] = _proposal_cov(_clipped_inverse(H) if ok else np.diag(np.full(n, 1e-4)), 1.0)
                s["L"] = alpha * np.linalg.cholesky(s["cov"])
            if ok:
                s["raw"] = (f0, s["L"].T @ g, s["L"].T @ H @ s["L"])
            finite.append(ok)
        return finite

    # 1. the raw stencil at every start, one call
    raw_stencil(states)
    for _ in range(max_iter):
        active = [s for s in states if not s["done"]]
        if not active:
            break
        need = [s for s in active if s["Q"] is None and s["raw"] is None]
        if need:
            Q = lp_of(np.vstack([s["x"] + (h * Y) @ s["L"].T for s in need])).reshape(len(need), m)
            for s, q in zip(need, Q):
                s["Q"], s["h"] = q, h
        # stencils that left the support: h/10 and h/100 for every such start in one call (the
        # first finite one is used; one call per level and start until 2026-11-23 late evening:
        # sim00 and sim04 of the README's sensors took 39 and 47 log_prob calls per fast fit, now
        # 31 and 33, benchmarks/fast_path_evaluations.py --set speed_accuracy)
        retry = [s for s in active if s["raw"] is None and not np.all(np.isfinite(s["Q"]))]
        if retry:
            R = lp_of(np.vstack([s["x"] + (hh * Y) @ s["L"].T for s in retry
                                 for hh in (0.1 * s["h"], 0.01 * s["h"])])).reshape(len(retry), 2, m)
            for s, qq in zip(retry, R):
                h0 = s["h"]
                s["Q"], s["h"] = (qq[0], 0.1 * h0) if np.all(np.isfinite(qq[0])) else (qq[1], 0.01 * h0)
        moves = []
        for s in active:
            s["it"] += 1
            raw, s["raw"] = s["raw"], None
            if raw is not None:
                f0, g, H = raw
            else:
                q, s["Q"] = s["Q"], None
                if not np.all(np.isfinite(q)):
                    # next to a wall of the prior (τ's cap, a bound): the raw stencil's steps are
                    # 1e-4 relative; a step from its derivatives (the BFGS route's line search moved
                    # off such walls too). Where it also leaves the support, stop.
                    s["walls"] += 1
                    if s["walls"] > max_stalls or not raw_stencil([s])[0]:
                        s.update(done=True, reason="the Hessian stencil leaves the support at every step size")
                        continue
                    raw, s["raw"] = s["raw"], None
                    f0, g, H = raw
                else:
                    f0, g, H = _stencil_derivatives(q, np.full(n, s["h"]), iu, ju)
            w, V = np.linalg.eigh(-0.5 * (H + H.T))
            wc = np.maximum(np.clip(w, 1e-8 * max(w.max(), 1e-8), None), 1.0)
            cov_new = _proposal_cov(s["L"] @ ((V / wc) @ V.T) @ s["L"].T, 1.0)
            consistent = bool(np.all(w > alpha * alpha / 1.25) and np.all(w < alpha * alpha / 0.8))
            d = V @ ((V.T @ g) / np.maximum(np.abs(w), 0.25))
            gain = 0.5 * float(g @ d)
            nd = float(np.linalg.norm(d))
            if nd > 2.0:
                d *= 2.0 / nd
            s["lp"] = float(f0)
            try:
                L_new = alpha * np.linalg.cholesky(cov_new)
            except np.linalg.LinAlgError:
                s.update(done=True, reason="the covariance is not positive definite")
                continue
            s["cov"] = cov_new
            if gain < NEWTON_GAIN_TOL and consistent and raw is None:   # never on the raw Hessian alone
                s.update(done=True, conv=True, reason="converged")
                continue
            s["d"], s["L_old"], s["L"] = d, s["L"], L_new
            moves.append(s)
        if moves:
            # one call: every step length of every start, and where the last full step was the best
            # (Newton's quadratic phase), the stencil at this full step in place of its centre
            parts, sizes = [], []
            for s in moves:
                if s["spec"]:
                    parts.append(s["x"] + s["L_old"] @ s["d"] + (h * Y) @ s["L"].T)
                    parts.append(s["x"] + (ts[1:, None] * s["d"][None, :]) @ s["L_old"].T)
                    sizes.append(m + ts.size - 1)
                else:
                    parts.append(s["x"] + (ts[:, None] * s["d"][None, :]) @ s["L_old"].T)
                    sizes.append(ts.size)
            vals = np.split(lp_of(np.vstack(parts)), np.cumsum(sizes)[:-1])
            for s, v in zip(moves, vals):
                cand = np.concatenate([v[:1], v[m:]]) if s["spec"] else v
                cand = np.where(np.isfinite(cand), cand, -np.inf)
                j = int(np.argmax(cand))
                if cand[j] > s["lp"] + 1e-9:
                    s["x"] = s["x"] + ts[j] * (s["L_old"] @ s["d"])
                    s["lp"], s["stalls"] = float(cand[j]), 0
                    if j == 0 and s["spec"]:
                        s["Q"], s["h"] = v[:m], h
                else:
                    s["stalls"] += 1
                    if s["stalls"] >= max_stalls:
                        s.update(done=True, reason=f"no step length raised log p in {max_stalls} iterations")
                s["spec"] = j == 0
        # 3. starts that met a higher one: the same mode
        live = sorted([s for s in states if not s["done"] or s["conv"]], key=lambda s: -s["lp"])
        for a_i, a in enumerate(live):
            if a["done"]:
                continue
            for b in live[:a_i]:
                if _same_mode(a, b):
                    a.update(done=True, reason="reached the mode of a higher start")
                    break
    else:
        for s in states:
            if not s["done"]:
                s.update(done=True, reason=f"{max_iter} iterations")
    out = [NewtonOptimum(s["x"], s["lp"], s["cov"], s["it"], s["conv"], s["reason"]) for s in states]
    return out, n_calls[0]


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
        hd = (lp[1:n + 1] + lp[n + 1:] - 2.0 * lp[0]) / step**2
    D = np.where(np.isfinite(hd) & (hd < 0), 1.0 / np.sqrt(np.abs(hd)), 1.0)
    D = np.clip(D, 1e-8, 1.0)

    def fun(y):
        lpv, g = _vectorised_grad(model, x0 + D * y)
        if not np.isfinite(lpv):
            return 1e300, np.zeros_like(y)
        return -lpv, -np.where(np.isfinite(g), g, 0.0) * D

    y, v = _bfgs(fun, np.zeros(n))
    return x0 + D * y, -float(v)


#: shifts of log f (the variance discrepancy) for the extra optimiser starts of :func:`laplace_start`:
#: f ten times the initial guess's 1 %. A large discrepancy flattens the likelihood (like a higher
#: temperature), so the optimiser crosses what would trap it and then lowers f. Measured on 29
#: sensors (20 simulated Gpixel ROIs, the 5 benchmark CSVs, the Basler, 3 speed_accuracy sensors):
#: this start alone found the higher optimum on all 3 where the first start had missed it
#: (+1.5, +5.7 and +136 nats); a start at f/10 found none the other two did not
#: (docs/performance.md, "Local optima").
MAP_START_LOG_F_SHIFTS = (2.3,)


#: shift of log τ (the clip spread) for the extra optimiser start of :func:`_map_starts` when the
#: initial guess puts τ at its prior cap (``tau_max_frac`` of the clip level). The cap is a wall
#: (log prior −∞ beyond it), and a start on it stays there: on sim00 (``benchmarks/speed_accuracy.py``)
#: both optimisers stopped on the wall, 136-264 nats below the mode at τ 7 times smaller, and the
#: mode had been reached only by chance (a polish step from one of those points). log τ − 2 reaches
#: the mode from both f starts; so does −3 (docs/performance.md, "two starts that were luck").
MAP_START_LOG_TAU_SHIFT = -2.0


def _map_starts(model, x0=None):
    """Extra starting points for :func:`laplace_start`: the initial guess with the variance
    discrepancy f shifted by :data:`MAP_START_LOG_F_SHIFTS` (or the guess itself without an f term),
    and, when the guess's clip spread τ sits within a factor e of its prior cap, the guess with
    log τ shifted by :data:`MAP_START_LOG_TAU_SHIFT`.
    The discrepancy and the outlier mixture trade off: a large f explains a deviant row, a small f
    with the row as an outlier is another local optimum, and the start decides which one a local
    optimiser finds (docs/performance.md, "Local optima"). ``x0``: the initial guess when the
    caller has it already (it costs ~3 ms on the Basler: a fast fit computed it twice)."""
    x0 = np.array(model.initial_guess() if x0 is None else x0, dtype=float)   # a copy
    names = list(getattr(model, "names", []))
    out = []
    if "log_f" in names:
        j = names.index("log_f")
        for df in MAP_START_LOG_F_SHIFTS:
            s = x0.copy()
            s[j] += df
            out.append(s)
    else:
        out.append(x0)
    if "log_tau" in names and hasattr(model, "tau_cap_dn"):
        if np.exp(x0[names.index("log_tau")]) > float(model.tau_cap_dn(x0)[0]) / np.e:
            s = x0.copy()
            s[names.index("log_tau")] += MAP_START_LOG_TAU_SHIFT
            out.append(s)
    return out


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


def _restart_points(x0, n_restarts):
    """:func:`find_map`'s fixed perturbations of the initial guess."""
    offsets = np.linspace(-1, 1, x0.size)
    return [x0 + (0.3 * (r + 1)) * np.roll(offsets, r) * (1 if r % 2 == 0 else -1) for r in range(n_restarts)]


#: the optimiser of :func:`laplace_start`: ``"newton"`` (:func:`newton_map`, since 2026-11-23
#: evening) or ``"bfgs"`` (:func:`find_map` / :func:`find_map_scaled`, then :func:`refine_covariance`
#: and :func:`polish_map`: the route before, kept for comparison in the benchmarks).
LAPLACE_OPTIMIZER = "newton"


def laplace_start(model: PTCModel, *, n_restarts: int = 2, refine_iter: int = 6, polish: bool = True,
                  multi_start: bool = True, coords=None, polish_both: bool = False, optimizer: str | None = None):
    """MAP and a self-consistent Laplace covariance: where both the MCMC walkers and the fast path's
    importance proposals start.

    With ``optimizer="newton"`` (the default, :data:`LAPLACE_OPTIMIZER`): :func:`newton_map` from
    the initial guess, ``n_restarts`` fixed perturbations of it (:func:`find_map`'s) and, with
    ``multi_start``, the starts of :func:`_map_starts`, all at once; the highest end point and its
    covariance are returned. With ``coords`` the starts are mapped by ``start_from_x`` and Newton
    runs in those coordinates; with ``polish_both`` it runs in the model's coordinates first and
    again in ``coords`` from there. ``refine_iter`` and ``polish`` apply to the BFGS route only
    (Newton's covariance is self-consistent by its stopping rule). Measured against the BFGS route
    on the 29 sensors of ``benchmarks/local_optima.py``: docs/performance.md, "Newton's method".

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
    ``coords`` (twice the work; :func:`bayescap.fast.fast_posterior` does this on its retry)."""
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
    done = []          # (x, Cholesky factor of its covariance) of the optima refined so far
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
