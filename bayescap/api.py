"""The Python API: load a photon-transfer CSV, fit it, read capacity with credible intervals.

>>> import bayescap
>>> data = bayescap.load("data/emva1288_basler_ccd12.csv")        # doctest: +SKIP
>>> result = bayescap.fit(data, seed=1)                           # doctest: +SKIP
>>> result.to_dict()["derived"]["capacity_bits"]                  # doctest: +SKIP
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from bayescap.exceptions import InputError, PTCInputError
from bayescap.inference import FastSettings
from bayescap.inference.mcmc import run_ensembles
from bayescap.inference.presets import QUALITY_PRESETS, SamplerSettings
from bayescap.io.ptc_csv import PTCData, read_ptc_csv
from bayescap.model import PTCModel, saturation_flags
from bayescap.physics.optics import default_mtf
from bayescap.posterior import FitResult, Scene

__all__ = ["load", "fit", "default_scene", "mtf_from_metadata", "measured_mtf", "draw_seed"]

#: metadata defaults applied when a key is absent (the report lists which were used)
METADATA_DEFAULTS = {"f_number": 2.8, "wavelength_nm": 555.0, "fill_factor": 1.0}


def load(path: str | os.PathLike, **overrides) -> PTCData:
    """Read and validate a photon-transfer CSV; keyword overrides replace metadata values."""
    return read_ptc_csv(path, overrides=overrides or None)


def default_scene(data: PTCData) -> Scene:
    """The scene used when none is given: the median exposure time of the measured rows that
    are not clipped (dark-current charge and shot noise are evaluated there)."""
    full, _ = saturation_flags(data)
    t = data.exposure_time_s[~full] if np.any(~full) else data.exposure_time_s
    if not np.all(np.isfinite(t)):  # a mean/variance table without exposure times
        return Scene(exposure_time_s=0.0, source="no exposure times in the table; no dark current is modelled")
    return Scene(exposure_time_s=float(np.median(t)), source="median exposure time of the unclipped rows")


def mtf_from_metadata(metadata: dict, notes: list | None = None):
    """The default MTF from sensor metadata: pixel aperture (``fill_factor``) x diffraction-limited
    lens (``f_number``, ``wavelength_nm``; needs ``pixel_pitch_um``) x, when the metadata give
    ``crosstalk_sigma_px``, a Gaussian crosstalk kernel (Eq. 3's ``G_σ``, σ in pixels).

    ``bayescap fit``, ``compare`` and ``report`` all build the MTF here, so one CSV gives one
    capacity whichever command reads it."""
    from bayescap.physics.optics import GaussianCrosstalk, MTFProduct

    md = {**METADATA_DEFAULTS, **metadata}
    pitch = metadata.get("pixel_pitch_um")
    if pitch is None and notes is not None:
        notes.append(
            "pixel_pitch_um unknown: the lens (diffraction) MTF is left out of Δs; "
            "give '# pixel_pitch_um:' or --pixel-pitch-um"
        )
    mtf = default_mtf(
        fill_factor=md["fill_factor"], f_number=md["f_number"], wavelength_nm=md["wavelength_nm"], pixel_pitch_um=pitch
    )
    sigma = metadata.get("crosstalk_sigma_px")
    if sigma is not None:  # typed and checked (finite, >= 0) by the CSV reader
        mtf = MTFProduct(components=tuple(mtf.components) + (GaussianCrosstalk(sigma_px=float(sigma)),))
    return mtf


def measured_mtf(path, *, seed: int = 0, n_boot: int = 200):
    """A measured system MTF as an MTF component with draws (for Δs with uncertainty).

    ``path`` is an MTF table (CSV: ``freq_cy_per_px,mtf``; no draws, so Δs carries no
    sharpness uncertainty) or a slanted-edge image, measured by ISO 12233:2023
    (:func:`bayescap.measure.sfr.measure_sfr`, with the ¼-pixel bin-width correction so that the
    bootstrap intervals are centred on the true MTF) with ``n_boot`` bootstrap draws."""
    from pathlib import Path

    from bayescap.measure import measure_sfr, read_image, read_mtf_table
    from bayescap.physics.optics import TabulatedMTF

    p = Path(path)
    if p.suffix.lower() == ".csv":
        r = read_mtf_table(p)
    else:
        r = measure_sfr(read_image(p), n_boot=n_boot, seed=seed, correct_bin_width=True)
    samples = r.mtf_samples if r.mtf_samples.shape[0] > 0 else None
    return TabulatedMTF(freq_cy_per_px=r.freq_cy_per_px, mtf=r.mtf, samples=samples, name=f"measured:{p.name}")


def _result_kw(data: PTCData, *, mtf, scene: Scene | None, seed):
    """What :class:`~bayescap.posterior.FitResult` computes the derived quantities with: the
    metadata with its defaults, the scene (:func:`default_scene` if None), the MTF and the seed."""
    return dict(metadata={**METADATA_DEFAULTS, **data.metadata}, scene=scene or default_scene(data), mtf=mtf, seed=seed)


def _check_mtf_passes(mtf, data: PTCData, given: bool):
    """Refuse, before any fitting, an MTF that is zero at every frequency of the band (a crosstalk σ
    of 10⁶ px, an all-zero MTF table): Δs would be −∞ and no capacity can be computed. A
    :class:`PTCInputError` naming where the MTF came from."""
    from bayescap.physics.capacity import mtf_loss_bits

    try:
        mtf_loss_bits(mtf)
    except ValueError as e:
        if given:
            name = getattr(mtf, "name", None)
            src = f"the MTF given ({name})" if name else "the MTF given"
        else:
            keys = ("crosstalk_sigma_px", "pixel_pitch_um", "f_number", "wavelength_nm", "fill_factor")
            src = (
                "the metadata's MTF ("
                + ", ".join(f"{k} {data.metadata[k]:g}" for k in keys if k in data.metadata)
                + ")"
            )
        raise PTCInputError(f"{e} with {src}: no capacity can be computed", path=data.source) from None


def _check_seed(seed) -> None:
    if seed is None:
        return
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a whole number >= 0 or None, got {seed!r}")


def _check_quality(quality, name="quality") -> None:
    if isinstance(quality, SamplerSettings):
        return
    if not isinstance(quality, str) or quality not in QUALITY_PRESETS:
        raise InputError(f"{name} must be one of {', '.join(QUALITY_PRESETS)} or a SamplerSettings, got {quality!r}")


def draw_seed() -> int:
    """A fresh seed for a run given none (32 bits from the operating system): the result records it,
    so the run can be repeated."""
    import secrets

    return secrets.randbits(32)


def _check_prior(prior) -> None:
    """Refuse a prior override that would give a foreign error later, or none at all: unknown keys,
    bounds that are not an increasing pair of finite numbers (natural bounds > 0; QE in (0, 1]),
    scales that are not finite and positive."""
    if prior is None:
        return
    if not isinstance(prior, dict):
        raise InputError(f"prior must be a dict of overrides of PTCModel.PRIOR, got {type(prior).__name__}")
    unknown = sorted(set(prior) - set(PTCModel.PRIOR))
    if unknown:
        raise InputError(f"unknown prior key(s) {', '.join(unknown)}; known: {', '.join(sorted(PTCModel.PRIOR))}")
    for key, v in prior.items():
        if key.endswith("_bounds"):
            if v is None and key != "log_k_bounds":
                continue
            try:
                lo, hi = (float(x) for x in v)
            except (TypeError, ValueError):
                raise InputError(f"prior '{key}' must be a pair (lo, hi) of numbers, got {v!r}") from None
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise InputError(f"prior '{key}' must be finite with lo < hi, got ({lo:g}, {hi:g})")
            if key == "qe_bounds" and not (0 < lo and hi <= 1):
                raise InputError(f"prior 'qe_bounds' must lie in (0, 1], got ({lo:g}, {hi:g})")
            if key != "log_k_bounds" and key != "qe_bounds" and lo <= 0:
                raise InputError(f"prior '{key}' gives natural values, which must be > 0, got ({lo:g}, {hi:g})")
        else:
            try:
                x = float(v)
            except (TypeError, ValueError):
                raise InputError(f"prior '{key}' must be a number, got {v!r}") from None
            if not (np.isfinite(x) and x > 0):
                raise InputError(f"prior '{key}' must be finite and > 0, got {v!r}")


def fit(
    data: PTCData | PTCModel | str,
    *,
    seed: int | None = None,
    quality: str | SamplerSettings = "standard",
    mtf=None,
    scene: Scene | None = None,
    progress: bool = False,
    terms=None,
    n_jobs: int | None = None,
    fast_settings=None,
    fallback: bool = True,
    fallback_quality: str = "fast",
    prior: dict | None = None,
    fast_result=None,
) -> FitResult:
    """Fit the Eq. 1 noise model to photon-transfer data and propagate to capacity.

    Parameters
    ----------
    data : PTCData, path to a contract CSV, or a :class:`~bayescap.model.PTCModel`.
    seed : makes the run reproducible (same seed, same numbers): a whole number >= 0. None draws
        one (:func:`draw_seed`), which the result records (``diagnostics.seed``,
        ``diagnostics.seed_drawn``).
    quality : "fast", "standard", "accurate" or a :class:`SamplerSettings` (MCMC).
        ``"fast"`` is the Laplace–IS path (:mod:`bayescap.inference.fast`): MAP, refined Laplace
        covariance, Pareto-smoothed importance sampling; when its own check fails (Pareto k̂ ≥
        ``khat_max`` or IS ESS < ``min_ess_is``) the fit falls back to the MCMC preset
        ``fallback_quality`` (default the short MCMC ``"fast"`` preset of
        :data:`bayescap.inference.QUALITY_PRESETS`), and the result says so (a note,
        ``diagnostics.fast_path``, ``diagnostics.fallback_reason``).
    mtf : an MTF component (see :mod:`bayescap.physics.optics`); default from the metadata.
    scene : where TR/capacity are evaluated; default :func:`default_scene`.
    terms : a :class:`bayescap.model.ModelTerms` to override the data-driven term selection.
    n_jobs : processes for the independent ensembles (default: one per core; the numbers do not
        depend on it).
    fast_settings : :class:`bayescap.inference.FastSettings` for ``quality="fast"``.
    fallback : with ``quality="fast"``, False returns a rejected Laplace–IS result (flagged NOT
        CONVERGED) instead of running MCMC.
    prior : overrides of :attr:`bayescap.model.PTCModel.PRIOR` (e.g. ``{"read_log_bounds": (1, 20)}``
        for a log-uniform read-noise prior on 1–20 e⁻); default: the documented production priors.
        Ignored when ``data`` is already a PTCModel (it carries its own prior).
    fast_result : with ``quality="fast"``, the ``(ChainResult, diagnostics)`` pair that
        :func:`bayescap.inference.fast.fast_posterior` returned for this model and ``seed`` (computed for many
        sensors at once by :func:`bayescap.batch.fit_many`); the fit then starts from it instead
        of running the fast path again (the fallback, when it is rejected, is unchanged).
    """
    _check_seed(seed)
    _check_quality(quality)
    if not isinstance(fallback_quality, str) or fallback_quality not in QUALITY_PRESETS:
        raise InputError(f"fallback_quality must be one of {', '.join(QUALITY_PRESETS)}, got {fallback_quality!r}")
    _check_prior(prior)
    if fast_settings is not None and not isinstance(fast_settings, FastSettings):
        raise InputError(f"fast_settings must be a FastSettings, got {type(fast_settings).__name__}")
    seed_drawn = seed is None
    if seed_drawn:
        seed = draw_seed()
    if isinstance(data, PTCModel):
        model, data = data, data.data
    else:
        if not isinstance(data, PTCData):
            data = load(data)
        # (terms given: the caller has chosen the model for every row)
        model = PTCModel.for_fit(data, prior=prior) if terms is None else PTCModel(data, terms=terms, prior=prior)
        data = model.data
    notes: list = []
    defaults_used = sorted(k for k in METADATA_DEFAULTS if k not in data.metadata)
    mtf_given = mtf is not None
    if mtf is None:
        mtf = mtf_from_metadata(data.metadata, notes)
    _check_mtf_passes(mtf, data, mtf_given)
    kw = _result_kw(data, mtf=mtf, scene=scene, seed=seed)
    if quality == "fast":
        from bayescap.inference.fast import fast_posterior

        fs = fast_settings or FastSettings()
        # with a gate on the interval ends' Monte Carlo error, the top-up covers the derived
        # quantities too (else one above the gate would send the fit to MCMC below)
        derived_fn = None if fs.end_mcse_max is None else FitResult.derived_values_fn(model, **kw)
        chains, fd = (
            fast_result
            if fast_result is not None
            else fast_posterior(model, seed=seed, settings=fs, derived_fn=derived_fn)
        )
        res = None
        if fd["accepted"] and fallback:
            # the result can still fail: with a gate on the interval ends' Monte Carlo error
            # (FastSettings.end_mcse_max), a derived quantity's error (capacity, TR) is checked here
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                res = FitResult.from_chains(model, chains, quality="fast", **kw)
            if res.diag["converged"]:
                for w in caught:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            else:
                fd = {**fd, "reason": "; ".join(res.diag["failed_checks"])}
                res = None
        elif not fallback:
            res = FitResult.from_chains(model, chains, quality="fast", **kw)
        if res is None:
            settings = QUALITY_PRESETS[fallback_quality]
            check_derived, check_reported = FitResult.chain_check_fns(model, **kw)
            mc = run_ensembles(
                model,
                settings=settings,
                seed=seed,
                progress=progress,
                n_jobs=n_jobs,
                derived_fn=check_derived,
                reported_fn=check_reported,
            )
            mc.wall_s += fd["wall_s"]  # the rejected attempt is part of the cost
            res = FitResult.from_chains(model, mc, quality="fast", checked=check_derived, **kw)
            res.diag.update(
                {
                    "fast_path": (
                        f"fast path (Laplace–IS) rejected ({fd['reason']}): fell back to MCMC, "
                        f"preset '{fallback_quality}' ({settings.n_ensembles} ensembles, "
                        f"ESS target {settings.ess_target:g})"
                    ),
                    "fast_path_accepted": False,
                    "fallback_reason": fd["reason"],
                    "fallback_quality": fallback_quality,
                    "fast_path_khat": fd["khat"],
                    "fast_path_ess_is": fd["ess_is"],
                    "fast_path_wall_s": fd["wall_s"],
                    **({"fast_path_retry_skipped": fd["retry_skipped"]} if fd.get("retry_skipped") else {}),
                    "fast_settings": dict(fd["settings"]) if fd.get("settings") is not None else None,
                }
            )
            res.notes.append(
                f"the Laplace–IS fast path was rejected ({fd['reason']}): the result comes "
                f"from the MCMC '{fallback_quality}' preset"
            )
    else:
        settings = QUALITY_PRESETS[quality] if isinstance(quality, str) else quality
        qname = quality if isinstance(quality, str) else "custom"
        check_derived, check_reported = FitResult.chain_check_fns(model, **kw)
        chains = run_ensembles(
            model,
            settings=settings,
            seed=seed,
            progress=progress,
            n_jobs=n_jobs,
            derived_fn=check_derived,
            reported_fn=check_reported,
        )
        res = FitResult.from_chains(model, chains, quality=qname, checked=check_derived, **kw)
    res.notes.extend(notes)
    if seed_drawn:
        res.diag["seed_drawn"] = True
    if defaults_used:
        res.flags["metadata_defaults"] = defaults_used
    return res


def fast_fit(
    data_or_model,
    *,
    seed,
    settings: FastSettings = FastSettings(),
    mtf=None,
    scene=None,
    fallback: bool = True,
    fallback_quality: str = "fast",
    terms=None,
):
    """``bayescap.fit(..., quality="fast")`` with explicit fast-path knobs (a thin wrapper).

    ``data_or_model``: a PTCData, a contract CSV path or a :class:`~bayescap.model.PTCModel`.
    ``fallback=False`` returns a rejected fast result (flagged NOT CONVERGED) instead of running
    the MCMC ``fallback_quality`` preset. See :func:`bayescap.api.fit`.
    """
    return fit(
        data_or_model,
        seed=seed,
        quality="fast",
        fast_settings=settings,
        mtf=mtf,
        scene=scene,
        fallback=fallback,
        fallback_quality=fallback_quality,
        terms=terms,
    )
