"""Outputs of a fit: the text report, the JSON, the InferenceData (NetCDF) file and the set of
files ``--out`` writes (with the plots of :mod:`bayescap.report.plots`).

The ``--out`` set is written as a whole (a temporary directory beside the target, then renamed
into place).
"""

from __future__ import annotations

import json
from pathlib import Path

from bayescap.posterior import FitResult
from bayescap.posterior.summary import DERIVED_ORDER, PARAMETER_ORDER

__all__ = ["format_text", "to_json", "write_outputs", "to_inference_data", "plot_ptc", "plot_corner"]


def plot_ptc(result, path=None, **kwargs):
    """:func:`bayescap.report.plots.plot_ptc`, loaded on the first call: the text report and the
    JSON start without the plotting module."""
    from bayescap.report import plots

    return plots.plot_ptc(result, path, **kwargs)


def plot_corner(result, path=None, **kwargs):
    """:func:`bayescap.report.plots.plot_corner`, loaded on the first call (:func:`plot_ptc`)."""
    from bayescap.report import plots

    return plots.plot_corner(result, path, **kwargs)


def _fmt(x):
    if x is None:
        return "—"
    ax = abs(x)
    if ax != 0 and (ax >= 1e6 or ax < 1e-3):
        return f"{x:.4g}"
    if ax >= 1000:
        return f"{x:,.0f}"
    return f"{x:.4g}"


def _limit_row(name, s):
    """A quantity the data do not determine: its limit alone, never a median with an interval."""
    lim = s["limit"]
    sign = "<" if lim["kind"] == "upper" else ">"
    text = f"{sign} {_fmt(lim['value'])}"
    line = f"  {name:<28} {text:>11}   ({100 * lim['level']:g} % {lim['kind']} limit)  {s.get('unit', '')}"
    if lim.get("because"):
        line += f"   <- follows {lim['because']}"
    return line


def _row(name, s):
    if s.get("limit"):
        return _limit_row(name, s)
    lo68, hi68 = s["ci68"]
    lo95, hi95 = s["ci95"]
    unit = s.get("unit", "")
    line = f"  {name:<28} {_fmt(s['median']):>11}   [{_fmt(lo68)}, {_fmt(hi68)}]   [{_fmt(lo95)}, {_fmt(hi95)}]  {unit}"
    tags = []
    if s.get("constrained") is False:
        if "upper_limit_95" in s:
            tags.append(f"upper limit {_fmt(s['upper_limit_95'])} (95 %)")
        elif "lower_bound" in s:
            tags.append(f"lower bound {_fmt(s['lower_bound'])}")
        else:
            tags.append("not constrained")
    if s.get("lower_bound") is True:
        tags.append("lower bound")
    if tags:
        line += "   <- " + "; ".join(tags)
    return line


def format_or_na(value, spec: str) -> str:
    """``format(value, spec)``, or "n/a" for a diagnostic that could not be computed (null in the JSON)."""
    return "n/a" if value is None else format(value, spec)


def format_text(result: FitResult | dict) -> str:
    """The human-readable report printed by ``bayescap fit``."""
    d = result.to_dict() if isinstance(result, FitResult) else result
    dg = d["diagnostics"]
    lines = []
    name = d["sensor"].get("sensor", "")
    lines.append(f"bayescap {d['bayescap_version']}: {d['input']}" + (f"  ({name})" if name else ""))
    conv = "converged" if dg["converged"] else "NOT CONVERGED"
    num = lambda key, spec: format_or_na(dg.get(key), spec)

    if dg.get("method") == "laplace-is":
        lines.append(
            f"sampler: {conv}: Laplace–IS, Pareto k̂ {num('khat', '.2f')} (target < {dg['khat_max']:g}), "
            f"IS ESS {num('ess_is', '.0f')} (target ≥ {dg['ess_target']:.0f}); {dg['n_draws']} resampled "
            f"draws, {dg['wall_s']:.2f} s, quality {dg['quality']}, seed {dg['seed']}"
            + (" (drawn)" if dg.get("seed_drawn") else "")
        )
    else:
        lines.append(
            f"sampler: {conv}: R-hat max {num('rhat_max', '.4f')} (target < {dg['rhat_target']}), "
            f"ESS min {num('ess_min', '.0f')} (target ≥ {dg['ess_target']:.0f}); {dg['n_ensembles']} "
            f"ensembles × {dg['n_walkers']} walkers × {dg['n_steps']} steps, {dg['wall_s']:.1f} s, "
            f"quality {dg['quality']}, seed {dg['seed']}" + (" (drawn)" if dg.get("seed_drawn") else "")
        )
    if "fast_path" in dg:
        lines.append(f"  {dg['fast_path']}")
    if dg.get("method") != "laplace-is" and dg.get("interval_end_mcse_max") is not None:
        # the chains' own Monte Carlo error of the interval ends (fit.interval_end_mcse_mcmc)
        tgt = dg.get("interval_end_mcse_target")
        lines.append(
            f"  Monte Carlo error of the 95 % interval ends: up to {num('interval_end_mcse_max', '.3f')} "
            f"of the width ({dg.get('interval_end_mcse_worst', '?')}"
            + (f"; target ≤ {tgt:g}" if tgt is not None else "; reported, not a check")
            + ")"
        )
    lines.append("")
    lines.append(f"  {'parameter':<28} {'median':>11}   68 % interval   95 % interval")
    params = d["parameters"]
    for n in PARAMETER_ORDER + [k for k in params if k not in PARAMETER_ORDER]:
        if n in params and not n.startswith("response_shape_"):
            lines.append(_row(n, params[n]))
    if any(k.startswith("response_shape_") for k in params):
        lines.append(
            "  (the response's shape coefficients response_shape_1.. are in the JSON; its deviation and "
            "linearity error are above and below)"
        )
    sc = d["scene"]
    lines.append("")
    lines.append(f"  derived at t = {sc['exposure_time_s']:.4g} s ({sc['source']})")
    der = d["derived"]
    for n in DERIVED_ORDER + [k for k in der if k not in DERIVED_ORDER]:
        if n in der:
            lines.append(_row(n, der[n]))
    cap = der.get("capacity_bits") or der.get("capacity_bits_per_pixel")
    if cap:
        unit = "bits" if "capacity_bits" in der else "bits/pixel"
        lines.append("")
        if cap.get("limit"):
            lim = cap["limit"]
            lines.append(
                f"  capacity C > {_fmt(lim['value'])} {unit} ({100 * lim['level']:g} % lower limit: "
                f"follows {lim['because']})"
            )
        else:
            lines.append(
                f"  capacity C = {_fmt(cap['median'])} {unit}, 95 % interval "
                f"[{_fmt(cap['ci95'][0])}, {_fmt(cap['ci95'][1])}]"
                + (" (lower bound)" if cap.get("lower_bound") else "")
            )
    nb = d.get("noise_budget_mid_grey")
    if nb:
        shares = sorted(nb["shares_percent"].items(), key=lambda kv: -kv[1])
        big = [f"{n} {v:.3g} %" for n, v in shares if v >= 0.1]
        small = [n for n, v in shares if v < 0.1]
        lines.append("")
        lines.append(
            f"  noise at mid-grey (S = {_fmt(nb['signal_e'])} e-): "
            + ", ".join(big)
            + (f"; negligible (< 0.1 %): {', '.join(small)}" if small else "")
        )
    lines.append("")
    lines.append("  model terms: " + ", ".join(d["model_terms"]))
    if d.get("response_model"):
        lines.append(f"  response: {d['response_model']['reading']}")
    for t, why in d.get("terms_left_out", {}).items():
        lines.append(f"  left out: {t}: {why}")
    for t, how in d.get("term_notes", {}).items():
        lines.append(f"  note on {t}: {how}")
    ms = d.get("model_selection")
    if ms:
        lines.append(f"  model selection ({ms['criterion']}): chose '{ms['chosen']}', {ms['why']}")
        for n, v in ms["variants"].items():
            lines.append(
                f"    {n:<22} elpd_loo {v['elpd_loo']:9.1f} ± {v['se']:.1f}   Δ {v['elpd_diff']:7.1f} ± "
                f"{v['se_diff']:.1f}   p_loo {v['p_loo']:.1f}   k̂>0.7: {v['n_khat_above_0.7']}"
                + ("" if v.get("converged", True) else "   NOT CONVERGED")
            )
    if d.get("warnings"):
        lines.append("")
        for w in d["warnings"]:
            lines.append(f"  ! warning ({w['code']}): {w['message']}")
    if d.get("notes"):
        lines.append("")
        for n in d["notes"]:
            lines.append(f"  ! {n}")
    return "\n".join(lines) + "\n"


def to_json(result: FitResult, *, indent=2) -> str:
    d = result.to_dict()
    return json.dumps(d, indent=indent, ensure_ascii=False, allow_nan=False) + "\n"


def to_inference_data(result: FitResult):
    """ArviZ InferenceData of ``result``: chains = independent ensembles (``az.rhat`` is the
    report's R-hat), physical parameters and derived quantities with units, the sampler's
    coordinates, pointwise log-likelihood (``az.loo``), replicated and observed data, the input
    columns (:mod:`bayescap.posterior.inference_data`; docs/results.md)."""
    from bayescap.posterior.inference_data import to_inference_data as _to_inference_data

    return _to_inference_data(result)


#: the files of a fit's output set (``bayescap fit --out DIR``)
OUTPUT_NAMES = ("result.json", "report.txt", "posterior.nc", "ptc.png", "corner.png")


def _check_space(folder: Path, idata) -> None:
    """Refuse, before h5py starts, a NetCDF file that cannot fit on the disk: h5py crashes the
    process (segmentation fault) when a write fails for want of space."""
    import errno
    import shutil

    need = sum(v.nbytes for g in idata.groups() for v in idata[g].variables.values()) + (1 << 20)
    if shutil.disk_usage(folder).free < need:
        raise OSError(errno.ENOSPC, f"No space left on device for posterior.nc (~{need >> 20} MB)", str(folder))


def write_outputs(result: FitResult, out_dir) -> list[Path]:
    """Write result.json, report.txt, posterior.nc, ptc.png and corner.png into ``out_dir``, as a
    whole: they are written into a temporary directory beside it, which then replaces
    ``out_dir`` (:func:`bayescap.io.atomic.write_dir_atomically`), so ``out_dir`` holds one
    complete run, the previous one, or nothing. An existing ``out_dir`` holding other files is
    refused (:class:`FileExistsError`); write errors raise :class:`OSError` and leave nothing."""
    from bayescap.io.atomic import output_problem, write_dir_atomically
    from bayescap.posterior.storage import netcdf_bytes

    out = Path(out_dir)
    problem = output_problem(out, directory=True, names=OUTPUT_NAMES, option="output directory")
    if problem:
        import errno

        raise FileExistsError(errno.EEXIST, problem, str(out))

    def fill(tmp: Path) -> None:
        (tmp / "result.json").write_text(to_json(result), encoding="utf-8")
        (tmp / "report.txt").write_text(format_text(result), encoding="utf-8")
        idata = to_inference_data(result)
        _check_space(tmp, idata)
        # built in memory and written by Python: h5py crashes the process when its own write fails
        (tmp / "posterior.nc").write_bytes(netcdf_bytes(idata))
        plot_ptc(result, tmp / "ptc.png")
        plot_corner(result, tmp / "corner.png")

    write_dir_atomically(out, fill)
    return [out / n for n in OUTPUT_NAMES]
