"""The posterior's curvature by finite differences: the Hessian stencil of ``n² + n + 1`` points,
the Laplace covariance (the eigenvalue-clipped inverse of the negative Hessian) and its refinement
in whitened coordinates, where the stencil's steps are far above the jitter of ``log_prob``."""

from __future__ import annotations

import numpy as np

from bayescap.model.ptc_model import PTCModel


def laplace_covariance(model: PTCModel, x, h=1e-4):
    """Inverse of the negative Hessian of log-prob at ``x`` (finite differences, one
    vectorised call), made positive definite by eigenvalue clipping.

    Central differences on ``n² + n + 1`` points: ``x``, ``x ± e_i`` and ``x ± (e_i + e_j)``
    (``i < j``), with ``e_i`` the step ``h·max(1, |x_i|)`` along axis ``i``::

        H_ii = [f(+i) − 2 f(0) + f(−i)] / e_i²
        H_ij = [f(+i+j) + f(−i−j) − f(+i) − f(−i) − f(+j) − f(−j) + 2 f(0)] / (2 e_i e_j)

    (Abramowitz & Stegun 25.3.23/25.3.27; both exact for a quadratic, error O(e²)): 73 points for
    n = 8, where the four-point stencil ``f(x±e_i±e_j)`` takes ``2n² + 2n`` (144)."""
    step = h * np.maximum(1.0, np.abs(x))
    Y, iu, ju = _unit_stencil(x.size)
    with np.errstate(all="ignore"):  # the stencil may leave the prior support: -inf, handled below
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

    :func:`laplace_covariance` differentiates with steps of 1e-4 (relative) in the
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
    f0, fp, fm = q[0], q[1 : n + 1], q[n + 1 : 2 * n + 1]
    fpp, fmm = q[2 * n + 1 : 2 * n + 1 + iu.size], q[2 * n + 1 + iu.size :]
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
