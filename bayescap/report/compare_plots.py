"""The cross-sensor figures of the HTML report (:mod:`bayescap.report.html`): capacity per sensor
(Fig. 8(b)), TR against H₀ (Fig. 8(a)), SNR against exposure (Figs. 5-6), each sensor's curve in
its own colour, line style and marker (curves that coincide stay told apart), and the matrix of
pairwise probabilities, coloured by the practical-difference probability."""

from __future__ import annotations

import warnings

import numpy as np
from matplotlib.figure import Figure

from bayescap.physics.capacity import tonal_range_bits
from bayescap.report.plots import plain_text
from bayescap.studies.compare import Comparison
from bayescap.studies.exposure import snr_at_exposure, tonal_range_at_exposure

__all__ = ["H0_GRID_LUX_S", "plot_capacity", "plot_tr_h0", "plot_snr_exposure", "plot_probability_matrix"]

#: exposures of the TR(H0) and SNR(H) curves (lux·s)
H0_GRID_LUX_S = np.geomspace(1e-3, 10.0, 61)

_N_CURVE_DRAWS = 1000

#: line styles and markers by sensor, so that curves that coincide stay told apart
_LINE_STYLES = ("-", "--", ":", "-.", (0, (5, 1, 1, 1, 1, 1)))
_MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*")


def _band(ax, x, draws, color, label, k=0):
    """Median curve and 95 % band of ``draws``; the ``k``-th sensor's line style and marker."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns above the clip
        lo, med, hi = np.nanquantile(draws, [0.025, 0.5, 0.975], axis=0)
    ax.fill_between(x, lo, hi, color=color, alpha=0.25, lw=0)
    n = np.size(x)
    ax.plot(
        x,
        med,
        color=color,
        lw=1.5,
        label=label,
        ls=_LINE_STYLES[k % len(_LINE_STYLES)],
        marker=_MARKERS[k % len(_MARKERS)],
        ms=5,
        markevery=((k * max(1, n // 32)) % max(1, n // 8), max(1, n // 8)),  # markers staggered by sensor
        fillstyle="none",
    )


def plot_capacity(cmp: Comparison):
    """Fig. 8(b): capacity (Mbit) per sensor, medians with 95 % intervals, at full resolution and
    at the fixed area."""
    d = cmp.to_dict()
    names = [plain_text(s["name"]) for s in d["sensors"]]
    x = np.arange(len(names))
    fig = Figure(figsize=(8, 4.2))
    ax = fig.subplots()
    area = d["conventions"]["area"]
    for off, key, lab, col in (
        (-0.18, "capacity_full_bits", "full resolution", "C0"),
        (0.18, "capacity_area_bits", plain_text(f"at {area['name']}") if area else None, "C1"),
    ):
        if lab is None:
            continue
        med = np.array([s[key]["median"] if s.get(key) else np.nan for s in d["sensors"]]) / 1e6
        lo = np.array([s[key]["ci95"][0] if s.get(key) else np.nan for s in d["sensors"]]) / 1e6
        hi = np.array([s[key]["ci95"][1] if s.get(key) else np.nan for s in d["sensors"]]) / 1e6
        ax.bar(x + off, med, width=0.36, color=col, alpha=0.8, label=lab)
        ax.errorbar(x + off, med, yerr=[med - lo, hi - med], fmt="none", ecolor="k", capsize=3, lw=1)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("information capacity C (Mbit)")
    ax.set_title(f"capacity, TR at H0 = {d['conventions']['h0_lux_s']:g} lux·s (95 % intervals)", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return fig


def plot_tr_h0(cmp: Comparison, h_grid=H0_GRID_LUX_S):
    """Fig. 8(a): TR (bits, 8-bit-equivalent) against average exposure H₀ with 95 % bands."""
    fig = Figure(figsize=(8, 4.2))
    ax = fig.subplots()
    c = cmp.conventions
    drawn = 0
    for i, s in enumerate(cmp.sensors):
        if s.calibration is None:
            continue
        idx = s.result.thin_index(_N_CURVE_DRAWS)
        tr, _ = tonal_range_at_exposure(
            s.result, h_grid, calibration=s.calibration, mid_grey=c["mid_grey_fraction"], idx=idx
        )
        _band(ax, h_grid, tonal_range_bits(tr), f"C{i % 10}", plain_text(s.name), k=i)
        drawn += 1
    ax.axvline(c["h0_lux_s"], color="k", ls=":", lw=1, label=f"H0 = {c['h0_lux_s']:g} lux·s")
    ax.set_xscale("log")
    ax.set_xlabel("average photometric exposure H0 (lux·s)")
    ax.set_ylabel("tonal range b' = log2 TR (bits)")
    ax.set_title(f"TR vs H0 (mean scene at {100 * c['mid_grey_fraction']:g} % of the range; 95 % bands)", fontsize=10)
    if not drawn:
        ax.text(0.5, 0.5, "no sensor has an exposure calibration", transform=ax.transAxes, ha="center")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


def plot_snr_exposure(cmp: Comparison, h_grid=H0_GRID_LUX_S):
    """Figs. 5-6: SNR (dB) against photometric exposure H (lux·s), 95 % bands, up to the clip."""
    fig = Figure(figsize=(8, 4.2))
    ax = fig.subplots()
    drawn = 0
    for i, s in enumerate(cmp.sensors):
        if s.calibration is None:
            continue
        idx = s.result.thin_index(_N_CURVE_DRAWS)
        _band(
            ax,
            h_grid,
            snr_at_exposure(s.result, h_grid, calibration=s.calibration, idx=idx),
            f"C{i % 10}",
            plain_text(s.name),
            k=i,
        )
        drawn += 1
    ax.set_xscale("log")
    ax.set_xlabel("photometric exposure H (lux·s)")
    ax.set_ylabel("SNR (dB)")
    ax.set_title("SNR vs exposure (Eq. 1; 95 % bands, often thinner than a line; curves end at the clip)", fontsize=10)
    if not drawn:
        ax.text(0.5, 0.5, "no sensor has an exposure calibration", transform=ax.transAxes, ha="center")
    else:
        ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


def plot_probability_matrix(cmp: Comparison, quantity: str = "area"):
    """Heat map coloured by what matters: ``P(C_row > (1+δ)·C_column)``, the probability that the
    row's capacity exceeds the column's by more than the practical difference δ; each cell also
    gives the ratio ``C_row/C_column`` (median) and ``P(C_row > C_column)``."""
    m = cmp.practical_matrix(quantity)
    p = cmp.probability_matrix(quantity)
    r = cmp.ratio_matrix(quantity)
    delta = cmp.conventions.get("practical_difference", 0.01)
    names = [plain_text(s.name) for s in cmp.sensors]
    n = len(names)
    # shown half-width on the page: a compact figure with large type stays readable
    fig = Figure(figsize=(0.95 * n + 2.8, 0.75 * n + 2.2))
    ax = fig.subplots()
    im = ax.imshow(m, vmin=0, vmax=1, cmap="Reds")
    for i in range(n):
        for j in range(n):
            if np.isfinite(m[i, j]):
                ax.text(
                    j,
                    i,
                    f"{m[i, j]:.2f}\n×{r[i, j]:.4g}\nP(>) {p[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=8,
                    linespacing=1.15,
                    color="w" if m[i, j] > 0.6 else "k",
                )
    ax.set_xticks(range(n))
    ax.set_yticks(range(n))
    ax.set_xticklabels(names, rotation=30, ha="right", fontsize=10)
    ax.set_yticklabels(names, fontsize=10)
    where = (
        "at full resolution"
        if quantity == "full"
        else f"at {cmp.conventions['area']['name']}"
        if cmp.conventions["area"]
        else ""
    )
    ax.set_title(
        plain_text(
            f"P(C_row > (1+δ)·C_column), δ = {100 * delta:g} % {where}\n(below: C_row/C_column, P(C_row > C_column))"
        ),
        fontsize=10,
    )
    fig.colorbar(im, ax=ax, fraction=0.046, label=plain_text(f"P(larger by more than {100 * delta:g} %)"))
    fig.tight_layout()
    return fig
