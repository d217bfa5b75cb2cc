"""Joint fit of one sensor at several analog gains, with the gain-independent parameters tied.

Each gain keeps its own photon-transfer model (:class:`bayescap.model.PTCModel`); the joint
posterior ties the coordinates that the analog gain does not change, namely the quantum
efficiency, PRNU, dark current and DSNU, by giving every gain's model the same value:

    log p(θ) = Σ_g log p_g(θ_g) − (G − 1) · log π(θ_shared)

``θ_g`` is gain g's coordinate vector with the shared coordinates filled in from ``θ``. Each
``log p_g`` contains the prior of the shared coordinates once, so G − 1 copies are taken off;
the model's priors are separable per coordinate, so ``log π(θ_shared)`` is the change of the first
model's log prior when its shared coordinates move (relative to a fixed reference point). The full
well is not tied: its coordinate is each gain's clip level, which the ADC sets at a high gain.

Sampling (``sampler``):

* ``"is"``: the fast path's recipe (:mod:`bayescap.inference.fast`): each gain's MAP and Laplace
  covariance (:func:`bayescap.inference.optimize.laplace_start`), their precisions summed into the
  joint one, the joint MAP polished by BFGS on the true joint density, then importance sampling
  from a multivariate Student-t (ν = 5) around it with Pareto-smoothed weights. It passes when the
  Pareto k̂ < 0.7. In about 30 dimensions (three gains) that is close: on the eight simulated
  three-gain series of ``benchmarks/gain_joint.py`` k̂ was 0.47-0.68.
* ``"mcmc"``: emcee with differential-evolution moves in coordinates whitened by the joint Laplace
  covariance, ``n_steps`` steps (a third discarded); converged when the kept steps are at least 50
  integrated autocorrelation times of the slowest coordinate (default 16000 steps: several minutes
  for three gains on 2 cores).
* ``"auto"`` (default): importance sampling, and MCMC when its check fails.

The result says which sampler gave the draws and whether its check passed (``converged``; a failed
check is also in ``notes``). ``benchmarks/gain_joint.py`` checks the joint intervals against the
simulated truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import emcee
import numpy as np
from scipy.optimize import minimize

from bayescap.inference.importance import psis_weights, student_t_draws
from bayescap.inference.optimize import laplace_start
from bayescap.model.ptc_model import PTCModel
from bayescap.posterior import summarize

__all__ = ["SHARED_COORDS", "JointGainModel", "JointGainFit", "fit_gain_series_jointly"]

#: model coordinates tied across gains (when every gain's model has them)
SHARED_COORDS = ("qe", "log_prnu", "log_dc", "log_dsnu")
KHAT_MAX = 0.7
_NU = 5.0
#: MCMC: kept steps per integrated autocorrelation time required
MIN_STEPS_PER_TAU = 50


class JointGainModel:
    """The joint log density of several gains' models with shared coordinates tied."""

    def __init__(self, models: list[PTCModel], shared=SHARED_COORDS):
        self.models = models
        self.shared = [c for c in shared if all(c in m.idx for m in models)]
        self.own = [[n for n in m.names if n not in self.shared] for m in models]
        self.ndim = len(self.shared) + sum(len(o) for o in self.own)
        starts = np.cumsum([len(self.shared)] + [len(o) for o in self.own])
        self.slices = [slice(a, b) for a, b in zip(starts[:-1], starts[1:])]
        self.ref_shared = None

    def split(self, x) -> list[np.ndarray]:
        """Gain-wise coordinate arrays ``(n, ndim_g)`` of joint draws ``x`` ``(n, ndim)``."""
        x = np.atleast_2d(np.asarray(x, float))
        out = []
        for m, own, sl in zip(self.models, self.own, self.slices):
            th = np.empty((x.shape[0], m.ndim))
            for j, c in enumerate(self.shared):
                th[:, m.idx[c]] = x[:, j]
            for j, c in enumerate(own):
                th[:, m.idx[c]] = x[:, sl.start + j]
            out.append(th)
        return out

    def join(self, thetas: list[np.ndarray], shared_values) -> np.ndarray:
        """The joint vector from per-gain vectors (1-D) and values of the shared coordinates."""
        x = np.empty(self.ndim)
        x[: len(self.shared)] = shared_values
        for m, own, sl, th in zip(self.models, self.own, self.slices, thetas):
            x[sl] = [th[m.idx[c]] for c in own]
        return x

    def _shared_log_prior(self, th0):
        m = self.models[0]
        ref = th0.copy()
        for j, c in enumerate(self.shared):
            ref[:, m.idx[c]] = self.ref_shared[j]
        return m.log_prior(th0) - m.log_prior(ref)

    def log_prob(self, x):
        thetas = self.split(x)
        lp = sum(m.log_prob(th) for m, th in zip(self.models, thetas))
        if len(self.models) > 1 and self.shared:
            with np.errstate(invalid="ignore"):
                lp = lp - (len(self.models) - 1) * self._shared_log_prior(thetas[0])
        return np.where(np.isfinite(lp), lp, -np.inf)


@dataclass
class JointGainFit:
    gains: list
    shared: list
    draws: list  # per gain: {physical name: (n,) equal-weight draws}
    khat: float
    ess: float
    converged: bool
    sampler: str = "is"
    mcmc: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def shared_summary(self) -> dict:
        out = {}
        name = {
            "qe": "quantum_efficiency",
            "log_prnu": "prnu_percent",
            "log_dc": "dark_current_e_per_s",
            "log_dsnu": "dsnu_e",
        }
        for c in self.shared:
            out[name[c]] = summarize(self.draws[0][name[c]], "")
        return out

    def to_dict(self) -> dict:
        return {
            "fit": "joint over gains (shared: " + ", ".join(self.shared) + ")",
            "converged": self.converged,
            "sampler": self.sampler,
            "mcmc": self.mcmc,
            "pareto_khat": self.khat,
            "importance_ess": self.ess,
            "shared": self.shared_summary(),
            "gains": [
                {
                    "analog_gain": g,
                    **{k: summarize(d[k], "") for k in ("conversion_gain_e_per_dn", "read_noise_e", "full_well_e")},
                }
                for g, d in zip(self.gains, self.draws)
            ],
            "notes": list(self.notes),
        }


def _mcmc(jm, x_map, cov, start, *, n_steps, seed):
    """emcee (DE moves) in coordinates whitened by ``cov``; returns (draws (n, ndim), info)."""
    L = np.linalg.cholesky(cov)
    n_walkers = 2 * jm.ndim + 2
    rng = np.random.default_rng(seed)
    z0 = np.linalg.solve(L, (start[rng.choice(start.shape[0], n_walkers, replace=False)] - x_map).T).T
    sampler = emcee.EnsembleSampler(
        n_walkers,
        jm.ndim,
        lambda z: jm.log_prob(x_map + z @ L.T),
        vectorize=True,
        moves=[(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)],
    )
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31))).get_state()
    sampler.run_mcmc(z0, n_steps, progress=False)
    burn = n_steps // 3
    tau = float(np.max(sampler.get_autocorr_time(discard=burn, tol=0)))
    kept = n_steps - burn
    info = {
        "n_walkers": n_walkers,
        "n_steps": n_steps,
        "burn_in": burn,
        "tau_max": tau,
        "steps_per_tau": kept / tau,
        "acceptance": float(np.mean(sampler.acceptance_fraction)),
    }
    z = sampler.get_chain(discard=burn, flat=True)
    return x_map + z @ L.T, info


def fit_gain_series_jointly(
    datas, gains, *, seed: int = 0, n_draws: int = 4000, sampler: str = "auto", n_steps: int = 16000
) -> JointGainFit:
    """Joint fit (module docstring) of PTCData ``datas`` at analog ``gains``."""
    if sampler not in ("auto", "is", "mcmc"):
        raise ValueError(f"sampler must be 'auto', 'is' or 'mcmc', got {sampler!r}")
    order = np.argsort(gains)
    gains = [float(gains[i]) for i in order]
    models = [PTCModel(datas[i]) for i in order]
    jm = JointGainModel(models, shared=SHARED_COORDS)
    starts = [laplace_start(m) for m in models]
    # joint Laplace: per-gain precisions summed in the joint coordinates
    prec = np.zeros((jm.ndim, jm.ndim))
    rhs = np.zeros(jm.ndim)
    for m, own, sl, (x_map, _, cov, _) in zip(models, jm.own, jm.slices, starts):
        cols = [jm.shared.index(n) if n in jm.shared else sl.start + own.index(n) for n in m.names]
        h = np.linalg.inv(cov)
        prec[np.ix_(cols, cols)] += h
        rhs[cols] += h @ x_map
    x0 = np.linalg.solve(prec, rhs)
    jm.ref_shared = x0[: len(jm.shared)].copy()
    if not np.isfinite(jm.log_prob(x0)[0]):  # the Gaussian combination left a bound: start at gain 1's values
        x0 = jm.join([s[0] for s in starts], [starts[0][0][models[0].idx[c]] for c in jm.shared])
    cov = np.linalg.inv(prec)
    scale = np.sqrt(np.diag(cov))
    eye = np.eye(jm.ndim) * 1e-5

    def neg(z):
        return -float(jm.log_prob(x0 + z * scale)[0])

    def grad(z):  # central differences, all 2·ndim points in one vectorised call
        lp = jm.log_prob(x0 + np.concatenate([z + eye, z - eye]) * scale)
        g = -(lp[: jm.ndim] - lp[jm.ndim :]) / 2e-5
        return np.where(np.isfinite(g), g, 0.0)

    res = minimize(neg, np.zeros(jm.ndim), jac=grad, method="BFGS", options={"maxiter": 200, "gtol": 1e-3})
    x_map = x0 + res.x * scale if np.isfinite(res.fun) and -res.fun >= jm.log_prob(x0)[0] else x0
    rng = np.random.default_rng(seed)
    x, logq = student_t_draws(x_map, cov, _NU, n_draws, rng)
    w, khat, ess = psis_weights(jm.log_prob(x) - logq)
    khat, ess = float(khat), float(ess)
    notes, info = [], {}
    is_ok = bool(khat < KHAT_MAX)
    if sampler == "is" or (sampler == "auto" and is_ok):
        used, converged = "is", is_ok
        x = x[rng.choice(n_draws, size=n_draws, p=w)]
        if not is_ok:
            notes.append(
                f"joint importance sampling failed its check (Pareto k = {khat:.2f} >= {KHAT_MAX}): the joint "
                "draws are not trustworthy; use sampler='mcmc' or the separate fits (gain_series.fit_gain_series)"
            )
    else:
        if sampler == "auto":
            notes.append(f"importance sampling failed its check (Pareto k = {khat:.2f}); MCMC used")
        start = x[rng.choice(n_draws, size=n_draws, p=w)]
        x, info = _mcmc(jm, x_map, cov, start, n_steps=n_steps, seed=seed)
        used = "mcmc"
        converged = bool(info["steps_per_tau"] >= MIN_STEPS_PER_TAU and info["acceptance"] > 0.05)
        if not converged:
            notes.append(
                f"the joint MCMC did not converge ({info['steps_per_tau']:.0f} kept steps per autocorrelation "
                f"time, {MIN_STEPS_PER_TAU} needed; acceptance {info['acceptance']:.2f}): raise n_steps"
            )
    thetas = jm.split(x)
    draws = [m.physical(th) for m, th in zip(models, thetas)]
    return JointGainFit(
        gains=gains,
        shared=jm.shared,
        draws=draws,
        khat=khat,
        ess=ess,
        converged=converged,
        sampler=used,
        mcmc=info,
        notes=notes,
    )
