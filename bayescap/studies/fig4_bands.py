"""Fig. 4 with every uncertain input drawn: capacity against pitch and the optimal pitch.

:func:`bayescap.studies.sweep.pixel_size_sweep` follows the paper's recipe (b' linear between the
Table 1 pitches, the paper's 0.35 bit/µm below 1.45 µm, one wavelength) and draws only the
Table 1 ranges. Its Eq. 9 optimum (≈ 1.2 µm) lies in the extrapolated region, where those ranges
only shift b' by a constant, so its interval is a few thousandths of a µm wide: it says how
little the Table 1 ranges matter there, not how well the optimum is known. Here each input that
is not fixed by the paper is drawn, and the source of each band is named:

* ``"table1"``: full well uniform within its printed range, PRNU uniform in [0, its bound]
  (:func:`~bayescap.studies.sweep.sample_table1`; sensitivity and dark current are single
  printed values and have no range);
* ``"tr_slope"``: the slope of b' below 1.45 µm, where Table 1 ends: uniform between the draw's
  least-squares slope over all Table 1 pitches and its slope over the last segment
  (1.75 → 1.45 µm); the paper's "approximately 0.35 bit/µm" lies in that range for the nominal;
* ``"wavelength"``: the green channel's wavelength, uniform in ``wavelength_range_nm`` (default
  500–600 nm); the diffraction cut-off ``P/(λN)`` cycles per pixel moves with it.

b' is interpolated between the Table 1 pitches with a monotone cubic (PCHIP, continuous slope),
so the capacity has no kinks at the table pitches and the optimum does not stick to them (with
linear interpolation the Eq. 8 optimum piles up just below 1.75 µm). Δs at any pitch and
wavelength comes from a cubic spline of Δs against ``P/λ`` (Δs of aperture × diffraction depends
on the pitch only through ``P/(λN)``), so the optimum is a smooth function of the draws and does
not depend on the grid (tested).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator

from bayescap.studies.sweep import (
    FORMATS_MM,
    _argmax_refined,
    delta_s_vs_pitch,
    nominal_table1,
    sample_table1,
    table1_tonal_range_levels,
)

__all__ = ["SOURCES", "Fig4Bands", "capacity_bands"]

SOURCES = ("table1", "tr_slope", "wavelength")
_REF_NM = 555.0


@dataclass
class Fig4Bands:
    """Draws (axis 0) of b', Δs and C on the pitch grid, and the optimal pitch per draw."""

    pitch_um: np.ndarray
    tr_bits_draws: np.ndarray
    delta_s_draws: np.ndarray
    capacity_draws_bits: np.ndarray
    optimal_pitch_draws_um: np.ndarray
    optimum_at_edge: np.ndarray
    sources: tuple
    table_pitch_um: np.ndarray
    table_tr_bits_draws: np.ndarray
    settings: dict = field(default_factory=dict)

    def band(self, quantity: str = "capacity", level: float = 0.95):
        """(low, median, high) over the draws of ``capacity`` (bits), ``tr`` or ``delta_s``."""
        x = {"capacity": self.capacity_draws_bits, "tr": self.tr_bits_draws, "delta_s": self.delta_s_draws}[quantity]
        a = (1 - level) / 2
        return tuple(np.quantile(x, [a, 0.5, 1 - a], axis=0))

    def optimum_summary(self) -> dict:
        q = np.quantile(self.optimal_pitch_draws_um, [0.025, 0.16, 0.5, 0.84, 0.975])
        return {
            "median_um": float(q[2]),
            "ci68_um": [float(q[1]), float(q[3])],
            "ci95_um": [float(q[0]), float(q[4])],
            "sources": list(self.sources),
            "n_draws": int(self.optimal_pitch_draws_um.size),
            "fraction_at_grid_edge": float(np.mean(self.optimum_at_edge)),
        }


def _delta_s_spline(method: str, f_number: float, lo_um: float, hi_um: float) -> CubicSpline:
    """Δs at 555 nm on a 0.01 µm pitch grid covering [lo, hi]; Δs(P, λ) = spline(P·555/λ)."""
    p = np.linspace(lo_um, hi_um, max(21, int(np.ceil((hi_um - lo_um) / 0.01)) + 1))
    ds, _ = delta_s_vs_pitch(p, f_number=f_number, wavelength_nm=_REF_NM, method=method)
    return CubicSpline(p, ds)


def capacity_bands(
    pitch_um=None,
    *,
    sources=SOURCES,
    n_draws: int = 1000,
    seed=0,
    method: str = "eq9",
    optical_format: str = "1/4in",
    f_number: float = 2.8,
    wavelength_range_nm: tuple[float, float] = (500.0, 600.0),
    exposure_time_s: float = 0.1,
    adc_bits: int = 10,
) -> Fig4Bands:
    """C(P) = s·2^Δs·b' per draw over the named ``sources`` (module docstring); inputs not drawn
    take the paper's values (mid full well, PRNU bound, 0.35 bit/µm, 555 nm)."""
    unknown = set(sources) - set(SOURCES)
    if unknown:
        raise ValueError(f"unknown uncertainty sources {sorted(unknown)}; choose from {SOURCES}")
    if pitch_um is None:
        pitch_um = np.round(np.arange(1.0, 3.0 + 1e-9, 0.005), 10)
    pitch = np.asarray(pitch_um, float)
    if pitch.ndim != 1 or pitch.size < 3 or not np.allclose(np.diff(pitch), pitch[1] - pitch[0]):
        raise ValueError("pitch_um must be a uniform increasing grid of at least 3 pitches")
    if pitch[-1] > 5.2 + 1e-9:
        raise ValueError("pitches above 5.2 µm are outside Table 1; no TR model there")
    rng = np.random.default_rng(seed)
    w_mm, h_mm = FORMATS_MM[optical_format]
    n_pix = w_mm * h_mm * 1e6 / pitch**2

    draws = sample_table1(n_draws, seed=rng)
    if "table1" not in sources:  # the paper's point values in every draw
        nom = nominal_table1()
        draws["full_well_e"] = np.repeat(nom["full_well_e"], n_draws, axis=0)
        draws["prnu_frac"] = np.repeat(nom["prnu_frac"], n_draws, axis=0)
    tp = draws["pitch_um"]
    order = np.argsort(tp)
    tp = tp[order]
    with np.errstate(divide="ignore"):
        tb = np.log2(table1_tonal_range_levels(draws, exposure_time_s=exposure_time_s, adc_bits=adc_bits))[:, order]

    # b' between table pitches: PCHIP per draw; below the smallest: linear with a slope per draw
    inside = pitch >= tp[0]
    tr = np.empty((n_draws, pitch.size))
    tr[:, inside] = PchipInterpolator(tp, tb, axis=1)(np.minimum(pitch[inside], tp[-1]))
    if "tr_slope" in sources:
        x = tp - tp.mean()
        lsq = (tb - tb.mean(axis=1, keepdims=True)) @ x / np.sum(x * x)
        last = (tb[:, 1] - tb[:, 0]) / (tp[1] - tp[0])
        lo, hi = np.minimum(lsq, last), np.maximum(lsq, last)
        slope = lo + (hi - lo) * rng.random(n_draws)
    else:
        slope = np.full(n_draws, 0.35)
    tr[:, ~inside] = tb[:, :1] - slope[:, None] * (tp[0] - pitch[~inside])[None, :]

    if "wavelength" in sources:
        lam = rng.uniform(*wavelength_range_nm, n_draws)
    else:
        lam = np.full(n_draws, _REF_NM)
    scaled = pitch[None, :] * _REF_NM / lam[:, None]
    spline = _delta_s_spline(method, f_number, 0.95 * scaled.min(), 1.05 * scaled.max())
    ds = spline(scaled)

    cap = n_pix[None, :] * np.exp2(ds) * np.maximum(tr, 0.0)
    opt, edge = _argmax_refined(pitch, cap)
    settings = {
        "method": method,
        "optical_format": optical_format,
        "f_number": f_number,
        "wavelength_range_nm": list(wavelength_range_nm) if "wavelength" in sources else [_REF_NM, _REF_NM],
        "tr_interpolation": "PCHIP between Table 1 pitches",
        "tr_slope_below_1p45": "uniform between least-squares and last-segment slope"
        if "tr_slope" in sources
        else "0.35 bit/um (paper)",
        "seed": seed,
    }
    return Fig4Bands(
        pitch_um=pitch,
        tr_bits_draws=tr,
        delta_s_draws=ds,
        capacity_draws_bits=cap,
        optimal_pitch_draws_um=opt,
        optimum_at_edge=edge,
        sources=tuple(sources),
        table_pitch_um=tp,
        table_tr_bits_draws=tb,
        settings=settings,
    )
