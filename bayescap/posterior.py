"""The fit result: posterior draws of the noise model, their summaries, derived quantities
(SNR, DR, TR, Δs, s', C) pushed through every draw, and convergence diagnostics.

``FitResult.to_dict()`` is the fit JSON of the contract (README, "Fit result JSON").
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from bayescap._version import __version__
from bayescap.exceptions import ConvergenceWarning
from bayescap.inference.chains import ChainResult, stuck_threshold, stuck_walkers
from bayescap.inference.diagnostics import (
    fast_diagnostics,
    interval_end_mcse_mcmc,
    worst_end,
)
from bayescap.io.ptc_csv import _ABSOLUTE_ZERO_C, _MAX_ABS_VALUE
from bayescap.model import PTCModel
from bayescap.physics.capacity import N_GREY_LEVELS, mtf_loss_bits, tonal_range
from bayescap.physics.noise import NoiseCoefficients, dynamic_range_db, snr_db

__all__ = ["FitResult", "Scene", "summarize", "DERIVED_INFO"]

DERIVED_INFO = {
    "tonal_range_bits": ("bits", "b' = log2 TR (Eq. 7), 8-bit-equivalent grey scale"),
    "dynamic_range_db": ("dB", "DR (Eq. 2)"),
    "snr_max_db": ("dB", "SNR at the largest non-saturating signal (Eq. 1)"),
    "mtf_loss_bits": ("bits", "Δs (Eq. 9)"),
    "effective_pixels": ("pixels", "s' = s·2^Δs"),
    "capacity_bits": ("bits", "C = s'·b' (Eq. 6)"),
}


@dataclass(frozen=True)
class Scene:
    """Where TR and capacity are evaluated: exposure time (dark-current charge and shot noise).

    ``temperature_c`` with ``reference_temperature_c`` scales the dark current by 2^(ΔT/6 °C)
    (paper, Section 2.2)."""

    exposure_time_s: float
    source: str = "given"
    temperature_c: float | None = None
    reference_temperature_c: float | None = None

    def __post_init__(self):
        # (a scene exposure of 1e308 s overflowed the dark signal and crashed the noise breakdown)
        if not 0.0 <= self.exposure_time_s <= _MAX_ABS_VALUE:
            raise ValueError(f"scene exposure time must be a number in [0, {_MAX_ABS_VALUE:g}] s, "
                             f"got {self.exposure_time_s}")
        for t in (self.temperature_c, self.reference_temperature_c):
            if t is not None and not _ABSOLUTE_ZERO_C <= t < math.inf:
                raise ValueError(f"scene temperature must be a finite number >= {_ABSOLUTE_ZERO_C:g} °C, got {t}")

    @property
    def dark_current_factor(self) -> float:
        if self.temperature_c is None or self.reference_temperature_c is None:
            return 1.0
        return 2.0 ** ((self.temperature_c - self.reference_temperature_c) / 6.0)

    def to_dict(self):
        d = {"exposure_time_s": self.exposure_time_s, "source": self.source}
        if self.temperature_c is not None:
            d["temperature_c"] = self.temperature_c
            d["reference_temperature_c"] = self.reference_temperature_c
            d["dark_current_factor"] = self.dark_current_factor
        return d


_DERIVED_NOTE_PREFIXES = ("width_px/height_px unknown", "no row reaches saturation", "the MTF reaches zero",
                          "noise stays below one", "the MTF exceeds 1")


#: the start of the failed check of an interval end's Monte Carlo error (FitResult._set_end_mcse)
_END_MCSE_FAILURE = "Monte Carlo error of a 95 % interval end"

#: an MCMC result whose preset does not check its interval ends' Monte Carlo error (``standard``, the
#: fast path's fallback) flags the quantities whose error is above this fraction of the width
#: (``flags["imprecise_interval_ends"]`` and a note). Worst ends: ``standard`` 0.022 in the median and
#: 0.047 at most on the README's 11 sensors (benchmarks/speed_accuracy.py), the fallback (ESS ≥ 200)
#: 0.024–0.073; on the clip-shelf ROIs of the batch whose fast path was rejected, 0.075–0.69
#: (benchmarks/fallback_preset.py; docs/performance.md, "2026-11-25, 01:09–")
IMPRECISE_END_MCSE = 0.1
_IMPRECISE_NOTE = "imprecise interval ends:"


def _mcmc_description(st) -> str:
    """The moves the ensembles ran (``bayescap.fit._moves``): the standard and accurate presets
    mix the IndependenceMove in (before, this said DEMove + StretchMove for every preset)."""
    moves = []
    if getattr(st, "independence_fraction", 0.0) > 0:
        moves.append(f"IndependenceMove (Student-t ν={st.independence_nu:g}) up to "
                     f"{100 * st.independence_fraction:.0f} % of steps")
    moves.append("DEMove" if st.de_fraction >= 1 else "DEMove + StretchMove")
    return "emcee ensembles (" + ", ".join(moves) + "), Gamma likelihood with discrepancy"


def _q(x, qs):
    return [float(v) for v in np.quantile(x, qs)]


def summarize(x, unit="", constrained=True, **extra):
    """Median, 68 % and 95 % equal-tailed intervals of a 1-D array of draws."""
    x = np.asarray(x, float).ravel()
    q = _q(x, [0.025, 0.16, 0.5, 0.84, 0.975])
    out = {"median": q[2], "ci68": [q[1], q[3]], "ci95": [q[0], q[4]], "unit": unit,
           "constrained": bool(constrained)}
    out.update(extra)
    return out


def _json_float(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def rerun_advice(quality) -> str:
    """What to rerun an unconverged MCMC fit of preset ``quality`` with (a preset name, or anything
    else for custom settings): the next preset up; for ``accurate`` (already the longest preset) a
    longer run, which the command line has no flag for."""
    return {"fast": "--quality standard or accurate", "standard": "--quality accurate"}.get(
        quality, "a longer run (from Python: bayescap.fit(..., quality=replace(QUALITY_PRESETS['accurate'], "
                 "max_rounds=40)), with dataclasses.replace and bayescap.fit.QUALITY_PRESETS)")


@dataclass
class FitResult:
    """Posterior of one sensor's noise model and everything derived from it."""

    model: PTCModel
    chains: ChainResult
    metadata: dict
    scene: Scene
    mtf: object
    seed: int | None
    quality: str
    draws: dict = field(default_factory=dict)        # physical name -> (n_samples,) all samples
    derived: dict = field(default_factory=dict)      # derived name -> (n_samples,)
    notes: list = field(default_factory=list)        # human-readable caveats, in order
    flags: dict = field(default_factory=dict)        # machine-readable caveats
    diag: dict = field(default_factory=dict)
    mtf_info: dict = field(default_factory=dict)

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_chains(cls, model: PTCModel, chains: ChainResult, *, metadata, scene, mtf, seed, quality):
        self = cls(model=model, chains=chains, metadata=metadata, scene=scene, mtf=mtf, seed=seed,
                   quality=quality)
        E, S, W, D = chains.chain.shape
        flat = chains.chain.reshape(E * S * W, D)
        self.draws = model.physical(flat)
        self._derive()
        self._diagnose()
        self._check_rows()
        return self

    @classmethod
    def chain_check_fns(cls, model: PTCModel, *, metadata, scene, mtf, seed):
        """``(derived_fn, reported_fn)`` for :func:`bayescap.fit.run_ensembles`'s checks after each
        round, each ``fn(chain) -> {name: (E, S, W) draws}``: ``derived_fn`` the derived quantities
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
            return {n: tmp.derived[n].reshape(chain.shape[:3])
                    for n in ("capacity_bits", "capacity_bits_per_pixel", "tonal_range_bits") if n in tmp.derived}

        def reported_fn(chain):
            return of(chain)._reported_draws(chain.shape[:3])

        return derived_fn, reported_fn

    @classmethod
    def derived_values_fn(cls, model: PTCModel, *, metadata, scene, mtf, seed):
        """``fn(x) -> {name: values (n,)}``: every derived quantity (capacity, TR, DR, SNR, ...) of
        draws ``x`` (n, ndim), as the result computes them; for the fast path's top-up towards its
        gate on the interval ends' Monte Carlo error (:func:`bayescap.fast.fast_posterior`'s
        ``derived_fn``) and the result's own check of the same errors."""
        def fn(x):
            x = np.asarray(x, float)
            tmp = cls._of_chain(model, x.reshape(1, -1, 1, x.shape[-1]), metadata=metadata, scene=scene,
                                mtf=mtf, seed=seed)
            return {n: np.asarray(v, float) for n, v in tmp.derived.items() if np.size(v) == x.shape[0]}
        # what it computes with: a result made with the same inputs reuses the fast path's errors of
        # the derived quantities' interval ends (_derived_end_mcse_importance)
        fn.inputs = (model, metadata, scene, mtf, seed)
        return fn

    def _same_derived_inputs(self, inputs) -> bool:
        """Whether :meth:`derived_values_fn`'s ``inputs`` are this result's (the same model and MTF
        objects, equal metadata, scene and seed)."""
        if inputs is None:
            return False
        model, metadata, scene, mtf, seed = inputs
        try:
            return bool(model is self.model and mtf is self.mtf and seed == self.seed and scene == self.scene
                        and metadata == self.metadata)
        except (TypeError, ValueError):     # metadata values that do not compare (arrays)
            return False

    @classmethod
    def _of_chain(cls, model, chain, *, metadata, scene, mtf, seed):
        """A result without chains holding the physical draws and derived quantities of ``chain``
        (E, S, W, D), for the checks :func:`bayescap.fit.run_ensembles` makes after each round."""
        E, S, W, D = chain.shape
        tmp = cls(model=model, chains=None, metadata=metadata, scene=scene, mtf=mtf, seed=seed, quality="")
        tmp.draws = model.physical(chain.reshape(E * S * W, D))
        tmp._derive()
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

    def _noise_coefficients(self, p, t_s):
        m = self.model
        k = p["conversion_gain_e_per_dn"]
        fac = self.scene.dark_current_factor
        if m.terms.dark_current:
            rd2 = p["read_noise_e"] ** 2 + fac * p["dark_current_e_per_s"] * t_s
        else:
            rd2 = p["dark_noise_e"] ** 2
        dsnu = p.get("dsnu_e", 0.0)
        prnu = p.get("prnu_percent", 0.0) / 100.0
        return NoiseCoefficients.from_parameters(read_noise_e=0.0, dark_noise_e=np.sqrt(rd2), dsnu_e=dsnu,
                                                 prnu_frac=prnu, conversion_gain_e_per_dn=k)

    def signal_max_e(self, p=None):
        """Largest non-saturating signal (e⁻) per draw, and whether it is only a lower bound."""
        p = self.draws if p is None else p
        m = self.model
        k = p["conversion_gain_e_per_dn"]
        t = self.scene.exposure_time_s
        dark_charge = 0.0
        if m.terms.dark_current:
            dark_charge = self.scene.dark_current_factor * p["dark_current_e_per_s"] * t
        if "full_well_e" in p:
            return np.maximum(p["full_well_e"] - dark_charge, 1e-9), False
        return np.maximum((m.max_mean_ok - m.black_dn) * k - dark_charge, 1e-9), True

    def _derive(self):
        p = self.draws
        coeffs = self._noise_coefficients(p, self.scene.exposure_time_s)
        s_max, lower = self.signal_max_e(p)
        tr = tonal_range(coeffs, s_max)
        bprime = np.log2(np.maximum(tr, 1.0))
        ml = mtf_loss_bits(self.mtf, draws=True)
        ds = np.asarray(ml.delta_s_bits, float)
        if ds.ndim == 1 and ds.size > 1:
            # MTF with its own draws (measured): pair them with posterior samples at random
            rng = np.random.default_rng(np.random.SeedSequence(self.seed).spawn(2)[1])
            ds = ds[rng.integers(0, ds.size, size=bprime.size)]
        else:
            ds = np.full_like(bprime, float(ds))
        self.mtf_info = {"model": self.mtf.describe(), **ml.to_dict()}
        w, h = self.metadata.get("width_px"), self.metadata.get("height_px")
        self.derived = {
            "tonal_range_bits": bprime,
            "dynamic_range_db": dynamic_range_db(coeffs, s_max),
            "snr_max_db": snr_db(coeffs, s_max),
            "mtf_loss_bits": ds,
        }
        if w and h:
            s = float(w) * float(h)
            self.derived["effective_pixels"] = s * np.exp2(ds)
            self.derived["capacity_bits"] = self.derived["effective_pixels"] * bprime
        else:
            self.derived["capacity_bits_per_pixel"] = np.exp2(ds) * bprime
            self.notes.append("width_px/height_px unknown: capacity is given per pixel "
                              "(capacity_bits_per_pixel); add '# width_px:' and '# height_px:'")
        if lower:
            self.flags["capacity_lower_bound"] = True
            self.notes.append("no row reaches saturation: the full well, DR, TR and capacity use "
                              "the largest measured signal and are lower bounds")
        if ml.band_cut:
            self.flags["mtf_band_cut"] = True
            self.notes.append(f"the MTF reaches zero at {ml.f_end_cy_per_px:.3f} cy/px, below Nyquist "
                              f"(0.5): the band is cut there, costing {ml.band_cut_bits:.2f} bits of Δs")
        if float(np.median(ds)) > 0.0:
            # Eq. 8/9 are for a low-pass MTF (Δs ≤ 0, the paper); above 1 over much of the band
            # (sharpening in the pipeline, an MTF not normalised at zero frequency) s' exceeds the
            # pixel count, which no capacity comparison should take at face value
            self.flags["mtf_above_one"] = True
            self.notes.append(f"the MTF exceeds 1 over much of the band (Δs = +{float(np.median(ds)):.2f} bits): "
                              "Eq. 9 assumes a low-pass MTF (Δs ≤ 0), so the effective pixels exceed the pixel "
                              "count; use an MTF measured without sharpening")
        if np.any(tr >= 0.999 * N_GREY_LEVELS * (1 - 1e-9)):
            self.notes.append("noise stays below one 8-bit grey level over part of the range: TR is "
                              "limited by the 8-bit-equivalent scale (the max(σ, 1) floor of Eq. 7)")

    # ----------------------------------------------------------------- diagnostics
    def _diagnose(self):
        if self.chains.extra.get("method") == "laplace-is":
            self._diagnose_importance()
        else:
            self._diagnose_mcmc()
        f = np.median(self.draws["variance_discrepancy"])
        if f > 0.05:
            self.notes.append(f"the variances scatter {100 * f:.1f} % beyond their statistical error: "
                              "the model or the measurements are inadequate (check linearity, lamp "
                              "stability, outlier rows)")

    def _diagnose_importance(self):
        """Draws resampled from Laplace–IS (:mod:`bayescap.fast`): independent draws, so R-hat,
        walker ESS and τ do not apply; the checks are PSIS's Pareto k̂ and the IS ESS."""
        c = self.chains
        x = c.extra
        E, S, W, D = c.chain.shape
        failed = [] if x["accepted"] else [x["reason"]]
        self.diag = {
            "method": "laplace-is",
            "method_description": "Laplace approximation + Pareto-smoothed importance sampling "
                                  f"(Student-t ν={x['nu']:g} proposal), Gamma likelihood with discrepancy",
            "quality": self.quality,
            "converged": bool(x["accepted"]),
            "failed_checks": failed,
            "rhat_max": None,              # R-hat does not apply to resampled independent draws
            "rhat_applicable": False,
            "ess_min": float(x["ess_is"]),
            "rhat_target": c.settings.rhat_target,
            "ess_target": float(x["min_ess_is"]),
            "khat": float(x["khat"]),
            "khat_max": float(x["khat_max"]),
            "ess_is": float(x["ess_is"]),
            "n_proposals": int(x["n_proposals"]),
            "n_draws": int(S),
            "retried_with_restarts": bool(x.get("retried_with_restarts", False)),
            "fast_path_accepted": bool(x["accepted"]),
            "n_ensembles": E, "n_walkers": W, "n_steps": S, "n_burn": 0, "n_rounds": 0,
            "tau_max_steps": 1.0, "acceptance": [1.0],
            "wall_s": c.wall_s,
            "seed": self.seed,
            "fast_path": (f"fast path (Laplace–IS): Pareto k̂ {x['khat']:.2f} (accept < "
                          f"{x['khat_max']:g}), importance-sampling ESS {x['ess_is']:.0f} of "
                          f"{x['n_proposals']} proposals (accept ≥ {x['min_ess_is']:g}); R-hat does not apply"),
            "per_quantity": {},
        }
        # the importance draws' own Monte Carlo error of each 95 % interval end (fast.interval_end_mcse):
        # the physical parameters' from the fast path, the derived quantities' computed here
        mcse = {**(x.get("end_mcse") or {}), **self._derived_end_mcse_importance()}
        if mcse:
            gate = x.get("end_mcse_max")
            failure = self._set_end_mcse(mcse, gate)
            worst = self.diag["interval_end_mcse_worst"]
            self.diag["n_topup"] = int(x.get("n_topup", 0))
            if failure and worst in self.derived:
                # the fast path's gate covers the parameters (a parameter above it is already in
                # its reason); a derived quantity above it fails here
                self.diag["failed_checks"].append(failure)
                self.diag["converged"] = False
            self.diag["fast_path"] += (f"; Monte Carlo error of the 95 % interval ends up to "
                                       f"{mcse[worst]:.3f} of the width ({worst}"
                                       + (f"; accept ≤ {gate:g}" if gate is not None else "") + ")"
                                       + (f", after {x['n_topup']} more draws" if x.get("n_topup") else ""))
            p_within = x.get("end_within_probability")
            if p_within is not None:
                # all ends at once (fast._joint_target): the chance that none is off by more than
                # end_tolerance of its width, if the predicted errors are right
                conf = x.get("end_confidence")
                self.diag["interval_end_within_probability"] = float(p_within)
                self.diag["fast_path"] += (f"; predicted probability that every end is within "
                                           f"{x['end_tolerance']:g} of its width {p_within:.2f}"
                                           + (f" (accept ≥ {conf:g})" if conf is not None and gate is not None
                                              else ""))
        if x.get("settings") is not None:
            # the knobs behind this result (FastSettings; the CLI's --fast-tolerance/--fast-confidence)
            self.diag["fast_settings"] = dict(x["settings"])
        tails = x.get("tails")
        if tails is not None:
            # long one-sided tails the probe found, each given defensive draws (fast._tail_probe)
            self.diag["fast_path_tails"] = [dict(t) for t in tails]
            if tails:
                self.diag["fast_path"] += ("; defensive draws for long tails: " + ", ".join(
                    f"{t['parameter']} {t['side']} ({t['reach_sd']:g} sd)" for t in tails))
        if not self.diag["converged"]:
            self.notes.insert(0, "NOT CONVERGED: the Laplace–IS fast path failed its own check ("
                              + "; ".join(self.diag["failed_checks"]) + "); do not use these intervals")
            warnings.warn(self.notes[0], ConvergenceWarning, stacklevel=4)

    def _derived_end_mcse_importance(self):
        """{derived quantity: Monte Carlo error of its 95 % interval ends / width} for a fast-path
        result: :func:`bayescap.fast.interval_end_mcse` of the quantity computed on the weighted
        draws behind the resampled ones (``chains.extra["weighted_draws"]``), counting the
        resampling, as the fast path does for the parameters; quantities that vary only (NaN where
        a quantity's draws are not all finite). {} when the chains carry no weighted draws."""
        wd = self.chains.extra.get("weighted_draws")
        if not wd:
            return {}
        if self._same_derived_inputs(getattr(wd.get("derived_fn"), "inputs", None)):
            # the fast path's top-up computed them already, on the same weighted draws and resampled
            # count, with a function of the same inputs (bayescap.fit and the batch pass it one):
            # its errors of the quantities that are not parameters (~5 % of a batch sensor's time)
            return {n: float(e) for n, e in (self.chains.extra.get("end_mcse") or {}).items()
                    if n not in self.draws}
        from bayescap.inference.end_errors import _varies, interval_end_mcse

        fn = FitResult.derived_values_fn(self.model, metadata=self.metadata, scene=self.scene, mtf=self.mtf,
                                         seed=self.seed)
        return {n: float(interval_end_mcse(v, wd["w"], n_resampled=wd["n_resampled"]))
                for n, v in fn(wd["x"]).items() if _varies(v)}

    def _set_end_mcse(self, end, target):
        """The diagnostics of the interval ends' Monte Carlo error ``end`` ({quantity: error /
        width}): ``interval_end_mcse``, its ``_max`` and ``_worst`` (NaN, draws not all finite,
        counts as the worst) and ``_target``. Returns the failed check's text when the worst
        exceeds ``target``, else None."""
        end = {n: float(v) for n, v in end.items()}
        if not end:
            return None
        worst = worst_end(end)
        self.diag.update({"interval_end_mcse": end, "interval_end_mcse_max": end[worst],
                          "interval_end_mcse_worst": worst, "interval_end_mcse_target": target})
        if target is not None and not end[worst] <= target:
            return f"{_END_MCSE_FAILURE} {end[worst]:.3f} of the width ({worst}) > {target:g}"
        return None

    def _flag_imprecise_ends(self):
        """Where no check bounds the interval ends' Monte Carlo error (MCMC presets without
        ``end_mcse_target``), flag the quantities whose ends' error is above
        :data:`IMPRECISE_END_MCSE` of the width: a converged chain (R-hat, ESS) can still put an end
        far from where a longer one would (a clip level's shelf; the fallback's ESS of 200)."""
        self.flags.pop("imprecise_interval_ends", None)
        self.notes = [n for n in self.notes if not n.startswith(_IMPRECISE_NOTE)]
        end = self.diag.get("interval_end_mcse") or {}
        if self.diag.get("method") != "emcee" or self.diag.get("interval_end_mcse_target") is not None:
            return
        bad = {n: round(float(v), 3) for n, v in end.items() if not v <= IMPRECISE_END_MCSE}
        if not bad:
            return
        self.flags["imprecise_interval_ends"] = bad
        worst = max(bad.values(), key=lambda v: v if np.isfinite(v) else np.inf)
        up_to = f"up to {worst:.2f}" if np.isfinite(worst) else "undefined where the draws are not all finite"
        self.notes.append(f"{_IMPRECISE_NOTE} the Monte Carlo error of the 95 % interval ends of "
                          + ", ".join(sorted(bad)) + f" is above {IMPRECISE_END_MCSE:g} of the width ({up_to}): "
                          "another seed can move those ends by that much. `--quality accurate` "
                          "runs until every end's error is ≤ 0.01 of the width (and says when it cannot)")

    def _diagnose_mcmc(self):
        c = self.chains
        E, S, W, D = c.chain.shape
        per = {}
        cached = c.extra.get("param_diagnostics") or {}
        for j, n in enumerate(self.model.names):
            per[n] = cached[j] if j in cached else fast_diagnostics(c.chain[..., j])
        for n in ("capacity_bits", "capacity_bits_per_pixel", "tonal_range_bits"):
            if n in self.derived:
                per[n] = cached[n] if n in cached else fast_diagnostics(self.derived[n].reshape(E, S, W))
        rhat_max = max(v["rhat"] for v in per.values())
        ess_min = min(min(v["ess_bulk"], v["ess_tail"]) for v in per.values())
        st = c.settings
        tau_max = float(np.max(c.tau))
        failed = []
        if not rhat_max < st.rhat_target:
            worst = max(per, key=lambda n: per[n]["rhat"])
            failed.append(f"R-hat max {rhat_max:.4f} ({worst}) ≥ {st.rhat_target}")
        if not ess_min >= st.ess_target:
            worst = min(per, key=lambda n: min(per[n]["ess_bulk"], per[n]["ess_tail"]))
            failed.append(f"ESS min {ess_min:.0f} ({worst}) < {st.ess_target:.0f}")
        if not np.all(np.isfinite(c.tau)):
            bad = [self.model.names[j] for j in np.flatnonzero(~np.isfinite(c.tau))]
            failed.append(f"autocorrelation time undefined ({', '.join(bad)}): a walker did not move in "
                          f"the {S} production steps")
        elif not S >= st.tau_factor * tau_max:
            failed.append(f"chain of {S} steps shorter than {st.tau_factor:g} autocorrelation times "
                          f"({tau_max:.1f} steps)")
        if not np.all(c.acceptance > 0.05):
            failed.append(f"acceptance fraction {c.acceptance.min():.3f} < 0.05 in an ensemble")
        # Monte Carlo error of every reported 95 % interval end (fit.interval_end_mcse_mcmc), as
        # run_ensembles computed it on the final chain, or here
        end = c.extra.get("end_mcse")
        if end is None:
            end = {n: interval_end_mcse_mcmc(x) for n, x in self._reported_draws((E, S, W)).items()}
        # walkers stranded far below the mode (fit.stuck_walkers): their draws are not posterior draws
        lp_w = np.transpose(c.log_prob, (1, 0, 2)).reshape(S, E * W)
        n_stuck = int(np.sum(stuck_walkers(lp_w, D)))
        if n_stuck:
            failed.append(f"{n_stuck} of {E * W} walkers stuck more than {stuck_threshold(D):.0f} nats below "
                          "the mode")
        converged = not failed
        self.diag = {
            "method": "emcee",
            "method_description": _mcmc_description(st),
            "quality": self.quality,
            "converged": converged,
            "failed_checks": failed,
            "rhat_max": rhat_max,
            "ess_min": ess_min,
            "rhat_target": st.rhat_target,
            "ess_target": st.ess_target,
            "tau_factor": st.tau_factor,
            "n_ensembles": E,
            "n_walkers": W,
            "n_steps": S,
            "n_burn": st.n_burn,
            # production steps turned into burn-in because the halves of the production disagreed
            # (time-split R-hat, fit.run_ensembles), and each such event
            "burn_in_extended_steps": int(c.extra.get("burn_in_extended", 0) or 0),
            "drift_events": list(c.extra.get("drift") or []),
            "n_rounds": c.n_rounds,
            "tau_max_steps": tau_max,
            "acceptance": [float(a) for a in c.acceptance],
            "walkers_stuck": n_stuck,
            "walkers_reset_in_burn_in": c.extra.get("walkers_reset"),
            "wall_s": c.wall_s,
            "seed": self.seed,
            "per_quantity": per,
        }
        failure = self._set_end_mcse(end, getattr(st, "end_mcse_target", None))
        if failure:
            failed.append(failure)
            self.diag["converged"] = converged = False
        self._flag_imprecise_ends()
        if self.diag["burn_in_extended_steps"]:
            ev = "; ".join(f"{e['quantity']} R-hat {e['rhat']:.3f} after round {e['round']}"
                           for e in self.diag["drift_events"])
            self.notes.append(f"burn-in extended by {self.diag['burn_in_extended_steps']} steps: the first and "
                              f"second halves of the production disagreed ({ev}), so the earlier steps were "
                              "discarded as burn-in and the intervals come from the steps after them")
        if not converged:
            self.notes.insert(0, "NOT CONVERGED: " + "; ".join(failed) + ". Do not use these intervals; "
                              f"rerun with {rerun_advice(self.quality)}")
            warnings.warn(self.notes[0], ConvergenceWarning, stacklevel=4)

    # ----------------------------------------------------------------- data checks
    def _check_rows(self, n_draws=400):
        """Outlier probabilities per row, and systematic residuals the model has no term for."""
        m = self.model
        E, S, W, D = self.chains.chain.shape
        th = self.chains.chain.reshape(-1, D)[self.thin_index(n_draws)]
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            pred = m.predict(th)     # shared by the outlier probabilities and the turnover check
        self.outliers = []
        for block, (rows, prob) in m.outlier_probabilities(th, pred).items():
            for r, pr in zip(rows, prob):
                if pr > 0.5:
                    self.outliers.append({"row": int(r), "block": block, "probability": float(pr)})
        if self.outliers:
            desc = ", ".join(f"row {o['row']} ({o['block']}, P = {o['probability']:.2f})" for o in self.outliers)
            self.notes.append(f"outlier rows (down-weighted by the mixture, not removed): {desc}")
        self._check_dark_floor()
        # variance turning over below the clip: the top unclipped rows sit well below the model
        obs, model, k, _ = pred["bright_var"]
        med = np.median(model, axis=0)
        kk = np.median(np.broadcast_to(k, model.shape), axis=0)
        z = (obs - med) / (med / np.sqrt(kk))
        order = np.argsort(m.s_obs)
        top = order[-4:]
        out_rows = {o["row"] for o in self.outliers}
        rows = m.observation_rows("bright_var")
        low = [i for i in top if z[i] < -4 and int(rows[i]) not in out_rows]
        if len(low) >= 2 and m.terms.clip in ("none", "adc"):
            self.flags["variance_turnover_unexplained"] = [int(rows[i]) for i in low]
            self.notes.append("the variance turns over below the clip level on rows "
                              + ", ".join(str(int(rows[i])) for i in low)
                              + ": the model has no term for that (non-linearity or a soft clip before "
                                "full well?); treat full well and the top of the range with caution")

    #: dark rows whose mean sits fewer than this many sd (temporal and, where measured, spatial)
    #: above 0 DN: the ADC's zero clips the low tail, shrinking the dark variances (≈ 0.2 % at 2.5 sd,
    #: 1.3 % at 2 sd, against a ≈ 1 % sampling error), a censoring the model does not have
    DARK_FLOOR_SD = 2.5

    def _check_dark_floor(self):
        """Flag dark rows whose pixel distribution reaches the ADC's zero (black level too low for
        the read noise and DSNU): read noise and DSNU are then biased low, silently otherwise."""
        d = self.model.data
        var = np.asarray(d.dark_temporal_var_dn2, float).copy()
        if d.dark_spatial_var_dn2 is not None:
            sp = np.asarray(d.dark_spatial_var_dn2, float)
            var = np.where(np.isfinite(sp), np.maximum(var, sp), var)
        with np.errstate(divide="ignore", invalid="ignore"):
            margin = np.asarray(d.dark_mean_dn, float) / np.sqrt(np.maximum(var, 1e-12))
        low = np.nonzero(margin < self.DARK_FLOOR_SD)[0]
        if low.size:
            rows = [int(d.row_label(i)) for i in low]
            self.flags["dark_floor_clipping"] = rows
            self.notes.append(
                f"dark mean only {float(np.min(margin[low])):.1f} sd above 0 DN on rows "
                + ", ".join(str(r) for r in rows[:8]) + (" …" if len(rows) > 8 else "")
                + ": the ADC's zero clips the darkest pixels, so read noise and DSNU are biased low "
                  "(raise the black level / offset, as EMVA 1288 requires)")

    def at_scene(self, scene: "Scene") -> "FitResult":
        """The same posterior evaluated at another scene (exposure time, temperature): derived
        quantities, notes and noise budget are recomputed, the draws are shared."""
        new = FitResult(model=self.model, chains=self.chains, metadata=self.metadata, scene=scene,
                        mtf=self.mtf, seed=self.seed, quality=self.quality, draws=self.draws)
        new.notes = [n for n in self.notes if not n.startswith(_DERIVED_NOTE_PREFIXES)]
        new.flags = {k: v for k, v in self.flags.items() if k not in ("capacity_lower_bound", "mtf_band_cut", "mtf_above_one")}
        new.diag = dict(self.diag)
        new.outliers = list(getattr(self, "outliers", []))
        new._derive()
        if new.diag.get("method") in ("emcee", "laplace-is") and new.diag.get("interval_end_mcse"):
            # the derived quantities moved with the scene, and so did their interval ends' error
            end = {k: v for k, v in new.diag["interval_end_mcse"].items() if k not in new.derived}
            if new.diag["method"] == "emcee":
                end.update({n: interval_end_mcse_mcmc(x) for n, x in new._reported_draws(new.shape_esw).items()
                            if n in new.derived})
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

    def noise_budget(self, fraction_of_range=0.5):
        """Share of each Eq. 1 term in the noise variance at a signal level of the scene
        (default mid-grey, half the largest non-saturating signal): {term: median %}."""
        p = self.draws
        s_max, _ = self.signal_max_e(p)
        S = fraction_of_range * s_max
        t = self.scene.exposure_time_s
        k = p["conversion_gain_e_per_dn"]
        terms = {"photon_shot": S}
        if self.model.terms.dark_current:
            terms["read"] = p["read_noise_e"] ** 2
            terms["dark_current_shot"] = self.scene.dark_current_factor * p["dark_current_e_per_s"] * t
        else:
            terms["read_plus_dark"] = p["dark_noise_e"] ** 2
        if "dsnu_e" in p:
            terms["dsnu"] = p["dsnu_e"] ** 2
        if "prnu_percent" in p:
            terms["prnu"] = (p["prnu_percent"] / 100.0 * S) ** 2
        terms["quantization"] = k * k / 12.0
        total = sum(terms.values())
        return {"signal_e": float(np.median(S)), "fraction_of_range": fraction_of_range,
                "shares_percent": {n: float(np.median(100.0 * v / total)) for n, v in terms.items()}}

    # ----------------------------------------------------------------- API
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
        """The contract's ``parameters`` block, with identifiability flags."""
        p, m, out = self.draws, self.model, {}
        k = p["conversion_gain_e_per_dn"]
        out["conversion_gain_e_per_dn"] = summarize(k, "e-/DN")

        def nonneg(name, x, unit, why_floor=None):
            q = np.quantile(x, [0.025, 0.5, 0.95])
            detected = q[0] > 0.2 * q[1] and why_floor is None
            extra = {}
            if not detected:
                extra["upper_limit_95"] = float(q[2])
                extra["note"] = why_floor or ("the posterior reaches down to zero: an upper limit, "
                                              "not a detection")
            out[name] = summarize(x, unit, constrained=detected, **extra)

        if m.terms.dark_current:
            rn = p["read_noise_e"]
            floor = None
            if np.median(rn / k) < 0.4:
                floor = ("read noise below 0.4 DN is masked by quantization (EMVA 1288): an upper "
                         "limit only")
            nonneg("read_noise_e", rn, "e-", floor)
            nonneg("dark_current_e_per_s", p["dark_current_e_per_s"], "e-/s")
        else:
            dn = p["dark_noise_e"]
            t = float(np.unique(m.t[m.t > 0])[0]) if np.any(m.t > 0) else 0.0
            out["dark_noise_e"] = summarize(dn, "e-", note=f"sqrt(read² + D·t) at t = {t:g} s: the only "
                                            "identifiable combination with one exposure time")
            out["read_noise_e"] = summarize(dn, "e-", constrained=False, upper_limit_95=float(np.quantile(dn, 0.95)),
                                            note="not separable from dark current with one exposure time: "
                                                 "the interval is that of sqrt(read² + D·t), an upper limit")
            if t > 0:
                dc = dn**2 / t
                out["dark_current_e_per_s"] = summarize(dc, "e-/s", constrained=False,
                                                        upper_limit_95=float(np.quantile(dc, 0.95)),
                                                        note="upper limit (all dark noise attributed to D·t)")
        if "full_well_e" in p:
            extra = {}
            if m.terms.clip == "adc":
                extra = {"clip_source": "adc",
                         "note": "the output clips at the ADC maximum: this is the charge at the clip; "
                                 "the photodiode's own well may be deeper"}
            else:
                extra = {"clip_source": "full_well_or_adc"}
            out["full_well_e"] = summarize(p["full_well_e"], "e-", **extra)
        else:
            lb = float(np.quantile((m.max_mean_ok - m.black_dn) * k, 0.025))
            out["full_well_e"] = {"median": None, "ci68": [lb, None], "ci95": [lb, None], "unit": "e-",
                                  "constrained": False, "lower_bound": lb,
                                  "note": "no row reaches saturation: only a lower bound (the largest "
                                          "measured signal)"}
        if "quantum_efficiency" in p:
            out["quantum_efficiency"] = summarize(p["quantum_efficiency"], "")
        if "prnu_percent" in p:
            nonneg("prnu_percent", p["prnu_percent"], "%")
        if "dsnu_e" in p:
            nonneg("dsnu_e", p["dsnu_e"], "e-")
        if m.terms.discrepancy:
            out["variance_discrepancy"] = summarize(p["variance_discrepancy"], "",
                                                    note="fractional scatter of the variances beyond statistics")
        if "clip_spread_dn" in p:
            out["clip_spread_dn"] = summarize(p["clip_spread_dn"], "DN", note="spread of pixel means at the clip")
        if "mean_discrepancy" in p:
            out["mean_discrepancy"] = summarize(p["mean_discrepancy"], "", note="fractional non-linearity scatter")
        return out

    def derived_summary(self) -> dict:
        out = {}
        lower = self.flags.get("capacity_lower_bound", False)
        for name, x in self.derived.items():
            unit = DERIVED_INFO.get(name, ("bits/pixel", ""))[0]
            extra = {}
            if lower and name not in ("mtf_loss_bits",):
                extra["lower_bound"] = True
            out[name] = summarize(x, unit, **extra)
            out[name].pop("constrained")
        return out

    def to_dict(self) -> dict:
        sensor = dict(self.metadata)
        diag = {k: v for k, v in self.diag.items()}
        return _clean({
            "bayescap_version": __version__,
            "input": self.model.data.source,
            "sensor": sensor,
            "scene": self.scene.to_dict(),
            "parameters": self.parameter_summary(),
            "derived": self.derived_summary(),
            "model_terms": self.model.terms.names(),
            "terms_left_out": dict(self.model.terms.reasons),
            "term_notes": dict(self.model.terms.how),
            "mtf": self.mtf_info,
            "noise_budget_mid_grey": self.noise_budget(),
            "outliers": list(getattr(self, "outliers", [])),
            **({"model_selection": self.model_selection} if getattr(self, "model_selection", None) else {}),
            "notes": list(self.notes),
            "flags": dict(self.flags),
            "diagnostics": diag,
        })


def _clean(obj):
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _json_float(obj)
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    return obj
