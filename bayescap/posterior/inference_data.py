"""A fit result as ArviZ InferenceData (the ``posterior.nc`` of ``bayescap fit --out``).

Groups:

- ``posterior``: the physical parameters and the derived quantities, each with a ``units``
  attribute. **Chains are the independent ensembles**; each ensemble's walkers are flattened into
  its draws: first the draws of the first half of the production steps (walker by walker, each in
  step order), then those of the second half (:func:`bayescap.inference.diagnostics.draw_order`).
  ArviZ's split R-hat splits a chain into those two halves (a split in time), and the report's
  diagnostics use the same chains (:func:`bayescap.inference.diagnostics.by_ensemble`), so
  ``az.rhat`` and ``az.ess`` (bulk and tail) on the file are the report's to rounding. A fast-path
  (Laplace–IS) result has one chain of resampled importance draws (attribute ``chains``), for
  which R-hat does not apply.
- ``unconstrained_posterior``: the sampler's coordinates (``log_k``, ...), the ones the report's
  ``diagnostics.per_quantity`` are computed on; same layout.
- ``sample_stats``: ``lp``, the log posterior density of each draw.
- ``log_likelihood``: the log-likelihood of every observation, one variable per kind of
  observation (:data:`OBSERVATION_VARS`: means in DN, variances in DN², dimension ``<name>_row``
  = the CSV's file rows) and :data:`ALL_OBSERVATIONS`, all of them concatenated (coordinates
  ``block`` and ``row``; ``az.loo(idata, var_name="all_observations")``), for at most
  :data:`PREDICTIVE_MAX_DRAWS` draws, evenly thinned in each chain (``draw`` coordinates are the
  posterior's).
- ``posterior_predictive``: the same variables replicated from the model's density (gamma for
  variances, normal for means, the outlier mixture where the model has it) for the same draws, so
  ``az.plot_ppc(idata, var_names=[...])`` compares one kind of observation at a time.
- ``observed_data``: the same variables, observed.
- ``constant_data``: the input CSV's columns (dimension ``level``), and the posterior's
  variables that are the same in every draw (no R-hat or ESS: a clip no row reaches, Δs with a
  fixed MTF), as scalars; the attribute ``constant_variables`` names them.

Attributes: bayescap version, input, sensor, seed, quality, method, the layout of the chains,
units. Every variable has a ``units`` attribute (:data:`DIMENSIONLESS` where it has none).
"""

from __future__ import annotations

import json
import warnings

import numpy as np

from bayescap._version import __version__
from bayescap.inference.diagnostics import draw_order
from bayescap.model.likelihood import BOUND_BLOCKS, OUTLIER_RATE, OUTLIER_REL_SD, ROBUST_BLOCKS
from bayescap.posterior.summary import DERIVED_INFO

__all__ = [
    "PREDICTIVE_MAX_DRAWS",
    "UNITS",
    "DIMENSIONLESS",
    "OBSERVATION_VARS",
    "ALL_OBSERVATIONS",
    "to_inference_data",
    "draw_order",
    "INPUT_COLUMNS",
]

#: at most this many draws (all chains together) in the log_likelihood and posterior_predictive
#: groups (as many as bayescap.studies.selection.loo uses): half a fast-path result's 4000, a
#: twentieth of a ``standard`` one (38 400 draws × ~150 observations would be 46 MB a group)
PREDICTIVE_MAX_DRAWS = 2000

#: the ``units`` attribute of a dimensionless variable (every variable of the file has one)
DIMENSIONLESS = "dimensionless"

#: units of the physical parameters and derived quantities
UNITS = {
    "conversion_gain_e_per_dn": "e-/DN",
    "read_noise_e": "e-",
    "dark_noise_e": "e-",
    "dark_current_e_per_s": "e-/s",
    "clip_dn": "DN",
    "full_well_e": "e-",
    "clip_spread_dn": "DN",
    "quantum_efficiency": DIMENSIONLESS,
    "mean_discrepancy": DIMENSIONLESS,
    "prnu_percent": "%",
    "dsnu_e": "e-",
    "variance_discrepancy": DIMENSIONLESS,
    "response_nonlinearity": DIMENSIONLESS,
    "pixel_offset_spread_dn": "DN",
    **{k: v[0] for k, v in DERIVED_INFO.items()},
    "capacity_bits_per_pixel": "bits/pixel",
}
#: each likelihood block's variable in the observed_data, posterior_predictive and log_likelihood
#: groups: (name, units, what it holds); the dimension is ``<name>_row`` (the CSV's file rows)
OBSERVATION_VARS = {
    "mean": ("signal_mean_dn", "DN", "bright mean minus dark mean (rows below the clip)"),
    "bright_var": ("temporal_var_dn2", "DN²", "bright temporal variance (rows below the clip)"),
    "dark_var": ("dark_temporal_var_dn2", "DN²", "dark temporal variance"),
    "spatial_var": ("spatial_var_dn2", "DN²", "bright spatial variance of the n_frames average"),
    "dark_spatial_var": ("dark_spatial_var_dn2", "DN²", "dark spatial variance of the n_frames average"),
    "clip_mean": ("clipped_mean_dn", "DN", "bright mean of the rows at the clip"),
    "plateau_var": ("clipped_temporal_var_dn2", "DN²", "bright temporal variance of the rows at the clip"),
    "dark_mean": ("dark_mean_dn", "DN", "dark mean (the dark means' ramp, black level profiled)"),
}
#: the log_likelihood variable holding every observation at once (dimension ``observation``,
#: coordinates ``block`` and ``row``): the pointwise log-likelihood PSIS-LOO is computed on
ALL_OBSERVATIONS = "all_observations"
#: units of the input columns in the constant_data group (the others are counts: dimensionless)
_COLUMN_UNITS = {
    "exposure_time_s": "s",
    "mean_dn": "DN",
    "temporal_var_dn2": "DN²",
    "dark_mean_dn": "DN",
    "dark_temporal_var_dn2": "DN²",
    "photons_per_pixel": "photons",
    "exposure_lux_s": "lux·s",
    "spatial_var_dn2": "DN²",
    "dark_spatial_var_dn2": "DN²",
}
#: the PTCData columns the constant_data group holds
INPUT_COLUMNS = (
    "exposure_time_s",
    "mean_dn",
    "temporal_var_dn2",
    "dark_mean_dn",
    "dark_temporal_var_dn2",
    "n_pixels",
    "photons_per_pixel",
    "exposure_lux_s",
    "spatial_var_dn2",
    "dark_spatial_var_dn2",
    "n_frames",
    "frac_saturated",
    "row_numbers",
)


def _is_importance(result) -> bool:
    return result.diag.get("method") == "laplace-is"


def _chain_dataset(arrays, E, S, W, order, step, walker, attrs=None):
    """A Dataset of (chain, draw) variables from flat (E·S·W,) draws in (E, S, W) order."""
    import xarray as xr

    data = {}
    for name, v in arrays.items():
        v = np.broadcast_to(np.asarray(v, float), (E * S * W,)).reshape(E, S * W)[:, order]
        data[name] = (("chain", "draw"), v, {"units": UNITS.get(name, DIMENSIONLESS)})
    coords = {"chain": np.arange(E), "draw": np.arange(S * W), "step": ("draw", step), "walker": ("draw", walker)}
    return xr.Dataset(data, coords=coords, attrs=attrs or {})


def _predictive_index(E, n):
    """Per chain, the draws (indices into the chain) of the log_likelihood/posterior_predictive
    groups: all of them when E·n ≤ PREDICTIVE_MAX_DRAWS, else evenly spaced."""
    k = min(n, max(1, PREDICTIVE_MAX_DRAWS // E))
    return np.linspace(0, n - 1, k).round().astype(int)


def _replicate(model, th, rng):
    """(observed (n_obs,), replicated (n_draws, n_obs), labels): every observation replicated from
    the model's density at draws ``th``, blocks in the order of ``model.pointwise_loglik``."""
    with np.errstate(all="ignore"):
        pred = model.predict(th)
    obs_out, rep_out = [], []
    n = th.shape[0]
    for name, (obs, mod, spread, kind) in pred.items():
        if name in BOUND_BLOCKS:  # a bound, not a density: not an observation of these groups
            continue
        rows = model.observation_rows(name)
        shape = (n, rows.size)
        mod = np.broadcast_to(mod, shape)
        spread = np.broadcast_to(spread, shape)
        obs = np.broadcast_to(obs, shape)
        # the observations of a block are the data's; the signal of rows near the clip is the
        # model's latent one, which varies with the draw: its median
        obs_out.append(obs[0] if np.all(obs == obs[:1]) else np.median(obs, axis=0))
        if kind == "gamma":
            rep = rng.gamma(spread, mod / spread)
        else:
            rep = rng.normal(mod, spread)
        if model.terms.robust and name in ROBUST_BLOCKS:
            bad = rng.random(shape) < OUTLIER_RATE
            if kind == "gamma":
                wide = mod * np.exp(OUTLIER_REL_SD * rng.standard_normal(shape))
            else:
                wide = rng.normal(mod, np.sqrt(spread * spread + (OUTLIER_REL_SD * mod) ** 2))
            rep = np.where(bad, wide, rep)
        rep_out.append(rep)
    return np.concatenate(obs_out), np.concatenate(rep_out, axis=1)


def _observation_groups(E, keep, step, walker, n_chain, ll, rep, observed, labels):
    """The log_likelihood, posterior_predictive and observed_data Datasets: one variable per
    likelihood block (:data:`OBSERVATION_VARS`), so that each has one unit and ``az.plot_ppc``
    draws one kind of observation at a time; log_likelihood adds :data:`ALL_OBSERVATIONS`."""
    import xarray as xr

    blocks = np.array([b for b, _ in labels])
    rows = np.array([r for _, r in labels], int)
    n_keep = keep.size
    draws = {"chain": np.arange(E), "draw": keep, "step": ("draw", step[keep]), "walker": ("draw", walker[keep])}
    ll = ll.reshape(E, n_keep, -1)
    rep = rep.reshape(E, n_keep, -1)
    lvars, pvars, ovars, coords = {}, {}, {}, {}
    for block in dict.fromkeys(blocks):
        name, unit, what = OBSERVATION_VARS[block]
        sel = blocks == block
        dim = f"{name}_row"
        coords[dim] = rows[sel]
        attrs = {"units": unit, "long_name": what}
        lvars[name] = (
            ("chain", "draw", dim),
            ll[..., sel],
            {"units": DIMENSIONLESS, "long_name": f"log density: {what}"},
        )
        pvars[name] = (("chain", "draw", dim), rep[..., sel], attrs)
        ovars[name] = ((dim,), observed[sel], attrs)
    lvars[ALL_OBSERVATIONS] = (
        ("chain", "draw", "observation"),
        ll,
        {"units": DIMENSIONLESS, "long_name": "log density of every observation (the blocks above, concatenated)"},
    )
    all_coords = {"observation": np.arange(len(labels)), "block": ("observation", blocks), "row": ("observation", rows)}
    attrs = {"draws": f"{n_keep} of each chain's {n_chain} draws, evenly spaced (draw: the posterior's index)"}
    loglik = xr.Dataset(lvars, coords={**draws, **coords, **all_coords}, attrs=attrs)
    pp = xr.Dataset(pvars, coords={**draws, **coords}, attrs=attrs)
    od = xr.Dataset(ovars, coords=coords)
    return loglik, pp, od


def _split_constants(post):
    """Move the variables that are the same in every draw (a clip with no clipped row, Δs with a
    fixed MTF) out of ``post``: R-hat and ESS are undefined for them. Returns (post, constants)."""
    const = {}
    for name in list(post.data_vars):
        v = post[name].values
        if v.size and np.all(v == v.flat[0]):
            attrs = {**post[name].attrs, "constant": "the same value in every draw (no R-hat or ESS)"}
            const[name] = ((), v.flat[0], attrs)
    return post.drop_vars(list(const)), const


def _chains_description(result, E, S, W):
    if _is_importance(result):
        return (
            f"one chain of {S} importance draws resampled from the Laplace–IS fast path: independent "
            "draws, R-hat does not apply (the checks are Pareto k-hat and the IS ESS, in the attribute "
            "diagnostics)"
        )
    return (
        f"{E} chains = the independent ensembles; each chain holds its {W} walkers × {S} steps: the "
        "draws of the first half of the steps, walker by walker in step order, then those of the "
        "second half (coordinates step and walker), so that ArviZ's split R-hat and ESS are the report's"
    )


def to_inference_data(result):
    """ArviZ InferenceData of ``result`` (module docstring)."""
    import arviz as az
    import xarray as xr

    c = result.chains
    E, S, W, D = c.chain.shape
    order, step, walker = draw_order(S, W)
    common = {"bayescap_version": __version__, "quality": result.quality, "seed": str(result.seed)}
    post = _chain_dataset(
        {**result.draws, **result.derived},
        E,
        S,
        W,
        order,
        step,
        walker,
        attrs={"chains": _chains_description(result, E, S, W)},
    )
    for name in post.data_vars:
        post[name].attrs["kind"] = "derived" if name in result.derived else "parameter"
        if name in DERIVED_INFO:
            post[name].attrs["description"] = DERIVED_INFO[name][1]
    flat = c.chain.reshape(E * S * W, D)
    post, constants = _split_constants(post)
    unc = _chain_dataset({n: flat[:, j] for j, n in enumerate(result.model.names)}, E, S, W, order, step, walker)
    for name in unc.data_vars:
        unc[name].attrs["long_name"] = "sampler coordinate (a transform of the physical parameters)"
    stats = _chain_dataset({"lp": c.log_prob.reshape(-1)}, E, S, W, order, step, walker)

    # log-likelihood and replicated observations on evenly thinned draws of each chain
    keep = _predictive_index(E, S * W)
    th = c.chain.reshape(E, S * W, D)[:, order][:, keep].reshape(-1, D)
    ll, labels = result.model.pointwise_loglik(th)
    rng = np.random.default_rng(np.random.SeedSequence(result.seed).spawn(3)[2])
    observed, rep = _replicate(result.model, th, rng)
    loglik, pp, od = _observation_groups(E, keep, step, walker, S * W, ll, rep, observed, labels)
    d = result.model.data
    const = {}
    for col in INPUT_COLUMNS:
        v = getattr(d, col, None)
        if v is not None:
            const[col] = (("level",), np.asarray(v), {"units": _COLUMN_UNITS.get(col, DIMENSIONLESS)})
    cd = xr.Dataset({**const, **constants}, attrs={"source": str(d.source), "metadata": json.dumps(_plain(d.metadata))})
    attrs = {
        **common,
        "input": str(d.source),
        "sensor": str(result.metadata.get("sensor", "")),
        "method": str(result.diag.get("method", "")),
        "chains": post.attrs["chains"],
        "n_chains": E,
        "rhat_applicable": int(not _is_importance(result)),
        # every physical and derived variable in the result's order, constants included
        "units": json.dumps({n: UNITS.get(n, DIMENSIONLESS) for n in [*result.draws, *result.derived]}),
        "constant_variables": json.dumps(sorted(constants)),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return az.InferenceData(
            attrs=attrs,
            posterior=post,
            unconstrained_posterior=unc,
            sample_stats=stats,
            log_likelihood=loglik,
            posterior_predictive=pp,
            observed_data=od,
            constant_data=cd,
        )


def _plain(obj):
    """JSON-able: numpy scalars and arrays to Python."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
