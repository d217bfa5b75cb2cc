"""Several :class:`~bayescap.model.PTCModel` of one structure evaluated in one ``log_prob``
call (:class:`PTCModelStack`), through a view of the model on per-draw gathered data.
"""

from __future__ import annotations

import copy

import numpy as np

from bayescap.model.ptc_model import PTCModel, _log_posterior

__all__ = ["PTCModelStack"]


class PTCModelStack:
    """Several :class:`PTCModel` of one structure evaluated in one ``log_prob`` call (issue 7:
    a batch vectorised across sensors, :func:`bayescap.batch.fit_many`).

    A ``log_prob`` call on a few points costs ~0.6 ms, almost all of it per-call overhead (the
    fast path makes ~200 such calls per sensor); stacking sensors pays it once per call. Sensors
    stack when :meth:`signature` agrees: the same parameters, terms and prior, and the same rows
    in every block (clip rows, spatial rows, fully clipped rows), so every array of the model has
    the same shape. The per-row data become (n_draws, rows) arrays gathered by each draw's sensor
    and the per-sensor numbers (black level, ADC maximum, clip-level bounds) per-draw arrays;
    :class:`PTCModel`'s own methods then run unchanged on that view.

    A sensor's numbers do not depend on the other sensors in the call: every operation is
    elementwise over (draw, row) except the choice of rows near the clip, which is taken over
    each request's draws (``request``), as a single model takes it over its call's draws.
    ``tests/test_batch.py`` checks that a stacked call equals each model's own ``log_prob``
    bit for bit.
    """

    #: per-row data arrays (stacked along a new first axis)
    ROW_ARRAYS = (
        "m",
        "v",
        "vd",
        "dm",
        "tt",
        "t",
        "nu",
        "nu_d",
        "s_obs",
        "mu_p",
        "full_means",
        "full_v",
        "full_nu",
        "full_sd",
        "sp",
        "spd",
        "L_ok",
        "L_all",
        "dark_frac_dn",
        "bright_frac_dn",
        "full_frac_dn",
        "t_full",
        "vd_ok",
        "mean_rounding_var",
        "dmn",
        "dmn_mbar",
        "dmn_tc",
        "dmn_sd",
        "sat_fs",
        "sat_sd",
    )

    def __init__(self, models):
        self.models = list(models)
        if not self.models:
            raise ValueError("PTCModelStack needs at least one model")
        sig = self.signature(self.models[0])
        for i, m in enumerate(self.models[1:], 1):
            if self.signature(m) != sig:
                raise ValueError(
                    f"model {i} does not stack with model 0: different parameters, terms, "
                    "prior or block rows (group models by PTCModelStack.signature)"
                )
        m0 = self.models[0]
        self.ndim, self.names = m0.ndim, m0.names
        # one model stacked with itself (the ensembles of an MCMC preset in lockstep,
        # bayescap.inference.mcmc._run_segments): its own data serve every draw, nothing to gather
        self._same = all(m is m0 for m in self.models)
        self._rows = (
            {}
            if self._same
            else {a: np.stack([getattr(m, a) for m in self.models]) for a in self.ROW_ARRAYS if hasattr(m0, a)}
        )
        self._black = np.array([m.black_dn for m in self.models], float)
        self._adc = None if m0.adc is None else np.array([m.adc for m in self.models], float)
        self._nu_pattern = np.array([m.nu_pattern for m in self.models], float)
        self._clip_bounds = (
            None
            if m0.clip_bounds is None
            else tuple(np.array([m.clip_bounds[j] for m in self.models], float) for j in (0, 1))
        )

    @staticmethod
    def signature(model: PTCModel):
        """What must agree for models to stack (a hashable tuple)."""
        tm = model.terms
        terms = (
            tm.dark_current,
            tm.clip,
            tm.clip_spread,
            tm.quantum_efficiency,
            tm.prnu,
            tm.dsnu,
            tm.robust,
            tm.discrepancy,
            getattr(model, "dark_rows", True),
            getattr(tm, "dark_mean", False),
            # the response's reference signal is the model's own (one per sensor)
            model.response_ref_dn if (tm.nonlinearity or tm.brighter_fatter) else None,
        )
        shapes = tuple((a, np.shape(getattr(model, a))) for a in PTCModelStack.ROW_ARRAYS if hasattr(model, a))
        rows = tuple(
            tuple(np.asarray(getattr(model, a)).tolist())
            for a in ("clip_rows", "lin_rows", "sp_rows", "spd_rows", "sat_rows")
        )
        prior = tuple(sorted((k, repr(v)) for k, v in model.PRIOR.items()))
        return (
            tuple(model.names),
            terms,
            shapes,
            rows,
            int(np.sum(model.full_sat)),
            model.adc is None,
            model.clip_bounds is None,
            prior,
        )

    def view(self, sensor, request=None) -> PTCModel:
        """A PTCModel whose data are those of ``sensor[i]`` for draw ``i`` (``request``: the id of
        the request each draw belongs to, for the per-request reductions)."""
        sensor = np.asarray(sensor, int)
        v = copy.copy(self.models[0])
        v._memo = {}  # model 0's initial guess is not this view's
        if self._same:
            # the model's own (rows,) arrays broadcast over the draws as in a single model's call;
            # only the choice of rows near the clip is per request. (With gathered (draws, rows)
            # copies a lockstep call of 2 × 48 draws took 6-7 % longer)
            v._request_ids = np.asarray(sensor if request is None else request)
            v._request_segments = None
            return v
        v.__class__ = _StackView
        v._stack_rows, v._stack_sensor, v._gathered = self._rows, sensor, {}
        v.black_dn = self._black[sensor]
        v.adc = None if self._adc is None else self._adc[sensor]
        v.nu_pattern = self._nu_pattern[sensor][:, None]
        v.clip_bounds = None if self._clip_bounds is None else tuple(b[sensor] for b in self._clip_bounds)
        v._request_ids = np.asarray(sensor if request is None else request)
        v._request_segments = None
        return v

    def log_prob(self, theta, sensor, request=None):
        """``PTCModel.log_prob`` of draw ``theta[i]`` under model ``sensor[i]``: (n,).

        Draws of one request must be contiguous (the clip-row choice is per request)."""
        sensor = np.asarray(sensor, int)
        request = sensor if request is None else np.asarray(request)
        return _log_posterior(
            theta,
            lambda good: self.view(
                sensor if good is None else sensor[good], request if good is None else request[good]
            ),
        )


class _GatheredRows:
    """A per-row data array of a :class:`PTCModelStack` view, gathered by draw on first use (a
    log-prior evaluation, or a model that does not use the array, never pays for it)."""

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        got = obj._gathered
        if self.name not in got:
            got[self.name] = obj._stack_rows[self.name][obj._stack_sensor]
        return got[self.name]

    def __set__(self, obj, value):
        obj._gathered[self.name] = value


class _StackView(PTCModel):
    """A :class:`PTCModel` evaluated on stacked data (made by :meth:`PTCModelStack.view` only)."""


for _a in PTCModelStack.ROW_ARRAYS:
    _d = _GatheredRows()
    _d.__set_name__(_StackView, _a)
    setattr(_StackView, _a, _d)
del _a, _d
