"""The emcee-based classes of the MCMC (:mod:`bayescap.inference.mcmc`), in a module of their own
(``bayescap.inference.IndependenceMove`` loads it on first access) so that ``import bayescap`` does not
import emcee.

emcee is imported here without scipy.stats, h5py and tqdm (:func:`_import_emcee`): emcee's package
imports every move, and its KDE move alone imports ``scipy.stats`` (0.8–1.3 s of a 2-core machine,
most of it scipy's docstring parsing; ``python -X importtime -c "import emcee"``), its HDF5 backend
h5py and its progress bar tqdm, none of which bayescap's MCMC uses."""

from __future__ import annotations

import sys

import numpy as np

from bayescap.inference.curvature import _proposal_cov


def _gaussian_kde(*args, **kwargs):
    """``scipy.stats.gaussian_kde``, imported on the first call (emcee's KDEMove calls it)."""
    from scipy.stats import gaussian_kde

    return gaussian_kde(*args, **kwargs)


class _LazyModule:
    """Stands for the module ``name`` in an emcee module: imports it on the first attribute read
    (``h5py.File`` when an :class:`emcee.backends.HDFBackend` opens its file, ``tqdm.tqdm`` when
    emcee shows a progress bar)."""

    def __init__(self, name):
        self._name = name

    def __getattr__(self, attr):
        import importlib

        return getattr(importlib.import_module(self._name), attr)


#: what emcee imports at import time and bayescap does not use: (the module, the emcee module that
#: imports it under ``except ImportError``, the name it binds there)
_DEFERRED = (
    ("scipy.stats", "emcee.moves.kde", "gaussian_kde"),
    ("h5py", "emcee.backends.hdf", "h5py"),
    ("tqdm", "emcee.pbar", "tqdm"),
)


def _import_emcee():
    """``import emcee`` without importing ``scipy.stats``, ``h5py`` or ``tqdm``, emcee unchanged for
    anyone else.

    emcee imports each of them in one place, guarded by ``except ImportError`` (then ``None``):
    ``emcee.moves.kde``'s ``from scipy.stats import gaussian_kde`` (0.8–1.3 s of a 2-core machine),
    ``emcee.backends.hdf``'s ``import h5py`` (~50-80 ms, for the HDF5 backend) and ``emcee.pbar``'s
    ``import tqdm`` (~20-30 ms, for its progress bar; bayescap's own bars import tqdm when shown). While
    emcee loads, ``sys.modules[name]`` is ``None`` for each of them that is not imported yet (Python's
    documented way to make an import raise ImportError), and afterwards the name emcee bound is
    :func:`_gaussian_kde` (which imports scipy.stats on its first call) or a :class:`_LazyModule`
    (where the package is installed): KDEMove, HDFBackend and emcee's progress bar work as before,
    for bayescap's callers too. When emcee is already imported this is a plain ``import emcee``."""
    if "emcee" not in sys.modules:
        import importlib
        import importlib.util

        blocked = [d for d in _DEFERRED if d[0] not in sys.modules]
        for name, _, _ in blocked:
            sys.modules[name] = None
        try:
            for _, where, _ in _DEFERRED:
                importlib.import_module(where)
        finally:
            for name, _, _ in blocked:
                if name in sys.modules and sys.modules[name] is None:
                    del sys.modules[name]
        for name, where, attr in blocked:
            module = sys.modules[where]
            if getattr(module, attr) is None:
                if name == "scipy.stats":
                    setattr(module, attr, _gaussian_kde)
                elif importlib.util.find_spec(name) is not None:
                    setattr(module, attr, _LazyModule(name))
    import emcee

    return emcee


emcee = _import_emcee()

__all__ = ["IndependenceMove"]

#: what :class:`_Sampler` puts in the states ``sample`` yields between steps (see there)
_RANDOM_STATE_LATER = "random state: taken when run_mcmc returns"


class IndependenceMove(emcee.moves.MHMove):
    """Independence Metropolis–Hastings for every walker at once: proposals from a fixed
    multivariate Student-t ``t_ν(mean, scale²·cov)`` (here the Laplace approximation at the MAP),
    accepted with probability ``min(1, p(x′) q(x) / (p(x) q(x′)))``.

    The proposal does not depend on the current position, so the move leaves the target invariant
    whatever ``mean`` and ``cov`` are (a poor approximation only lowers the acceptance); when the
    approximation is good, successive states are nearly independent. One ``log_prob`` call per step
    for the whole ensemble (emcee's red-blue moves need two). Mixed with DE/stretch moves, which
    cover what the t misses (skewed upper limits, bounds). Calibration on known targets:
    ``benchmarks/check_moves.py``."""

    def __init__(self, mean, cov, *, nu: float = 6.0, scale: float = 1.0):
        self.mean = np.asarray(mean, float)
        self.nu = float(nu)
        c = _proposal_cov(np.asarray(cov, float), scale)
        try:
            self.L = np.linalg.cholesky(c)
        except np.linalg.LinAlgError:  # eigenvalue floor at 1e-14 of the largest can still fail: jitter
            self.L = np.linalg.cholesky(c + 1e-10 * np.max(np.diag(c)) * np.eye(c.shape[0]))
        self.n_proposed = 0
        self.n_accepted = 0
        super().__init__(self._get_proposal, ndim=self.mean.size)

    def log_q(self, x):
        """log proposal density up to a constant (the constant cancels in the ratio)."""
        z = np.linalg.solve(self.L, (np.atleast_2d(x) - self.mean).T)
        maha = np.einsum("ij,ij->j", z, z)
        return -0.5 * (self.nu + self.mean.size) * np.log1p(maha / self.nu)

    def propose(self, model, state):
        state, accepted = super().propose(model, state)
        self.n_proposed += accepted.size
        self.n_accepted += int(np.sum(accepted))
        return state, accepted

    def _get_proposal(self, coords, random):
        n, d = coords.shape
        z = random.standard_normal((n, d))
        u = random.chisquare(self.nu, size=n) / self.nu
        q = self.mean + (z @ self.L.T) / np.sqrt(u)[:, None]
        log_q_new = -0.5 * (self.nu + d) * np.log1p(np.einsum("ij,ij->i", z, z) / u / self.nu)
        # MHMove adds this to log p(x') − log p(x): log q(x) − log q(x')
        return q, self.log_q(coords) - log_q_new


class _Sampler(emcee.EnsembleSampler):
    """emcee's ``EnsembleSampler`` with two per-step costs removed, the chains unchanged:

    - it takes a vectorised ``log_prob``'s (n,) array as it is: emcee converts each walker's value
      in a Python call (``_scalar``) after probing for blobs, ~0.1 ms a call on 96 walkers, ~4 % of
      a standard fit. bayescap uses no blobs and no named parameters; the checks (infinite or NaN
      positions, NaN log-probabilities) and the values are emcee's;
    - ``sample`` copies the generator's state (``RandomState.get_state``, 42 µs) into the state
      of every step; bayescap uses only the state ``run_mcmc`` returns, so the copy is taken
      there, once (the intermediate states carry ``_RANDOM_STATE_LATER``, and setting it is a
      no-op, as emcee's setter ignores a state it cannot set)."""

    @property
    def random_state(self):
        return _RANDOM_STATE_LATER

    @random_state.setter
    def random_state(self, state):
        if not (isinstance(state, str) and state == _RANDOM_STATE_LATER):
            emcee.EnsembleSampler.random_state.fset(self, state)

    def run_mcmc(self, initial_state, nsteps, **kwargs):
        state = super().run_mcmc(initial_state, nsteps, **kwargs)
        state.random_state = self._random.get_state()
        return state

    def compute_log_prob(self, coords):
        if np.any(np.isinf(coords)):
            raise ValueError("At least one parameter value was infinite")
        if np.any(np.isnan(coords)):
            raise ValueError("At least one parameter value was NaN")
        log_prob = np.asarray(self.log_prob_fn(coords), dtype=float)
        if log_prob.shape != (coords.shape[0],):
            raise ValueError(f"log_prob returned shape {log_prob.shape}, expected ({coords.shape[0]},)")
        if np.any(np.isnan(log_prob)):
            raise ValueError("Probability function returned NaN")
        return log_prob, None
