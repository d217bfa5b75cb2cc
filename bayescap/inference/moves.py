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

    #: the most ``log_prob`` points one batched call of planned steps evaluates (:meth:`plan`): below
    #: :class:`~bayescap.inference.lockstep.Lockstep`'s ``solo_points``, so that a batch still shares
    #: its call with the other ensembles' requests
    BATCH_POINTS = 480

    def __init__(self, mean, cov, *, nu: float = 6.0, scale: float = 1.0):
        self.mean = np.asarray(mean, float)
        self.nu = float(nu)
        c = _proposal_cov(np.asarray(cov, float), scale)
        try:
            self.L = np.linalg.cholesky(c)
        except np.linalg.LinAlgError:  # eigenvalue floor at 1e-14 of the largest can still fail: jitter
            self.L = np.linalg.cholesky(c + 1e-10 * np.max(np.diag(c)) * np.eye(c.shape[0]))
        # (a product with the inverse factor, once, instead of a general solve at every step: ~0.1 ms)
        self._L_inv = np.linalg.inv(self.L)
        self.n_proposed = 0
        self.n_accepted = 0
        self._planned = 0  # steps this move takes in the current run (plan); 0: one call per step
        self._batch = None  # (proposals (B, n, d), their log q (B, n), their log p (B, n)), next index
        self._next = 0
        super().__init__(self._get_proposal, ndim=self.mean.size)

    def plan(self, n_steps: int):
        """Announce that this move takes the next ``n_steps`` steps of the run (:class:`_Sampler`
        draws the run's sequence of moves first). The proposals do not depend on the walkers'
        positions, so those of several steps are drawn, and their ``log_prob`` evaluated, in one
        call (at most :data:`BATCH_POINTS` points): a call on a few walkers costs mostly per-call
        overhead. Each step then accepts or rejects its own proposals against the walkers' current
        positions, as one step at a time would: the same Markov chain (the random stream is drawn
        in a different order). 0 (the default, and after each run): one call per step."""
        self._planned = max(0, int(n_steps))
        self._batch = None
        self._next = 0

    def log_q(self, x):
        """log proposal density up to a constant (the constant cancels in the ratio)."""
        z = self._L_inv @ (np.atleast_2d(x) - self.mean).T
        maha = np.einsum("ij,ij->j", z, z)
        return -0.5 * (self.nu + self.mean.size) * np.log1p(maha / self.nu)

    def propose(self, model, state):
        if self._planned > 0:
            state, accepted = self._propose_planned(model, state)
        else:
            state, accepted = super().propose(model, state)
        self.n_proposed += accepted.size
        self.n_accepted += int(np.sum(accepted))
        return state, accepted

    def _propose_planned(self, model, state):
        """One step of :meth:`propose` from the batch of :meth:`plan` (drawn and evaluated when it
        is used up): emcee's ``MHMove.propose`` with the proposals, their log q and log p taken
        from the batch."""
        n, d = state.coords.shape
        if self._batch is None or self._next >= self._batch[0].shape[0]:
            b = max(1, min(self._planned, self.BATCH_POINTS // max(n, 1)))
            z = model.random.standard_normal((b, n, d))
            u = model.random.chisquare(self.nu, size=(b, n)) / self.nu
            q = self.mean + (z @ self.L.T) / np.sqrt(u)[..., None]
            log_q_new = -0.5 * (self.nu + d) * np.log1p(np.einsum("bij,bij->bi", z, z) / u / self.nu)
            lp, _ = model.compute_log_prob_fn(q.reshape(b * n, d))
            self._batch, self._next = (q, log_q_new, np.asarray(lp, float).reshape(b, n)), 0
        q, log_q_new, lp = (a[self._next] for a in self._batch)
        self._next += 1
        self._planned -= 1
        # MHMove: log p(x') − log p(x) + log q(x) − log q(x')
        lnpdiff = lp - state.log_prob + self.log_q(state.coords) - log_q_new
        accepted = np.log(model.random.rand(n)) < lnpdiff
        new_state = emcee.State(q, log_prob=lp)
        return self.update(state, new_state, accepted), accepted

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
      no-op, as emcee's setter ignores a state it cannot set);
    - :meth:`sample` draws the run's moves first, so that the IndependenceMove evaluates the
      proposals of several of its steps in one call (:meth:`IndependenceMove.plan`)."""

    @property
    def random_state(self):
        return _RANDOM_STATE_LATER

    @random_state.setter
    def random_state(self, state):
        if not (isinstance(state, str) and state == _RANDOM_STATE_LATER):
            emcee.EnsembleSampler.random_state.fset(self, state)

    def sample(
        self,
        initial_state,
        iterations=1,
        tune=False,
        skip_initial_state_check=False,
        store=True,
        progress=False,
        **kwargs,
    ):
        """emcee's ``sample`` with the run's sequence of moves drawn first, so that a move that can
        batch its proposals (:meth:`IndependenceMove.plan`) knows how many steps it takes. The
        rest is emcee's loop: the initial state's checks, one move per step, every step stored.
        Runs without such a move, without a fixed length, with tuning or with emcee's other options
        (thinning, a progress bar) are emcee's own (the same chain as emcee's sampler, bit for bit)."""
        if iterations is None or tune or progress or kwargs or not any(hasattr(m, "plan") for m in self._moves):
            yield from super().sample(
                initial_state,
                iterations=iterations,
                tune=tune,
                skip_initial_state_check=skip_initial_state_check,
                store=store,
                progress=progress,
                **kwargs,
            )
            return
        from emcee.ensemble import walkers_independent
        from emcee.model import Model

        state = emcee.State(initial_state, copy=True)
        if np.shape(state.coords) != (self.nwalkers, self.ndim):
            raise ValueError(f"incompatible input dimensions {np.shape(state.coords)}")
        if not skip_initial_state_check and not walkers_independent(state.coords):
            raise ValueError(
                "Initial state has a large condition number. Make sure that your walkers are linearly "
                "independent for the best performance"
            )
        self.random_state = state.random_state
        if state.log_prob is None:
            state.log_prob, state.blobs = self.compute_log_prob(state.coords)
        if np.shape(state.log_prob) != (self.nwalkers,):
            raise ValueError("incompatible input dimensions")
        if np.any(np.isnan(state.log_prob)):
            raise ValueError("The initial log_prob was NaN")
        if store:
            self.backend.grow(iterations, state.blobs)
        model = Model(self.log_prob_fn, self.compute_log_prob, map, self._random)
        picks = self._random.choice(len(self._moves), size=int(iterations), p=self._weights)
        planned = [(j, m) for j, m in enumerate(self._moves) if hasattr(m, "plan")]
        for j, m in planned:
            m.plan(int(np.count_nonzero(picks == j)))
        try:
            for j in picks:
                state, accepted = self._moves[j].propose(model, state)
                state.random_state = self.random_state
                if store:
                    self.backend.save_step(state, accepted)
                yield state
        finally:
            for _, m in planned:
                m.plan(0)

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
