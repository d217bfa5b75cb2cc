"""Plots of a fit: the photon-transfer curve with its posterior predictive band, and the corner
plot of the parameters.

The figures are :class:`matplotlib.figure.Figure` objects made without pyplot: no backend is
selected and no global style is changed, so a notebook's display stays as it was. Returned
figures display in a notebook; ``path`` writes a PNG atomically. matplotlib loads on the first
plot, so the text report and the JSON start without it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bayescap.posterior import FitResult
from bayescap.posterior.summary import PARAMETER_ORDER

__all__ = ["plot_ptc", "plot_corner", "plain_text"]


def plain_text(text) -> str:
    """``text`` shown as it is in a matplotlib title, label or legend: every ``$`` escaped, so a
    file or sensor name such as ``cam_$5_vs_$10`` is not parsed as math text."""
    return str(text).replace("$", r"\$")


def _corner_size(k: int) -> float:
    """The side (inches) corner.py gives a figure of ``k`` × ``k`` panels when it makes one itself."""
    factor, whspace = 2.0, 0.05
    return 0.5 * factor + factor * k + factor * (k - 1.0) * whspace + 0.2 * factor


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
    dobs, dmodel, drep = pp["dark_var"]
    ax.plot(np.zeros_like(dobs) + max(S.min() * 0.5, 1e-3), dobs, "g.", ms=3, label="dark pairs")
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
    """Corner plot of the physical parameters (corner.py)."""
    import corner
    from matplotlib.figure import Figure

    names = [n for n in PARAMETER_ORDER if n in result.draws and np.ptp(result.draws[n]) > 0]
    idx = result.thin_index(n_max)
    X = np.column_stack([result.draws[n][idx] for n in names])
    fig = Figure(figsize=(_corner_size(len(names)),) * 2)
    corner.corner(
        X,
        fig=fig,
        labels=names,
        quantiles=[0.025, 0.5, 0.975],
        show_titles=True,
        title_fmt=".4g",
        label_kwargs={"fontsize": 7},
        title_kwargs={"fontsize": 7},
    )
    if path is not None:
        _savefig(fig, path)
    return fig


def _savefig(fig, path):
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
