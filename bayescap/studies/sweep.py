"""Image information capacity versus pixel size (Tisse et al. 2008, Fig. 4), with uncertainty.

The study: a fixed imaging area (1/4-inch optical format: 3.6 mm × 2.7 mm, the 4:3 area of
4.5 mm diagonal; the paper's own 1/4-inch sensors, 2048 × 1536 pixels of 1.75 µm, measure
3.58 × 2.69 mm), an ideal diffraction-limited lens (f/2.8, λ = 555 nm) and ideal square pixels
(fill factor 1). For each pitch P:

* number of pixels ``s = W·H/P²`` (continuous, so that the optimum is not quantised by the
  integer array size);
* MTF loss Δs (Eq. 9 by default, Eq. 8 over the Nyquist square on request) of pixel aperture ×
  lens;
* tonal range TR (Eq. 7, 8-bit-equivalent, :func:`bayescap.physics.capacity.tonal_range`) of the Table 1
  pixels, **over the sensor's dynamic range** (signal from the dark floor σ(0) to the full well,
  one grey level = full well/256) at Δt = 100 ms, 25 °C, 10-bit ADC, read noise and DSNU
  neglected; b' = log2 TR is interpolated linearly in pitch between the Table 1 pitches and, below
  1.45 µm, extrapolated with the paper's trend (−0.35 bit/µm);
* capacity ``C = s · 2^Δs · b'`` (Eq. 6).

Beyond the paper, the Table 1 parameters are drawn uniformly within their printed ranges (full
well between its bounds, PRNU between 0 and its bound; seeded, vectorised over draws), which
gives C(P) with credible bands and the distribution of the optimal pitch.

Command line (registered by ``bayescap.cli``)::

    bayescap sweep pixel-size --format 1/4in --f-number 2.8 [--json] [--seed N] [--draws N]
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayescap.physics.capacity import (
    effective_pixels,
    information_capacity_bits,
    mtf_loss_bits,
    mtf_loss_bits_eq8,
    tonal_range,
)
from bayescap.physics.optics import (
    OPTICAL_FORMATS,
    PixelAperture,
    default_mtf,
    mtf50_cy_per_px,
)
from bayescap.physics.photometry import (
    mpe30_lux_s,
    pixel_noise_coefficients,
    snr_vs_exposure_db,
)
from bayescap.physics.table1 import PixelSpec, load_table1

__all__ = [
    "FORMATS_MM",
    "PAPER_TR_TREND_BITS_PER_UM",
    "sample_table1",
    "nominal_table1",
    "table1_tonal_range_levels",
    "interpolate_tr_bits",
    "delta_s_vs_pitch",
    "PixelSizeSweep",
    "pixel_size_sweep",
    "snr_curves_table1",
    "farrell_tradeoff",
]


#: imaging area (width, height) in mm of the optical formats (4:3), keyed "1/4in" etc.
FORMATS_MM = {f"{k}in": v for k, v in OPTICAL_FORMATS.items() if k[0].isdigit()}


#: Section 3: below 1.45 µm "TR continues to decrease ... at approximately 0.35 bit/µm"
PAPER_TR_TREND_BITS_PER_UM = 0.35


def _table_columns(specs, temperature_c):
    return (
        np.array([s.pitch_um for s in specs]),
        np.array([s.full_well_min_e for s in specs]),
        np.array([s.full_well_max_e for s in specs]),
        np.array([s.sensitivity_e_per_lux_s for s in specs]),
        np.array([s.dark_current_e_per_s(temperature_c) for s in specs]),
        np.array([s.prnu_max_frac for s in specs]),
    )


def sample_table1(
    n_draws: int, *, seed=None, specs: list[PixelSpec] | None = None, temperature_c: float = 25.0
) -> dict:
    """Draw Table 1 pixel parameters uniformly within the printed ranges.

    Full well ~ U[min, max]; PRNU ~ U[0, bound] (the table prints "< bound"); sensitivity and
    dark current (at ``temperature_c``) are single printed values and stay fixed. Returns arrays
    of shape ``(n_draws, n_pixels)`` plus ``pitch_um`` of shape ``(n_pixels,)``.
    """
    if n_draws < 1:
        raise ValueError(f"n_draws must be >= 1, got {n_draws}")
    specs = load_table1() if specs is None else specs
    pitch, fw_lo, fw_hi, sens, dark, prnu_hi = _table_columns(specs, temperature_c)
    rng = np.random.default_rng(seed)
    u = rng.random((2, n_draws, pitch.size))
    return {
        "pitch_um": pitch,
        "full_well_e": fw_lo + (fw_hi - fw_lo) * u[0],
        "prnu_frac": prnu_hi * u[1],
        "sensitivity_e_per_lux_s": np.broadcast_to(sens, (n_draws, pitch.size)).copy(),
        "dark_current_e_per_s": np.broadcast_to(dark, (n_draws, pitch.size)).copy(),
    }


def nominal_table1(*, specs: list[PixelSpec] | None = None, temperature_c: float = 25.0) -> dict:
    """The paper's point values: full well at the middle of its range, PRNU at its bound.

    Same layout as :func:`sample_table1` with one draw.
    """
    specs = load_table1() if specs is None else specs
    pitch, fw_lo, fw_hi, sens, dark, prnu_hi = _table_columns(specs, temperature_c)
    return {
        "pitch_um": pitch,
        "full_well_e": (0.5 * (fw_lo + fw_hi))[None],
        "prnu_frac": prnu_hi[None],
        "sensitivity_e_per_lux_s": sens[None],
        "dark_current_e_per_s": dark[None],
    }


def table1_tonal_range_levels(params: dict, *, exposure_time_s: float = 0.1, adc_bits: int = 10, exposure_lux_s=None):
    """TR (Eq. 7, grey levels on the 8-bit-equivalent scale) of each Table 1 pixel and draw.

    ``exposure_lux_s=None`` (default): over the sensor's dynamic range, from the dark floor to
    the full well, one grey level = full well / 256 (``capacity.tonal_range(coeffs, FW)``).
    ``exposure_lux_s=H``: the scene's brightest point gets exposure H; the integral stops at
    ``S_top = min(sensitivity · H, FW)`` on the same grey scale (FW/256 e⁻ per level), so
    TR grows with H until the pixel saturates (the paper's Fig. 8(a) view).
    """
    fw = np.asarray(params["full_well_e"], float)
    coeffs = pixel_noise_coefficients(
        full_well_e=fw,
        dark_current_e_per_s=params["dark_current_e_per_s"],
        prnu_frac=params["prnu_frac"],
        exposure_time_s=exposure_time_s,
        adc_bits=adc_bits,
    )
    if exposure_lux_s is None:
        return tonal_range(coeffs, fw)
    s_top = np.minimum(np.asarray(params["sensitivity_e_per_lux_s"], float) * exposure_lux_s, fw)
    levels = 256.0 * s_top / fw
    return tonal_range(coeffs, s_top, n_levels=levels)


def interpolate_tr_bits(
    pitch_um, table_pitch_um, tr_bits, *, trend_bits_per_um: float | None = PAPER_TR_TREND_BITS_PER_UM
):
    """b'(P) = log2 TR at arbitrary pitches from its values at the Table 1 pitches.

    Linear in pitch between table pitches (vectorised over a leading draws axis of
    ``tr_bits``: shape ``(..., n_table)`` → ``(..., n_pitch)``). Below the smallest table pitch
    b' falls linearly with slope ``trend_bits_per_um`` (the paper's 0.35 bit/µm); with ``None``
    the slope is, per draw, the least-squares slope of b' over the table pitches. Pitches above
    the largest table pitch are refused.
    """
    p = np.asarray(pitch_um, float)
    tp = np.asarray(table_pitch_um, float)
    order = np.argsort(tp)
    tp = tp[order]
    tb = np.asarray(tr_bits, float)[..., order]
    if np.any(p > tp[-1] + 1e-12):
        raise ValueError(f"pitches above {tp[-1]} µm are outside Table 1; no TR model there")
    # interpolation matrix (shared by all draws): W[i, j] weight of table pitch j at p[i]
    w = np.zeros((p.size, tp.size))
    inside = p >= tp[0]
    pi = np.clip(p, tp[0], tp[-1])
    j = np.clip(np.searchsorted(tp, pi, side="right") - 1, 0, tp.size - 2)
    t = (pi - tp[j]) / (tp[j + 1] - tp[j])
    rows = np.arange(p.size)
    w[rows, j] = 1.0 - t
    w[rows, j + 1] = t
    out = tb @ w.T
    if np.any(~inside):
        if trend_bits_per_um is None:
            x = tp - tp.mean()
            slope = (tb - tb.mean(axis=-1, keepdims=True)) @ x / np.sum(x * x)
        else:
            slope = np.asarray(trend_bits_per_um, float)
        below = (tp[0] - p)[~inside]
        base = tb[..., :1]
        out[..., ~inside] = base - np.asarray(slope)[..., None] * below
    return out


def delta_s_vs_pitch(
    pitch_um,
    *,
    f_number: float | None = 2.8,
    wavelength_nm: float = 555.0,
    fill_factor: float = 1.0,
    method: str = "eq9",
    crosstalk=None,
):
    """Δs (bits) of pixel aperture × diffraction lens (× optional crosstalk) at each pitch.

    ``method``: ``"eq9"`` (:func:`bayescap.physics.capacity.mtf_loss_bits`, radial) or ``"eq8"``
    (:func:`bayescap.physics.capacity.mtf_loss_bits_eq8`, 2-D over the Nyquist square).
    Returns ``(delta_s_bits, band_cut_bits)`` arrays.
    """
    if method not in ("eq8", "eq9"):
        raise ValueError(f"method must be 'eq8' or 'eq9', got {method!r}")
    ds, cut = [], []
    for p in np.atleast_1d(np.asarray(pitch_um, float)):
        m = default_mtf(
            fill_factor=fill_factor, f_number=f_number, wavelength_nm=wavelength_nm, pixel_pitch_um=float(p)
        )
        if crosstalk is not None:
            m = type(m)(components=m.components + (crosstalk,))
        r = mtf_loss_bits(m) if method == "eq9" else mtf_loss_bits_eq8(m)
        ds.append(float(r.delta_s_bits))
        cut.append(r.band_cut_bits)
    return np.array(ds), np.array(cut)


def _q(x, qs, axis=0):
    return np.quantile(x, qs, axis=axis)


def _argmax_refined(pitch, c):
    """Argmax along the last axis, refined by a parabola through the neighbours (uniform grid)."""
    i = np.argmax(c, axis=-1)
    n = pitch.size
    h = pitch[1] - pitch[0]
    inner = (i > 0) & (i < n - 1)
    ii = np.clip(i, 1, n - 2)
    take = lambda k: np.take_along_axis(c, (ii + k)[..., None], axis=-1)[..., 0]
    y0, y1, y2 = take(-1), take(0), take(1)
    den = y0 - 2 * y1 + y2
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(inner & (den < 0), 0.5 * (y0 - y2) / den, 0.0)
    return pitch[i] + np.clip(off, -0.5, 0.5) * h * inner, ~inner


@dataclass
class PixelSizeSweep:
    """Result of :func:`pixel_size_sweep` (arrays over the pitch grid; draws on axis 0)."""

    pitch_um: np.ndarray
    n_pixels: np.ndarray
    delta_s_bits: np.ndarray
    band_cut_bits: np.ndarray
    tr_bits_nominal: np.ndarray
    capacity_nominal_bits: np.ndarray
    tr_bits_draws: np.ndarray
    capacity_draws_bits: np.ndarray
    optimal_pitch_draws_um: np.ndarray
    optimum_at_edge: np.ndarray
    table_pitch_um: np.ndarray
    table_tr_bits_draws: np.ndarray
    table_tr_bits_nominal: np.ndarray
    settings: dict = field(default_factory=dict)

    @property
    def effective_pixels(self):
        return effective_pixels(self.n_pixels, self.delta_s_bits)

    @property
    def effective_pixels_optimum_um(self) -> float:
        return float(_argmax_refined(self.pitch_um, self.effective_pixels)[0])

    @property
    def nominal_optimum_um(self) -> float:
        return float(_argmax_refined(self.pitch_um, self.capacity_nominal_bits)[0])

    def optimal_pitch_summary(self) -> dict:
        x = self.optimal_pitch_draws_um
        q = _q(x, [0.025, 0.16, 0.5, 0.84, 0.975])
        return {
            "median_um": float(q[2]),
            "ci68_um": [float(q[1]), float(q[3])],
            "ci95_um": [float(q[0]), float(q[4])],
            "mean_um": float(np.mean(x)),
            "sd_um": float(np.std(x, ddof=1)) if x.size > 1 else 0.0,
            "fraction_at_grid_edge": float(np.mean(self.optimum_at_edge)),
            "n_draws": int(x.size),
        }

    def tr_difference_bits(self, p_small=1.45, p_large=5.2) -> dict:
        """b'(p_large) − b'(p_small) at two Table 1 pitches (the paper: ≈ 1.3 bit)."""
        i = int(np.argmin(np.abs(self.table_pitch_um - p_small)))
        j = int(np.argmin(np.abs(self.table_pitch_um - p_large)))
        d = self.table_tr_bits_draws[:, j] - self.table_tr_bits_draws[:, i]
        q = _q(d, [0.025, 0.5, 0.975])
        return {
            "nominal_bits": float(self.table_tr_bits_nominal[j] - self.table_tr_bits_nominal[i]),
            "median_bits": float(q[1]),
            "ci95_bits": [float(q[0]), float(q[2])],
        }

    def rows(self, pitches_um=None) -> list[dict]:
        """Table rows at selected pitches (default: 1.0, 1.2 and the Table 1 pitches)."""
        if pitches_um is None:
            pitches_um = sorted({1.0, 1.2, *[float(p) for p in self.table_pitch_um]})
        out = []
        for p in pitches_um:
            k = int(np.argmin(np.abs(self.pitch_um - p)))
            cq = _q(self.capacity_draws_bits[:, k], [0.025, 0.5, 0.975])
            tq = _q(self.tr_bits_draws[:, k], [0.025, 0.5, 0.975])
            out.append(
                {
                    "pitch_um": float(self.pitch_um[k]),
                    "n_pixels": float(self.n_pixels[k]),
                    "delta_s_bits": float(self.delta_s_bits[k]),
                    "band_cut_bits": float(self.band_cut_bits[k]),
                    "effective_pixels": float(self.effective_pixels[k]),
                    "tr_bits_nominal": float(self.tr_bits_nominal[k]),
                    "tr_bits_median": float(tq[1]),
                    "tr_bits_ci95": [float(tq[0]), float(tq[2])],
                    "capacity_nominal_bits": float(self.capacity_nominal_bits[k]),
                    "capacity_median_bits": float(cq[1]),
                    "capacity_ci95_bits": [float(cq[0]), float(cq[2])],
                    "tr_extrapolated": bool(self.pitch_um[k] < self.table_pitch_um.min() - 1e-9),
                }
            )
        return out

    def to_dict(self) -> dict:
        return {
            "study": "pixel-size",
            "settings": self.settings,
            "optimal_pitch": self.optimal_pitch_summary(),
            "optimal_pitch_nominal_um": self.nominal_optimum_um,
            "effective_pixels_optimum_um": self.effective_pixels_optimum_um,
            "tr_difference_1p45_to_5p2": self.tr_difference_bits(),
            "rows": self.rows(),
        }


def pixel_size_sweep(
    pitch_um=None,
    *,
    optical_format: str = "1/4in",
    f_number: float = 2.8,
    wavelength_nm: float = 555.0,
    n_draws: int = 2000,
    seed=0,
    method: str = "eq9",
    tr_trend_bits_per_um: float | None = PAPER_TR_TREND_BITS_PER_UM,
    exposure_time_s: float = 0.1,
    temperature_c: float = 25.0,
    adc_bits: int = 10,
    exposure_lux_s=None,
    specs: list[PixelSpec] | None = None,
) -> PixelSizeSweep:
    """Fig. 4: capacity C (bits) against pixel pitch on a fixed optical format, with draws.

    Parameters
    ----------
    pitch_um : pitch grid (µm), uniform; default 1.00–5.20 µm in 0.01 µm steps.
    optical_format : key of :data:`FORMATS_MM` (``"1/4in"`` = 3.6 × 2.7 mm).
    f_number, wavelength_nm : ideal diffraction-limited lens.
    n_draws, seed : Table 1 draws (:func:`sample_table1`); the optimum is found per draw.
    method : ``"eq9"`` (paper's Fig. 4) or ``"eq8"``.
    tr_trend_bits_per_um : slope of b' below 1.45 µm (None: per-draw least-squares slope).
    exposure_time_s, temperature_c, adc_bits : where TR is evaluated (dark charge D·Δt at
        that temperature; quantization K = FW/2ⁿ).
    exposure_lux_s : None for TR over the dynamic range (default), or an exposure H (lux·s)
        for TR at that exposure (see :func:`table1_tonal_range_levels`).
    """
    if optical_format not in FORMATS_MM:
        raise ValueError(f"unknown optical format {optical_format!r}; choose one of {sorted(FORMATS_MM)}")
    width_mm, height_mm = FORMATS_MM[optical_format]
    specs = load_table1() if specs is None else specs
    if pitch_um is None:
        pitch_um = np.round(np.arange(1.0, 5.2 + 1e-9, 0.01), 10)
    pitch = np.asarray(pitch_um, float)
    if pitch.ndim != 1 or pitch.size < 3 or np.any(np.diff(pitch) <= 0):
        raise ValueError("pitch_um must be an increasing 1-D grid of at least 3 pitches")
    if not np.allclose(np.diff(pitch), pitch[1] - pitch[0], rtol=1e-6, atol=1e-9):
        raise ValueError("pitch_um must be uniformly spaced (the optimum is refined by a parabola)")
    n_pix = (width_mm * 1e3) * (height_mm * 1e3) / pitch**2
    ds, cut = delta_s_vs_pitch(pitch, f_number=f_number, wavelength_nm=wavelength_nm, method=method)
    tr_kw = dict(exposure_time_s=exposure_time_s, adc_bits=adc_bits, exposure_lux_s=exposure_lux_s)
    nom = nominal_table1(specs=specs, temperature_c=temperature_c)
    tp = nom["pitch_um"]
    with np.errstate(divide="ignore"):
        tb_nom = np.log2(table1_tonal_range_levels(nom, **tr_kw))[0]
        draws = sample_table1(n_draws, seed=seed, specs=specs, temperature_c=temperature_c)
        tb = np.log2(table1_tonal_range_levels(draws, **tr_kw))
    tr_nom = interpolate_tr_bits(pitch, tp, tb_nom, trend_bits_per_um=tr_trend_bits_per_um)
    tr = interpolate_tr_bits(pitch, tp, tb, trend_bits_per_um=tr_trend_bits_per_um)
    cap_nom = information_capacity_bits(n_pix, ds, bits_per_pixel=np.maximum(tr_nom, 0.0))
    cap = information_capacity_bits(n_pix, ds, bits_per_pixel=np.maximum(tr, 0.0))
    opt, edge = _argmax_refined(pitch, cap)
    settings = {
        "optical_format": optical_format,
        "imaging_area_mm": [width_mm, height_mm],
        "f_number": f_number,
        "wavelength_nm": wavelength_nm,
        "fill_factor": 1.0,
        "delta_s_method": method,
        "tr_convention": ("dynamic_range" if exposure_lux_s is None else f"exposure {exposure_lux_s} lux·s"),
        "tr_grey_scale": "8-bit equivalent: one grey level = full well / 256",
        "tr_trend_below_1p45_bits_per_um": (
            "per-draw least squares" if tr_trend_bits_per_um is None else tr_trend_bits_per_um
        ),
        "exposure_time_s": exposure_time_s,
        "temperature_c": temperature_c,
        "adc_bits": adc_bits,
        "read_noise_e": 0.0,
        "dsnu_e": 0.0,
        "draws": {
            "n": n_draws,
            "seed": seed,
            "full_well": "uniform within the Table 1 range",
            "prnu": "uniform in [0, bound]",
        },
        "nominal": "full well at mid-range, PRNU at its bound",
        "pitch_grid_um": [float(pitch[0]), float(pitch[-1]), float(pitch[1] - pitch[0])],
    }
    return PixelSizeSweep(
        pitch_um=pitch,
        n_pixels=n_pix,
        delta_s_bits=ds,
        band_cut_bits=cut,
        tr_bits_nominal=tr_nom,
        capacity_nominal_bits=cap_nom,
        tr_bits_draws=tr,
        capacity_draws_bits=cap,
        optimal_pitch_draws_um=opt,
        optimum_at_edge=edge,
        table_pitch_um=tp,
        table_tr_bits_draws=tb,
        table_tr_bits_nominal=tb_nom,
        settings=settings,
    )


def snr_curves_table1(
    h_lux_s,
    *,
    specs: list[PixelSpec] | None = None,
    exposure_time_s: float = 0.1,
    temperature_c: float = 25.0,
    adc_bits: int = 10,
) -> dict:
    """Fig. 2(b): SNR (dB) against exposure H (lux·s) of every Table 1 pixel (nominal values).

    Returns ``{pitch_um: snr_db array}``; NaN above the full well.
    """
    specs = load_table1() if specs is None else specs
    out = {}
    for s in specs:
        out[s.pitch_um] = snr_vs_exposure_db(
            h_lux_s,
            sensitivity_e_per_lux_s=s.sensitivity_e_per_lux_s,
            full_well_e=s.full_well_mid_e,
            dark_current_e_per_s=s.dark_current_e_per_s(temperature_c),
            prnu_frac=s.prnu_max_frac,
            exposure_time_s=exposure_time_s,
            adc_bits=adc_bits,
        )
    return out


def farrell_tradeoff(
    *,
    specs: list[PixelSpec] | None = None,
    f_number: float | None = 2.8,
    wavelength_nm: float = 555.0,
    exposure_time_s: float = 0.1,
    temperature_c: float = 25.0,
    adc_bits: int = 10,
) -> list[dict]:
    """MPE30 (lux·s for SNR = 30 dB) and MTF50 of each Table 1 pixel (Farrell et al.).

    MTF50 is given for the detector alone (ideal square pixel: 0.603 cy/px at every pitch) and
    for detector × diffraction lens, in cy/px and cy/mm. The trade-off curve is MTF50 (cy/mm)
    against 1/MPE30.
    """
    specs = load_table1() if specs is None else specs
    rows = []
    det50 = mtf50_cy_per_px(PixelAperture())
    for s in specs:
        mpe = float(
            mpe30_lux_s(
                sensitivity_e_per_lux_s=s.sensitivity_e_per_lux_s,
                full_well_e=s.full_well_mid_e,
                dark_current_e_per_s=s.dark_current_e_per_s(temperature_c),
                prnu_frac=s.prnu_max_frac,
                exposure_time_s=exposure_time_s,
                adc_bits=adc_bits,
            )
        )
        sys50 = (
            mtf50_cy_per_px(default_mtf(f_number=f_number, wavelength_nm=wavelength_nm, pixel_pitch_um=s.pitch_um))
            if f_number
            else det50
        )
        rows.append(
            {
                "pitch_um": s.pitch_um,
                "mpe30_lux_s": mpe,
                "inv_mpe30_per_lux_s": 1.0 / mpe,
                "mtf50_detector_cy_per_px": det50,
                "mtf50_detector_cy_per_mm": det50 / (s.pitch_um * 1e-3),
                "mtf50_system_cy_per_px": sys50,
                "mtf50_system_cy_per_mm": sys50 / (s.pitch_um * 1e-3),
            }
        )
    return rows


def _format_table(res: PixelSizeSweep) -> str:
    o = res.optimal_pitch_summary()
    st = res.settings
    lines = [
        f"Image information capacity vs pixel pitch: {st['optical_format']} "
        f"({st['imaging_area_mm'][0]} x {st['imaging_area_mm'][1]} mm), ideal f/{st['f_number']} lens "
        f"at {st['wavelength_nm']} nm, Delta-s by {st['delta_s_method']}, TR over "
        f"{st['tr_convention']} (8-bit equivalent), {st['draws']['n']} Table 1 draws (seed {st['draws']['seed']})",
        "",
        f"{'pitch um':>8} {'pixels M':>9} {'Ds bits':>8} {'eff. M':>7} {'TR bits [95%]':>22} {'C Mbit [95%]':>24}",
    ]
    for r in res.rows():
        mark = "*" if r["tr_extrapolated"] else " "
        lines.append(
            f"{r['pitch_um']:8.2f} {r['n_pixels'] / 1e6:9.3f} {r['delta_s_bits']:8.3f} "
            f"{r['effective_pixels'] / 1e6:7.3f} {r['tr_bits_median']:6.3f} "
            f"[{r['tr_bits_ci95'][0]:5.3f}, {r['tr_bits_ci95'][1]:5.3f}]{mark} "
            f"{r['capacity_median_bits'] / 1e6:7.3f} [{r['capacity_ci95_bits'][0] / 1e6:6.3f}, "
            f"{r['capacity_ci95_bits'][1] / 1e6:6.3f}]"
        )
    d = res.tr_difference_bits()
    lines += [
        "  (* TR extrapolated below 1.45 um with the trend)",
        "",
        f"optimal pitch: median {o['median_um']:.3f} um, 68% [{o['ci68_um'][0]:.3f}, {o['ci68_um'][1]:.3f}], "
        f"95% [{o['ci95_um'][0]:.3f}, {o['ci95_um'][1]:.3f}] um (nominal Table 1 values: "
        f"{res.nominal_optimum_um:.3f} um; effective pixels alone: {res.effective_pixels_optimum_um:.3f} um; "
        f"paper: ~1.45 um)",
        f"TR difference 1.45 -> 5.2 um: {d['median_bits']:.3f} bit, 95% [{d['ci95_bits'][0]:.3f}, "
        f"{d['ci95_bits'][1]:.3f}] (nominal {d['nominal_bits']:.3f}; paper: ~1.3 bit)",
    ]
    return "\n".join(lines)
