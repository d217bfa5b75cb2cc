"""Saving a fit result and loading it back: :meth:`FitResult.save` / :meth:`FitResult.load`.

The file is the result's InferenceData (:mod:`bayescap.posterior.inference_data`, the same groups
as ``posterior.nc``), whose attribute ``bayescap_result`` (JSON) adds what the report needs
beyond the draws: metadata, scene, seed, quality, model terms and prior, diagnostics, notes,
flags, the MTF and the sampler's settings. Loading rebuilds the model from the input data
(``constant_data``), takes the sampler's chain from ``unconstrained_posterior`` and the physical
and derived draws from ``posterior`` (exact float64), so ``to_dict()`` (the JSON) and the report
come back identical. Written atomically (a temporary file in the target folder, then a rename).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from bayescap.inference import presets
from bayescap.inference.chains import ChainResult
from bayescap.io.ptc_csv import PTCData
from bayescap.model.ptc_model import PTCModel
from bayescap.model.terms import ModelTerms
from bayescap.physics import optics
from bayescap.posterior.inference_data import INPUT_COLUMNS, _plain, draw_order, to_inference_data
from bayescap.posterior.scene import Scene

__all__ = ["save_result", "load_result", "FORMAT_VERSION"]

#: the layout of the ``bayescap_result`` attribute
FORMAT_VERSION = 1
#: the chains' ``extra`` entries not stored (functions; weighted draws go to their own group)
_EXTRA_LEFT_OUT = ("weighted_draws", "param_diagnostics")


def _mtf_state(mtf):
    """A JSON description of an MTF made of :mod:`bayescap.physics.optics` dataclasses, or None."""
    if dataclasses.is_dataclass(mtf) and getattr(optics, type(mtf).__name__, None) is type(mtf):
        out = {"class": type(mtf).__name__}
        for f in dataclasses.fields(mtf):
            v = getattr(mtf, f.name)
            if f.name == "components":
                v = [_mtf_state(c) for c in v]
                if any(c is None for c in v):
                    return None
            elif isinstance(v, np.ndarray):
                v = {"array": v.tolist()}
            out[f.name] = v
        return out
    return None


def _mtf_from_state(state):
    if state is None:
        return None
    kw = {}
    for k, v in state.items():
        if k == "class":
            continue
        if k == "components":
            v = tuple(_mtf_from_state(c) for c in v)
        elif isinstance(v, dict) and "array" in v:
            v = np.asarray(v["array"], float)
        kw[k] = v
    return getattr(optics, state["class"])(**kw)


def _result_state(result) -> dict:
    c = result.chains
    m = result.model
    return _plain(
        {
            "format": FORMAT_VERSION,
            "metadata": result.metadata,
            "scene": dataclasses.asdict(result.scene),
            "seed": result.seed,
            "quality": result.quality,
            "diag": result.diag,
            "notes": result.notes,
            "flags": result.flags,
            "input_warnings": result.input_warnings,
            "mtf_info": result.mtf_info,
            "mtf": _mtf_state(result.mtf),
            "outliers": list(getattr(result, "outliers", [])),
            "model_selection": getattr(result, "model_selection", None),
            "terms": dataclasses.asdict(m.terms),
            "prior": m.__dict__.get("PRIOR"),
            "data_source": str(m.data.source),
            "data_metadata": m.data.metadata,
            "derived_names": list(result.derived),
            "chains": {
                "shape": list(c.chain.shape),
                "acceptance": c.acceptance,
                "tau": c.tau,
                "x_map": c.x_map,
                "lp_map": c.lp_map,
                "wall_s": c.wall_s,
                "n_rounds": c.n_rounds,
                "settings_class": type(c.settings).__name__,
                "settings": dataclasses.asdict(c.settings) if dataclasses.is_dataclass(c.settings) else None,
                "extra": {k: v for k, v in c.extra.items() if k not in _EXTRA_LEFT_OUT and not callable(v)},
            },
        }
    )


def save_result(result, path) -> Path:
    """Write ``result`` to ``path`` (netCDF, module docstring), atomically."""
    path = Path(path)
    idata = to_inference_data(result)
    idata.attrs["bayescap_result"] = json.dumps(_result_state(result), allow_nan=True)
    wd = result.chains.extra.get("weighted_draws")
    if wd:
        import xarray as xr

        idata.add_groups(
            {
                "bayescap_weighted_draws": xr.Dataset(
                    {"x": (("proposal", "dim"), np.asarray(wd["x"])), "w": (("proposal",), np.asarray(wd["w"]))},
                    attrs={"n_resampled": int(wd["n_resampled"])},
                )
            }
        )
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    try:
        idata.to_netcdf(str(tmp), engine="h5netcdf")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _tuples(v):
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v


def load_result(path, result_cls):
    """The ``result_cls`` (FitResult) saved at ``path`` by :func:`save_result`."""
    import arviz as az

    idata = az.from_netcdf(str(path), engine="h5netcdf")
    try:
        idata = idata.load() if hasattr(idata, "load") else idata
        groups = {g: idata[g].load() for g in idata.groups()}
        state = json.loads(idata.attrs["bayescap_result"])
    finally:
        for g in idata.groups():
            idata[g].close()
    if state.get("format") != FORMAT_VERSION:
        raise ValueError(f"{path}: not a bayescap result file of format {FORMAT_VERSION}")
    cd = groups["constant_data"]
    cols = {k: np.asarray(cd[k].values) for k in INPUT_COLUMNS if k in cd}
    data = PTCData(**cols, metadata=state["data_metadata"], source=state["data_source"])
    terms = ModelTerms(**state["terms"])
    prior = state["prior"]
    model = PTCModel(data, terms=terms, prior={k: _tuples(v) for k, v in prior.items()} if prior else None)

    ch = state["chains"]
    E, S, W, D = ch["shape"]
    order, _, _ = draw_order(S, W)

    def esw(values):
        """(E, n) file draws back to the (E, S, W) step-major order, flattened."""
        out = np.empty((E, S * W))
        out[:, order] = values
        return out.reshape(E * S * W)

    unc = groups["unconstrained_posterior"]
    chain = np.stack([esw(unc[n].values) for n in model.names], axis=-1).reshape(E, S, W, D)
    log_prob = esw(groups["sample_stats"]["lp"].values).reshape(E, S, W)
    settings = ch["settings"]
    if settings is not None:
        settings = getattr(presets, ch["settings_class"])(**{k: _tuples(v) for k, v in settings.items()})
    extra = dict(ch["extra"])
    if "bayescap_weighted_draws" in groups:
        g = groups["bayescap_weighted_draws"]
        extra["weighted_draws"] = {
            "x": np.asarray(g["x"].values),
            "w": np.asarray(g["w"].values),
            "n_resampled": int(g.attrs["n_resampled"]),
        }
    chains = ChainResult(
        chain=chain,
        log_prob=log_prob,
        acceptance=np.asarray(ch["acceptance"], float),
        tau=np.asarray(ch["tau"], float),
        x_map=np.asarray(ch["x_map"], float),
        lp_map=ch["lp_map"],
        settings=settings,
        wall_s=ch["wall_s"],
        n_rounds=ch["n_rounds"],
        extra=extra,
    )
    n_draws = E * S * W
    post = {n: esw(groups["posterior"][n].values) for n in groups["posterior"].data_vars}
    for n in json.loads(idata.attrs.get("constant_variables", "[]")):
        post[n] = np.full(n_draws, float(cd[n].values))
    order_names = json.loads(idata.attrs.get("units", "{}"))  # every variable, in the result's order
    post = {
        n: post[n]
        for n in sorted(post, key=lambda n: list(order_names).index(n) if n in order_names else len(order_names))
    }
    derived_names = state["derived_names"]
    r = result_cls(
        model=model,
        chains=chains,
        metadata=state["metadata"],
        scene=Scene(**state["scene"]),
        mtf=_mtf_from_state(state["mtf"]),
        seed=state["seed"],
        quality=state["quality"],
        draws={n: v for n, v in post.items() if n not in derived_names},
        derived={n: post[n] for n in derived_names},
        notes=list(state["notes"]),
        flags=dict(state["flags"]),
        diag=state["diag"],
        input_warnings=list(state.get("input_warnings", [])),
        mtf_info=state["mtf_info"],
    )
    r.outliers = list(state["outliers"])
    if state.get("model_selection") is not None:
        r.model_selection = state["model_selection"]
    return r
