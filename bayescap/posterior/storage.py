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
from pathlib import Path

import numpy as np

from bayescap.inference import presets
from bayescap.inference.chains import ChainResult
from bayescap.io.atomic import atomic_write_bytes
from bayescap.io.ptc_csv import PTCData
from bayescap.model.ptc_model import PTCModel
from bayescap.model.response_spline import is_spline, knots
from bayescap.model.terms import ModelTerms
from bayescap.physics import optics
from bayescap.posterior.inference_data import INPUT_COLUMNS, _plain, draw_order, to_inference_data
from bayescap.posterior.scene import Scene

__all__ = ["save_result", "load_result", "netcdf_bytes", "FORMAT_VERSION"]

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


#: the MTF classes a result file may name ("mtf.class"): the ones :func:`_mtf_state` writes
_MTF_CLASSES = frozenset(
    n for n in dir(optics) if isinstance(getattr(optics, n), type) and dataclasses.is_dataclass(getattr(optics, n))
)


def _mtf_from_state(state):
    if state is None:
        return None
    cls = state.get("class") if isinstance(state, dict) else None
    if cls not in _MTF_CLASSES:  # never a class the file names freely (any module attribute)
        raise ValueError(f"not a bayescap MTF class: {cls!r}")
    kw = {}
    for k, v in state.items():
        if k == "class":
            continue
        if k == "components":
            v = tuple(_mtf_from_state(c) for c in v)
        elif isinstance(v, dict) and "array" in v:
            v = np.asarray(v["array"], float)
        kw[k] = v
    return getattr(optics, cls)(**kw)


def _response_knots(terms) -> list | None:
    """The response spline's knots when the model has one, else None. Saved with the result: the
    file holds the spline's coefficients, which on other knots are another shape."""
    if getattr(terms, "nonlinearity", False) and is_spline(int(getattr(terms, "response_degree", 0))):
        return [float(k) for k in knots()]
    return None


def _check_response_knots(path, terms, state) -> None:
    """Refuse a file whose response spline has knots other than this bayescap's (or none recorded):
    its draws would be read back on another shape."""
    here = _response_knots(terms)
    if here is None:
        return
    saved = state.get("response_spline_knots")
    if saved is not None and len(saved) == len(here) and np.allclose(saved, here, rtol=0.0, atol=1e-12):
        return
    was = "not recorded in the file" if saved is None else "at " + ", ".join(f"{k:.4g}" for k in saved)
    raise ValueError(
        f"{path}: its response is a spline log-slope whose knots are {was}, not at this bayescap's "
        f"{', '.join(f'{k:.4g}' for k in here)}: its draws would be read on another shape; fit the data again"
    )


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
            "response_spline_knots": _response_knots(m.terms),
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
    # built in memory, then written by Python: h5py writing a file itself crashes the process
    # (SIGSEGV) when a write fails (a full disk, a quota, ``ulimit -f``); an OSError here instead
    atomic_write_bytes(path, netcdf_bytes(idata))
    return path


def netcdf_bytes(idata) -> bytes:
    """The netCDF-4 file (h5netcdf) of an InferenceData, as bytes: the same groups and attributes as
    ``idata.to_netcdf``, built in memory so that no file write happens inside h5py. Numbers are
    compressed with HDF5's byte shuffle before zlib: MCMC draws are noise in their low bytes, which
    zlib alone barely shrinks (6.1 MB of 6.7 on a 25-row sensor's fast fit, 2.5 CPU-s to write);
    shuffled, the high bytes compress (6.0 MB, 1.5 CPU-s). Any netCDF-4 reader decodes it."""
    import xarray as xr

    groups = {f"/{g}": idata[g] for g in idata.groups()}
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs=dict(idata.attrs)), **groups})
    encoding = {
        g: {v: {"zlib": True, "shuffle": True} for v, x in ds.variables.items() if x.dtype.kind in "biufc"}
        for g, ds in groups.items()
    }
    return bytes(tree.to_netcdf(None, engine="h5netcdf", encoding=encoding))


def _checked_shape(path, shape, groups, n_params):
    """The chain's (E, S, W, D) as the file states it, checked against the draws the file holds
    before anything of that size is allocated (a crafted shape must not ask for gigabytes)."""
    ok = isinstance(shape, list) and len(shape) == 4 and all(type(x) is int and x > 0 for x in shape)
    if ok:
        E, S, W, D = shape
        unc = groups.get("unconstrained_posterior")
        sizes = {int(unc[n].size) for n in unc.data_vars} if unc is not None and unc.data_vars else set()
        ok = D == n_params and sizes == {E * S * W}
    if not ok:
        raise ValueError(f"{path}: not a bayescap result file (the chain's shape {shape!r} does not match its draws)")
    return E, S, W, D


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
    _check_response_knots(path, terms, state)
    prior = state["prior"]
    model = PTCModel(data, terms=terms, prior={k: _tuples(v) for k, v in prior.items()} if prior else None)

    ch = state["chains"]
    E, S, W, D = _checked_shape(path, ch.get("shape"), groups, len(model.names))
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
        cls = getattr(presets, str(ch.get("settings_class")), None)
        if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
            raise ValueError(f"{path}: not a bayescap result file (sampler settings {ch.get('settings_class')!r})")
        settings = cls(**{k: _tuples(v) for k, v in settings.items()})
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
    try:
        mtf = _mtf_from_state(state["mtf"])
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
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
        mtf=mtf,
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
