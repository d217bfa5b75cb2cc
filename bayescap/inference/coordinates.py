"""Sampler coordinates: the clip level as log(clip - lower bound) and the QE as log(qe), with the
Jacobian, where the optimiser, the Laplace approximation, the fast path and the MCMC start work."""

from __future__ import annotations

import numpy as np

from bayescap.inference.optimize import laplace_start


class SamplerCoordinates:
    """The posterior of ``model`` in the coordinates its optimiser, Laplace approximation, fast-path
    proposals and MCMC start work in, Jacobian included: the clip level as ``z = log(clip_dn − lo)``
    where it is free (``lo`` its data-derived lower bound, the largest unclipped row mean), the QE
    as ``log(qe)`` where the model has one; every other coordinate unchanged. The MCMC itself
    samples the model's coordinates. ``LogClipCoordinates`` is another name of the same class.

    Why the clip: where its posterior piles up against ``lo`` (the well clips just above the
    last unclipped row), the MAP sits on the bound, the Hessian's stencil leaves the support and the
    Laplace covariance falls back to ``diag(1e-4)`` or comes out 1 000× too wide; the importance
    weights then fail (k̂ 87 and 28 on two simulated Gpixel ROIs). In ``z`` the density
    ``p(clip)·(clip − lo)`` vanishes at the bound and the mode is interior. On 20 simulated
    Gpixel ROIs the fast path is accepted on 17 instead of 15.

    Why the QE: with photon counts the mean signal pins QE/K (``S = QE·μ_p/K``) to ~1e-4 where the
    mean discrepancy is small, so the posterior is a thin ridge along ``QE ∝ K``, straight in
    (log K, log QE) and curved in (log K, QE): on a small Gpixel ROI the curve leaves a straight
    line by 3.4 of the ridge's widths 2.5 sds out, where straight t proposals draw too rarely: in
    QE the fast path's intervals of K, the full well, QE, read noise and capacity are ~1 % of the
    width a side too narrow, in log QE they are not."""

    def __init__(self, model):
        self.model, self.names, self.ndim = model, list(model.names), model.ndim
        clip = self._clip_free(model)
        self.j = self.names.index("clip_dn") if clip else None
        self.lo, self.hi = model.clip_bounds if clip else (None, None)
        self.q = self.names.index("qe") if "qe" in self.names else None

    @staticmethod
    def _clip_free(model) -> bool:
        names = list(getattr(model, "names", []))
        cb = getattr(model, "clip_bounds", None)
        return "clip_dn" in names and cb is not None and cb[1] > cb[0]

    @classmethod
    def applies(cls, model) -> bool:
        return cls._clip_free(model) or "qe" in list(getattr(model, "names", []))

    def describe(self) -> str:
        """The transformed coordinates, as the diagnostics name them."""
        return ", ".join(
            ([] if self.j is None else ["log(clip_dn - lower bound)"]) + ([] if self.q is None else ["log(qe)"])
        )

    def to_x(self, z):
        x = np.array(z, float, copy=True)
        if self.j is not None:
            x[..., self.j] = self.lo + np.exp(x[..., self.j])
        if self.q is not None:
            x[..., self.q] = np.exp(x[..., self.q])
        return x

    def to_z(self, x):
        z = np.array(x, float, copy=True)
        if self.j is not None:
            z[..., self.j] = np.log(np.maximum(z[..., self.j] - self.lo, 1e-300))
        if self.q is not None:
            z[..., self.q] = np.log(np.maximum(z[..., self.q], 1e-300))
        return z

    def log_jacobian(self, z):
        """``log |dx/dz|`` at the rows of ``z``: the sum of the transformed coordinates."""
        z = np.atleast_2d(np.asarray(z, float))
        out = np.zeros(z.shape[0])
        for i in (self.j, self.q):
            if i is not None:
                out = out + z[:, i]
        return out

    def jacobian_diag(self, z):
        """``dx/dz`` at one point ``z`` (a diagonal: each coordinate maps on its own)."""
        J = np.ones(self.ndim)
        for i in (self.j, self.q):
            if i is not None:
                J[i] = np.exp(z[i])
        return J

    def log_prob(self, z):
        z = np.atleast_2d(np.asarray(z, float))
        with np.errstate(all="ignore"):
            return self.model.log_prob(self.to_x(z)) + self.log_jacobian(z)

    def start_from_x(self, x):
        """``to_z`` of a point of the model's coordinates, its clip moved off the bound (a MAP on
        the bound, clip_dn = lo, has z = −∞) to ``lo + 1e-9 (hi − lo)``."""
        x = np.array(x, float, copy=True)
        if self.j is not None:
            x[self.j] = max(x[self.j], self.lo + 1e-9 * (self.hi - self.lo))
        return self.to_z(x)

    def initial_guess(self):
        x0 = np.array(self.model.initial_guess(), float)
        if self.j is not None:
            x0[self.j] = max(x0[self.j], self.lo + 1e-3 * (self.hi - self.lo))
        return self.to_z(x0)


LogClipCoordinates = SamplerCoordinates


def _sampler_coordinates(model):
    """:class:`SamplerCoordinates` of ``model`` where its clip level is free or it has a QE, else None."""
    return SamplerCoordinates(model) if SamplerCoordinates.applies(model) else None


def mcmc_start(model, *, n_restarts: int = 0):
    """Where the walkers start: :func:`laplace_start`, in :class:`SamplerCoordinates` where the
    clip level is free or the model has a QE (as the fast path does).

    A local optimiser in the model's coordinates can stop with the clip level on its lower bound,
    where the Hessian's stencil leaves the support (Newton stops there; :func:`polish_map`, of the
    BFGS route, crawled): on a simulated
    Gpixel ROI it can stop 46 nats below the mode, which
    the MCMC then has to climb in burn-in; in ``z`` the mode is interior.
    Returns
    (x_map, lp_map, cov, coords, z_map, cov_z): the point and covariance in the model's coordinates
    (``cov`` by the delta method, ``∂clip/∂z = clip − lo``, ``∂qe/∂z = qe``), and those of ``coords`` (None without)."""
    coords = _sampler_coordinates(model)
    if coords is None:
        x_map, lp_map, cov, _ = laplace_start(model, n_restarts=n_restarts)
        return x_map, lp_map, cov, None, None, None
    z_map, _, cz, _ = laplace_start(model, n_restarts=n_restarts, coords=coords)
    x_map = coords.to_x(z_map)
    with np.errstate(all="ignore"):
        lp_map = float(model.log_prob(x_map[None])[0])
    J = coords.jacobian_diag(z_map)
    return x_map, lp_map, cz * np.outer(J, J), coords, z_map, cz
