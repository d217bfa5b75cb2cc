"""Plots of a fit: the photon-transfer curve with its posterior predictive band, and the corner
plot of the parameters.

The figures are :class:`matplotlib.figure.Figure` objects made without pyplot: no backend is
selected and no global style is changed, so a notebook's display stays as it was. In Jupyter a
returned figure shows as a cell's last expression or with ``IPython.display.display(fig)`` once
the inline backend is active (``%matplotlib inline``, or any pyplot import in the kernel);
``path`` writes a PNG (256-colour palette) atomically. matplotlib loads on the first plot, so the
text report and the JSON start without it.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from bayescap.posterior import FitResult

__all__ = ["plot_ptc", "plot_corner", "png_bytes", "plain_text", "CORNER_LABELS"]


def plain_text(text) -> str:
    """``text`` shown as it is in a matplotlib title, label or legend: every ``$`` escaped, so a
    file or sensor name such as ``cam_$5_vs_$10`` is not parsed as math text."""
    return str(text).replace("$", r"\$")


#: the physical parameters the corner plot shows, in its order, with their axis labels (units in
#: brackets) and the short names above the diagonal's histograms; a fit's nuisance parameters
#: (clip spread, variance and mean discrepancies) stay out
CORNER_LABELS = {
    "conversion_gain_e_per_dn": ("K (e⁻/DN)", "K"),
    "read_noise_e": ("read noise (e⁻)", "read noise"),
    "dark_noise_e": ("dark noise (e⁻)", "dark noise"),
    "dark_current_e_per_s": ("dark current (e⁻/s)", "dark current"),
    "full_well_e": ("full well (e⁻)", "full well"),
    "quantum_efficiency": ("QE", "QE"),
    "prnu_percent": ("PRNU (%)", "PRNU"),
    "dsnu_e": ("DSNU (e⁻)", "DSNU"),
}

#: the corner plot: inches per panel, resolution of corner.png, points scattered under the
#: contours (the tails outside them)
_CORNER_PANEL_IN = 1.45
_CORNER_DPI = 100
_CORNER_POINTS = 1500


def _posterior_predictive(result: FitResult, n_draws=300):
    m = result.model
    E, S, W, D = result.chains.chain.shape
    flat = result.chains.chain.reshape(-1, D)
    idx = result.thin_index(n_draws)
    th = flat[idx]
    pred = m.predict(th)
    rng = np.random.default_rng(np.random.SeedSequence(result.seed).spawn(3)[2])
    out = {}
    for name in ("bright_var", "dark_var"):
        if name not in pred:  # a mean/variance table has no dark pairs
            continue
        obs, model, k, _ = pred[name]
        k = np.broadcast_to(k, model.shape)
        rep = rng.gamma(k, model / k)
        out[name] = (obs, model, rep)
    out["signal_dn"] = np.median(m._last_latent_signal_dn, axis=0)
    return out


def plot_ptc(result: FitResult, path=None):
    """Photon-transfer curve: measured temporal variances against signal, the posterior
    predictive 95 % band, and residuals relative to the posterior median model."""
    from matplotlib.figure import Figure

    m = result.model
    pp = _posterior_predictive(result)
    obs, model, rep = pp["bright_var"]
    S = pp["signal_dn"]
    med = np.median(model, axis=0)
    lo, hi = np.quantile(rep, [0.025, 0.975], axis=0)
    order = np.argsort(S)
    fig = Figure(figsize=(7, 7))
    ax, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.fill_between(S[order], lo[order], hi[order], color="C0", alpha=0.3, label="posterior predictive 95 %")
    ax.plot(S[order], med[order], "C0-", lw=1, label="model (posterior median)")
    ax.plot(S, obs, "k.", ms=4, label="measured (bright pairs)")
    full = m.full_sat
    d = m.data
    if np.any(full):
        ax.plot(
            d.signal_dn[full],
            np.maximum(d.temporal_var_dn2[full], 1e-3),
            "rx",
            ms=5,
            label="fully clipped rows (locate the clip only)",
        )
    if "dark_var" in pp:
        dobs, dmodel, drep = pp["dark_var"]
        ax.plot(np.zeros_like(dobs) + max(S.min() * 0.5, 1e-3), dobs, "g.", ms=3, label="dark pairs")
    if not d.has_dark_rows:  # a mean/variance table: mark the PTC turnoff (derived.ptc_turnoff_dn)
        from bayescap.posterior.derived import ptc_turnoff

        i_t, _ = ptc_turnoff(d.signal_dn, d.temporal_var_dn2)
        if i_t is not None:
            ax.axvline(d.signal_dn[i_t], color="0.4", ls="--", lw=1, label="PTC turnoff")
    ax.set_ylabel("temporal variance (DN²)")
    ax.set_title(plain_text(f"photon transfer: {Path(str(d.source)).name}"))
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    res = 100 * (obs - med) / med
    rlo = 100 * (lo - med) / med
    rhi = 100 * (hi - med) / med
    ax2.fill_between(S[order], rlo[order], rhi[order], color="C0", alpha=0.3)
    ax2.axhline(0, color="C0", lw=1)
    ax2.plot(S, res, "k.", ms=4)
    ax2.set_xlabel("signal above dark (DN)")
    ax2.set_ylabel("residual (%)")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    if path is not None:
        _savefig(fig, path)
    return fig


def plot_corner(result: FitResult, path=None, n_max=20000):
    """Corner plot of the physical parameters (corner.py): labels with units; above each
    histogram the report's median and 95 % interval (dashed lines), or for a quantity the report
    gives as a limit (DSNU the data do not detect, ...) the limit alone ("< 0.22 (95 % upper
    limit)", one solid line, the excluded side shaded). The histograms and contours use up to
    ``n_max`` thinned draws; outside the outer contour a thinner subset is scattered, which keeps
    the PNG small."""
    import corner
    from matplotlib.figure import Figure

    names = [n for n in CORNER_LABELS if n in result.draws and np.ptp(result.draws[n]) > 0]
    idx = result.thin_index(n_max)
    X = np.column_stack([result.draws[n][idx] for n in names])
    k = len(names)
    side = _CORNER_PANEL_IN * k + 0.9
    fig = Figure(figsize=(side, side))
    corner.corner(
        X,
        bins=40,
        fig=fig,
        labels=[CORNER_LABELS[n][0] for n in names],
        label_kwargs={"fontsize": 11},
        max_n_ticks=3,
        smooth=0.7,
        plot_datapoints=False,
        fill_contours=True,
        plot_density=False,
        levels=(0.393, 0.865, 0.989),
        labelpad=0.08,
    )
    axes = np.array(fig.axes).reshape(k, k)
    sub = X[np.linspace(0, len(X) - 1, min(_CORNER_POINTS, len(X))).astype(int)]
    for i in range(1, k):
        for j in range(i):
            axes[i, j].plot(sub[:, j], sub[:, i], ".", ms=1.5, color="0.4", alpha=0.6, zorder=-1)
    summary = result.parameter_summary()
    for i, n in enumerate(names):
        _mark_diagonal(axes[i, i], CORNER_LABELS[n][1], summary.get(n), X[:, i])
    for ax in fig.axes:
        ax.tick_params(labelsize=8)
    # room for the titles above the first histogram and beside the last
    fig.subplots_adjust(top=1 - 0.45 / side, right=1 - 0.4 / side)
    if path is not None:
        _savefig(fig, path, dpi=_CORNER_DPI)
    return fig


def _mark_diagonal(ax, label, s, x):
    """Title and lines of a histogram: the summary ``s``'s median and 95 % interval, or its limit
    alone (:func:`bayescap.posterior.limits.apply_parameter_limits`)."""
    lim = (s or {}).get("limit")
    if lim:
        v, upper = lim["value"], lim["kind"] == "upper"
        ax.axvline(v, color="C3", lw=1.2)
        lo, hi = ax.get_xlim()
        span = (v, max(hi, v)) if upper else (min(lo, v), v)  # the side the limit excludes
        ax.axvspan(*span, color="0.85", zorder=-2)
        ax.set_xlim(lo, hi)
        sign = "<" if upper else ">"
        ax.set_title(f"{label}\n{sign} {_g(v)} ({100 * lim['level']:g} % {lim['kind']} limit)", fontsize=8.5)
        return
    if s is not None and s.get("median") is not None:
        med, (lo, hi) = s["median"], s["ci95"]
    else:
        lo, med, hi = np.quantile(x, [0.025, 0.5, 0.975])
    for v in (lo, med, hi):
        ax.axvline(v, color="k", ls="--", lw=0.8)
    ax.set_title(f"{label}\n{_g(med)} [{_g(lo)}, {_g(hi)}]", fontsize=8.5)


def _g(x) -> str:
    """Four significant digits, whole numbers without an exponent."""
    return f"{x:.0f}" if abs(x) >= 1e4 else f"{x:.4g}"


def png_bytes(fig, dpi=110) -> bytes:
    """The figure as a PNG with an adaptive 256-colour palette: line art and flat fills lose
    nothing visible, and the file is a third to a fifth of the full-colour one."""
    from PIL import Image

    # Agg's pixels as they are (format "rgba"): the same pixels a full-colour PNG would hold, without
    # encoding that PNG and decoding it again (a quarter of the time; the same bytes out)
    buf = io.BytesIO()
    fig.savefig(buf, format="rgba", dpi=dpi)
    w, h = (int(v) for v in fig.get_size_inches() * dpi)  # Agg's canvas: int() of the size in pixels
    if len(buf.getbuffer()) == 4 * w * h:
        im = Image.frombuffer("RGBA", (w, h), buf.getbuffer(), "raw", "RGBA", 0, 1)
    else:  # not the size expected: let PIL read the size from a PNG
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
        buf.seek(0)
        im = Image.open(buf)
    with im:
        pal = im.convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    out = io.BytesIO()
    pal.save(out, format="png", optimize=True)
    return out.getvalue()


def _savefig(fig, path, dpi=110):
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    try:
        if path.suffix.lower() == ".png":
            tmp.write_bytes(png_bytes(fig, dpi))
        else:
            fig.savefig(tmp, dpi=dpi)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
