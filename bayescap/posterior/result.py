"""The fit result: posterior draws of the noise model, their summaries, the derived quantities
(:mod:`bayescap.posterior.derived`), the convergence diagnostics (:mod:`bayescap.posterior.diagnose`)
and the data checks (:mod:`bayescap.posterior.checks`).

``FitResult.to_dict()`` is the fit JSON of the contract (README, "Fit result JSON").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayescap._version import __version__
from bayescap.inference.chains import ChainResult
from bayescap.inference.diagnostics import interval_end_mcse_mcmc
from bayescap.model.ptc_model import PTCModel
from bayescap.posterior.checks import ChecksMixin
from bayescap.posterior.derived import _DERIVED_FLAGS, _DERIVED_NOTE_PREFIXES, DerivedMixin, derived_per_draw
from bayescap.posterior.diagnose import _END_MCSE_FAILURE, DiagnoseMixin
from bayescap.posterior.display import html_table, short_repr
from bayescap.posterior.inputs import InputsMixin
from bayescap.posterior.limits import apply_parameter_limits
from bayescap.posterior.response_view import response_model_summary
from bayescap.posterior.scene import Scene
from bayescap.posterior.summary import json_safe, summarize

__all__ = ["FitResult", "DerivedValues", "QUANTIZATION_FLOOR_DN"]

#: a read (or one-exposure dark) noise below this many DN is masked by quantization (EMVA 1288): it is
#: reported as an upper limit no lower than this floor
QUANTIZATION_FLOOR_DN = 0.4


class DerivedValues:
    """:meth:`FitResult.derived_values_fn`: ``self(x) -> {name: values (n,)}``, every derived
    quantity of draws ``x`` (n, ndim). ``inputs`` is what it computes with, ``(model, metadata,
    scene, mtf, seed)``: a result made with the same inputs reuses the fast path's errors of the
    derived quantities' interval ends (``_derived_end_mcse_importance``)."""

    def __init__(self, result_cls, inputs):
        self.result_cls = result_cls
        self.inputs = inputs
        self._per_draw = None

    @property
    def per_draw(self) -> bool:
        """Whether each draw's values depend on that draw alone, so that a caller may compute them
        for new draws only and join them to earlier ones (:class:`bayescap.inference.end_errors.PerDrawValues`):
        not when the MTF has its own draws (:func:`bayescap.posterior.derived.derived_per_draw`)."""
        if getattr(self, "_per_draw", None) is None:
            self._per_draw = derived_per_draw(self.inputs[3])
        return self._per_draw

    def __call__(self, x):
        model, metadata, scene, mtf, seed = self.inputs
        x = np.asarray(x, float)
        tmp = self.result_cls._of_chain(
            model, x.reshape(1, -1, 1, x.shape[-1]), metadata=metadata, scene=scene, mtf=mtf, seed=seed, repeats=False
        )
        return {n: np.asarray(v, float) for n, v in tmp.derived.items() if np.size(v) == x.shape[0]}


@dataclass(repr=False)
class FitResult(DerivedMixin, DiagnoseMixin, ChecksMixin, InputsMixin):
    """Posterior of one sensor's noise model and everything derived from it."""

    model: PTCModel
    chains: ChainResult
    metadata: dict
    scene: Scene
    mtf: object
    seed: int | None
    quality: str
    draws: dict = field(default_factory=dict)  # physical name -> (n_samples,) all samples
    derived: dict = field(default_factory=dict)  # derived name -> (n_samples,)
    notes: list = field(default_factory=list)  # human-readable caveats, in order
    flags: dict = field(default_factory=dict)  # machine-readable caveats
    diag: dict = field(default_factory=dict)
    mtf_info: dict = field(default_factory=dict)
    input_warnings: list = field(default_factory=list)  # plausibility of the input (JSON "warnings")

    def __repr__(self) -> str:
        """Sensor, quality, convergence, K, read noise and capacity with their 95 % intervals."""
        return short_repr(self)

    def _repr_html_(self) -> str:
        """A table for notebooks: each parameter and derived quantity's median, 95 % interval, unit."""
        return html_table(self)

    def save(self, path):
        """Write this result to ``path`` (netCDF: the InferenceData of ``posterior.nc`` plus what
        the report needs; :mod:`bayescap.posterior.storage`), atomically. Returns the path."""
        from bayescap.posterior.storage import save_result

        return save_result(self, path)

    @classmethod
    def load(cls, path) -> "FitResult":
        """A result written by :meth:`save`: its ``to_dict()`` (the JSON) and report are the saved one's."""
        from bayescap.posterior.storage import load_result

        return load_result(path, cls)

    @classmethod
    def from_chains(cls, model: PTCModel, chains: ChainResult, *, metadata, scene, mtf, seed, quality, checked=None):
        """The result of ``chains``; ``checked``: the ``derived_fn`` of :meth:`chain_check_fns` made
        with the same inputs, whose computation on the last chain it checked is taken over when that
        chain is ``chains.chain`` (the MCMC's final round: its derived quantities are not computed twice)."""
        self = cls(model=model, chains=chains, metadata=metadata, scene=scene, mtf=mtf, seed=seed, quality=quality)
        self.notes.extend(getattr(model, "data_notes", []))  # rows left out before the fit (model.rows_to_fit)
        tmp = None if checked is None else checked.result_of(chains.chain)
        if tmp is not None:
            self.draws, self.derived, self.mtf_info = tmp.draws, tmp.derived, tmp.mtf_info
            self.notes.extend(tmp.notes)
            self.flags.update(tmp.flags)
        else:
            E, S, W, D = chains.chain.shape
            self._derive_draws(chains.chain.reshape(E * S * W, D))
        self._diagnose()
        self._check_rows()
        self._check_inputs()
        return self

    @classmethod
    def chain_check_fns(cls, model: PTCModel, *, metadata, scene, mtf, seed):
        """``(derived_fn, reported_fn)`` for :func:`bayescap.inference.mcmc.run_ensembles`'s checks
        after each round, each ``fn(chain) -> {name: (E, S, W) draws}``: ``derived_fn`` the derived quantities
        whose convergence :meth:`_diagnose` checks (capacity, tonal range); ``reported_fn`` every
        quantity the result gives an interval for (physical parameters and derived quantities,
        constants left out), whose interval ends' Monte Carlo error the checks compute once the
        others pass. The two share the derived draws of the last chain they were given: a round's
        checks call both on the same chain, and each computation costs ~5–11 ms (capacity, TR, ...)."""
        last = [None, None]

        def of(chain):
            if last[0] is not chain:
                last[:] = [chain, cls._of_chain(model, chain, metadata=metadata, scene=scene, mtf=mtf, seed=seed)]
            return last[1]

        def derived_fn(chain):
            tmp = of(chain)
            return {
                n: tmp.derived[n].reshape(chain.shape[:3])
                for n in ("capacity_bits", "capacity_bits_per_pixel", "tonal_range_bits")
                if n in tmp.derived
            }

        def reported_fn(chain):
            return of(chain)._reported_draws(chain.shape[:3])

        # (for from_chains: the result computed on the last chain checked, if it is ``chain``)
        derived_fn.result_of = lambda chain: last[1] if last[0] is chain else None
        return derived_fn, reported_fn

    @classmethod
    def derived_values_fn(cls, model: PTCModel, *, metadata, scene, mtf, seed):
        """``fn(x) -> {name: values (n,)}``: every derived quantity (capacity, TR, DR, SNR, ...) of
        draws ``x`` (n, ndim), as the result computes them; for the fast path's top-up towards its
        gate on the interval ends' Monte Carlo error (:func:`bayescap.inference.fast.fast_posterior`'s
        ``derived_fn``) and the result's own check of the same errors. A :class:`DerivedValues`
        (module level, so that a result holding it pickles: ``fit_many(..., n_jobs=2)``)."""
        return DerivedValues(cls, (model, metadata, scene, mtf, seed))

    def _same_derived_inputs(self, inputs) -> bool:
        """Whether :meth:`derived_values_fn`'s ``inputs`` are this result's (the same model and MTF
        objects, equal metadata, scene and seed)."""
        if inputs is None:
            return False
        model, metadata, scene, mtf, seed = inputs
        try:
            return bool(
                model is self.model
                and mtf is self.mtf
                and seed == self.seed
                and scene == self.scene
                and metadata == self.metadata
            )
        except (TypeError, ValueError):  # metadata values that do not compare (arrays)
            return False

    @classmethod
    def _of_chain(cls, model, chain, *, metadata, scene, mtf, seed, repeats=True):
        """A result without chains holding the physical draws and derived quantities of ``chain``
        (E, S, W, D), for the checks :func:`bayescap.inference.mcmc.run_ensembles` makes after each
        round (``repeats``: the draws may repeat, :meth:`_derive_draws`)."""
        E, S, W, D = chain.shape
        tmp = cls(model=model, chains=None, metadata=metadata, scene=scene, mtf=mtf, seed=seed, quality="")
        tmp._derive_draws(chain.reshape(E * S * W, D), repeats=repeats)
        return tmp

    def _reported_draws(self, shape):
        """{name: draws reshaped (E, S, W)} of the physical parameters and derived quantities
        that vary (a constant has no Monte Carlo error)."""
        n = int(np.prod(shape))
        out = {}
        for name, v in list(self.draws.items()) + list(self.derived.items()):
            v = np.asarray(v, float)
            if v.size == n and np.ptp(v) > 0:
                out[name] = v.reshape(shape)
        return out

    @property
    def shape_esw(self):
        E, S, W, _ = self.chains.chain.shape
        return (E, S, W)

    def at_scene(self, scene: "Scene") -> "FitResult":
        """The same posterior evaluated at another scene (exposure time, temperature): derived
        quantities, notes and noise budget are recomputed, the draws are shared."""
        new = FitResult(
            model=self.model,
            chains=self.chains,
            metadata=self.metadata,
            scene=scene,
            mtf=self.mtf,
            seed=self.seed,
            quality=self.quality,
            draws=self.draws,
        )
        new.notes = [n for n in self.notes if not n.startswith(_DERIVED_NOTE_PREFIXES)]
        new.flags = {k: v for k, v in self.flags.items() if k not in _DERIVED_FLAGS}
        new.diag = dict(self.diag)
        new.input_warnings = list(self.input_warnings)
        new.outliers = list(getattr(self, "outliers", []))
        new._derive()
        if new.diag.get("method") in ("emcee", "laplace-is") and new.diag.get("interval_end_mcse"):
            # the derived quantities moved with the scene, and so did their interval ends' error
            end = {k: v for k, v in new.diag["interval_end_mcse"].items() if k not in new.derived}
            if new.diag["method"] == "emcee":
                end.update(
                    {
                        n: interval_end_mcse_mcmc(x)
                        for n, x in new._reported_draws(new.shape_esw).items()
                        if n in new.derived
                    }
                )
            else:
                end.update(new._derived_end_mcse_importance())
            failure = new._set_end_mcse(end, new.diag.get("interval_end_mcse_target"))
            failed = [f for f in new.diag["failed_checks"] if not f.startswith(_END_MCSE_FAILURE)]
            new.diag["failed_checks"] = failed + ([failure] if failure else [])
            if failure and new.diag["converged"]:
                new.diag["converged"] = False
                new.notes.insert(0, "NOT CONVERGED at this scene: " + failure + ". Do not use these intervals")
            new._flag_imprecise_ends()
        return new

    def push(self, fn, n_max=None):
        """Push a function of the physical-parameter dict through the posterior draws.

        ``fn(draws: dict[str, ndarray]) -> ndarray`` must be vectorised over the leading axis."""
        p = self.draws if n_max is None else {k: v[self.thin_index(n_max)] for k, v in self.draws.items()}
        return fn(p)

    def thin_index(self, n_max):
        n = next(iter(self.draws.values())).size
        if n <= n_max:
            return np.arange(n)
        return np.linspace(0, n - 1, n_max).round().astype(int)

    def parameter_summary(self) -> dict:
        """The contract's ``parameters`` block, with identifiability flags and, for what the data
        do not determine, a ``limit`` (:func:`~bayescap.posterior.limits.apply_parameter_limits`).
        Walkers stranded far below the mode are left out (:meth:`summary_draws`)."""
        p, m, out = self.summary_draws(), self.model, {}
        k = p["conversion_gain_e_per_dn"]
        out["conversion_gain_e_per_dn"] = summarize(k, "e-/DN")

        def nonneg(name, x, unit, why_floor=None):
            q = np.quantile(x, [0.025, 0.5, 0.95])
            detected = q[0] > 0.2 * q[1] and why_floor is None
            extra = {}
            if not detected:
                extra["upper_limit_95"] = float(q[2]) if why_floor is None else floor_limit(x)
                extra["note"] = why_floor or ("the posterior reaches down to zero: an upper limit, not a detection")
            out[name] = summarize(x, unit, constrained=detected, **extra)

        def floor_limit(x):
            # below the quantization floor the posterior's precision rests on how many pixels the
            # noise carries across a rounding boundary, which the model takes from smooth Gaussian
            # noise and offset distributions; a ROI's realised count scatters beyond that (zoo:
            # the 95 % point 2-4 % below the truth, i37_8bit_k100_dsnu, sub_12bit_read0p2_int), so
            # the limit is the floor itself unless the posterior reaches above it
            return max(float(np.quantile(x, 0.95)), QUANTIZATION_FLOOR_DN * float(np.median(k)))

        if m.terms.dark_current:
            rn = p["read_noise_e"]
            floor = None
            if np.median(rn / k) < QUANTIZATION_FLOOR_DN:
                floor = (
                    "read noise below 0.4 DN is masked by quantization (EMVA 1288): an upper limit only, "
                    "the larger of the posterior's 95 % point and 0.4 DN"
                )
            nonneg("read_noise_e", rn, "e-", floor)
            nonneg("dark_current_e_per_s", p["dark_current_e_per_s"], "e-/s")
        elif not getattr(m, "dark_rows", True):
            self._intercept_read_noise(out, p["dark_noise_e"], k, floor_limit)
        else:
            dn = p["dark_noise_e"]
            t = float(np.unique(m.t[m.t > 0])[0]) if np.any(m.t > 0) else 0.0
            note = f"sqrt(read² + D·t) at t = {t:g} s: the only identifiable combination with one exposure time"
            masked = np.median(dn / k) < QUANTIZATION_FLOOR_DN
            dn_limit = floor_limit(dn) if masked else float(np.quantile(dn, 0.95))
            if masked:
                out["dark_noise_e"] = summarize(
                    dn,
                    "e-",
                    constrained=False,
                    upper_limit_95=dn_limit,
                    note=note + "; below 0.4 DN it is masked by quantization (EMVA 1288): an upper limit only, "
                    "the larger of the posterior's 95 % point and 0.4 DN",
                )
            else:
                out["dark_noise_e"] = summarize(dn, "e-", note=note)
            out["read_noise_e"] = summarize(
                dn,
                "e-",
                constrained=False,
                upper_limit_95=dn_limit,
                note="not separable from dark current with one exposure time: "
                "the interval is that of sqrt(read² + D·t), an upper limit",
            )
            if t > 0:
                dc = dn**2 / t
                out["dark_current_e_per_s"] = summarize(
                    dc,
                    "e-/s",
                    constrained=False,
                    upper_limit_95=dn_limit**2 / t,
                    note="upper limit (all dark noise attributed to D·t)",
                )
        if "full_well_e" in p:
            extra = {}
            if m.terms.clip == "adc":
                extra = {
                    "clip_source": "adc",
                    "note": "the output clips at the ADC maximum: this is the charge at the clip; "
                    "the photodiode's own well may be deeper",
                }
            else:
                extra = {"clip_source": "full_well_or_adc"}
            if getattr(m, "response_share_unknown", False):
                share = (
                    "without photon counts the photon-transfer curve's bend may be the response's (bent means: "
                    "more charge at the clip) or brighter-fatter's (straight means: (clip − black)·K); the "
                    "interval spans both readings, half the draws taking each"
                )
                extra["note"] = f"{extra['note']}; {share}" if "note" in extra else share
            out["full_well_e"] = summarize(p["full_well_e"], "e-", **extra)
        else:
            lb = float(np.quantile((m.max_mean_ok - m.black_dn) * k, 0.025))
            out["full_well_e"] = {
                "median": None,
                "ci68": [lb, None],
                "ci95": [lb, None],
                "unit": "e-",
                "constrained": False,
                "lower_bound": lb,
                "note": "no row reaches saturation: only a lower bound (the largest measured signal)",
            }
        if "quantum_efficiency" in p:
            out["quantum_efficiency"] = summarize(p["quantum_efficiency"], "")
        if "prnu_percent" in p:
            nonneg("prnu_percent", p["prnu_percent"], "%")
        if "dsnu_e" in p:
            nonneg("dsnu_e", p["dsnu_e"], "e-")
        if m.terms.discrepancy:
            out["variance_discrepancy"] = summarize(
                p["variance_discrepancy"], "", note="fractional scatter of the variances beyond statistics"
            )
        if "clip_spread_dn" in p:
            out["clip_spread_dn"] = summarize(p["clip_spread_dn"], "DN", note="spread of pixel means at the clip")
        if "mean_discrepancy" in p:
            out["mean_discrepancy"] = summarize(p["mean_discrepancy"], "", note="fractional non-linearity scatter")
        if "response_nonlinearity" in p:
            out["response_nonlinearity"] = summarize(
                p["response_nonlinearity"],
                "",
                note="fractional deviation of the response at the largest unclipped signal",
            )
        for j in range(1, 64):
            if f"response_shape_{j}" not in p:
                break
            out[f"response_shape_{j}"] = summarize(
                p[f"response_shape_{j}"], "", note="coefficient of the response's log-slope (docs/model.md)"
            )
        if "brighter_fatter_a00_per_e" in p:
            out["brighter_fatter_a00_per_e"] = summarize(
                p["brighter_fatter_a00_per_e"],
                "1/e-",
                note="brighter-fatter a00 (Astier et al. 2019 Eq. 16); negative: the variance grows less than the mean",
            )
        if "pixel_offset_spread_dn" in p:
            nonneg("pixel_offset_spread_dn", p["pixel_offset_spread_dn"], "DN")
        return apply_parameter_limits(self, out)

    def _intercept_read_noise(self, out, rn, k, floor_limit):
        """``read_noise_e`` of a table without dark pairs (a mean/variance table): the PTC's intercept,
        in electrons (it also holds any dark-current shot noise the flats collected)."""
        note = "the photon-transfer curve's intercept (no dark pairs): read noise, plus any dark-current shot noise of the flats"
        if np.median(rn / k) < QUANTIZATION_FLOOR_DN:
            out["read_noise_e"] = summarize(
                rn,
                "e-",
                constrained=False,
                upper_limit_95=floor_limit(rn),
                note=note + "; below 0.4 DN it is masked by quantization (EMVA 1288): an upper limit only, "
                "the larger of the posterior's 95 % point and 0.4 DN",
            )
        else:
            out["read_noise_e"] = summarize(rn, "e-", note=note)
            _prior_dominated_intercept(out["read_noise_e"], rn, self.model.PRIOR["read_scale_e"])

    def emva1288(self) -> dict:
        """The fit in EMVA 1288 (Release 4.0) terms, with intervals (:func:`bayescap.posterior.emva.emva1288_view`)."""
        from bayescap.posterior.emva import emva1288_view

        return emva1288_view(self)

    def to_dict(self) -> dict:
        sensor = dict(self.metadata)
        diag = {k: v for k, v in self.diag.items()}
        params = self.parameter_summary()
        return json_safe(
            {
                "bayescap_version": __version__,
                "input": self.model.data.source,
                "sensor": sensor,
                "scene": self.scene.to_dict(),
                "parameters": params,
                "derived": self.derived_summary(params),
                "model_terms": self.model.terms.names(),
                "terms_left_out": dict(self.model.terms.reasons),
                "term_notes": dict(self.model.terms.how),
                "response_model": response_model_summary(self),
                "mtf": self.mtf_info,
                "noise_budget_mid_grey": self.noise_budget(),
                "outliers": list(getattr(self, "outliers", [])),
                **({"model_selection": self.model_selection} if getattr(self, "model_selection", None) else {}),
                "notes": list(self.notes),
                "warnings": [dict(w) for w in self.input_warnings],
                "flags": dict(self.flags),
                "diagnostics": diag,
            }
        )


def _prior_dominated_intercept(s, rn, scale_e):
    """The intercept's read noise as an upper limit when its 95 % interval is as wide as the prior's
    (the rule :func:`~bayescap.posterior.limits.apply_parameter_limits` applies to ``read_noise_e``)."""
    from bayescap.posterior.limits import PRIOR_DOMINATED_FRACTION

    prior_width = (2.2414 - 0.03134) * scale_e
    lo, hi = np.quantile(rn, [0.025, 0.975])
    if hi - lo > PRIOR_DOMINATED_FRACTION * prior_width:
        s["constrained"] = False
        s["upper_limit_95"] = float(np.quantile(rn, 0.95))
        s["note"] = (
            f"the intercept hardly constrains it: its 95 % interval is {(hi - lo) / prior_width:.0%} as wide "
            f"as the prior's (half-normal, scale {scale_e:g} e-)"
        )
