"""The spatial frequency response of one slanted edge or MTF table, and its summary figures.

:class:`SFRResult` holds the MTF, its bootstrap replicates and per-channel results;
:func:`_crossing_cy_per_px` (MTF50) and :func:`_sampling_efficiency` summarise a curve as
sfrmat ``findfreq`` and ``sampeff`` do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "SFRResult",
]

#: Half-sampling frequency used by sfrmat ``sampeff`` for the sampling efficiency.
_EFFICIENCY_HALF_SAMPLING_CY_PER_PX = 0.495


@dataclass(frozen=True)
class SFRResult:
    """Spatial frequency response of one slanted edge (or one MTF table).

    Attributes
    ----------
    freq_cy_per_px : (n_freq,) array
        Frequencies in cycles per pixel, measured normal to the edge.
    mtf : (n_freq,) array
        MTF of the primary channel (``channel``).
    mtf_samples : (n_boot, n_freq) array
        Bootstrap replicates of ``mtf`` (shape ``(0, n_freq)`` when not available, e.g.
        for a table read from a file or ``n_boot=0``).
    mtf50_cy_per_px : float
        First crossing of MTF = 0.5 (linear interpolation); NaN if the MTF never drops
        below 0.5 in the reported range.
    mtf50_samples : (n_boot,) array
        MTF50 of every bootstrap replicate.
    edge_angle_deg : float
        Edge angle in degrees, sfrmat convention: angle from the vertical for a
        near-vertical edge, that angle + 90 for a near-horizontal edge (NaN for tables).
    sampling_efficiency : float
        sfrmat ``sampeff``: min(MTF10 frequency / 0.495 cy/px, 1) (fraction, not %).
    warnings : list of str
        Everything flagged during the measurement (also emitted as :class:`MTFWarning`).
    channel : str
        Name of the primary channel: ``"mono"`` for gray data, ``"R"``, ``"G"``, ``"B"``
        or ``"lum"`` for RGB data (default ``"lum"``), the column name for tables.
    mtf_by_channel, mtf50_by_channel_cy_per_px, sampling_efficiency_by_channel : dict
        The same for every analysed channel (bootstrap only for the primary one).
    orientation : str
        ``"vertical"`` or ``"horizontal"`` (edge direction in the input image),
        ``"unknown"`` for tables.
    """

    freq_cy_per_px: np.ndarray
    mtf: np.ndarray
    mtf_samples: np.ndarray
    mtf50_cy_per_px: float
    mtf50_samples: np.ndarray
    edge_angle_deg: float
    sampling_efficiency: float
    warnings: list[str]
    channel: str
    mtf_by_channel: dict[str, np.ndarray] = field(default_factory=dict)
    mtf50_by_channel_cy_per_px: dict[str, float] = field(default_factory=dict)
    sampling_efficiency_by_channel: dict[str, float] = field(default_factory=dict)
    orientation: str = "unknown"
    npol: int | None = None
    nbin: int | None = None
    window: str | None = None
    n_rows_used: int | None = None
    n_phase_cycles: int | None = None
    roi: tuple[int, int, int, int] | None = None
    source: str = ""

    # ---- interpolation -------------------------------------------------------------
    def mtf_at(self, f_cy_per_px: Any, channel: str | None = None) -> np.ndarray:
        """MTF at arbitrary frequencies (cy/px) by linear interpolation.

        Frequencies above the last tabulated frequency are **clamped to the last value**
        (the MTF is *not* assumed to be 0 beyond the measured range), likewise values
        below the first frequency take the first value.  ``channel`` selects another
        entry of ``mtf_by_channel``.  Returns an array of the shape of ``f_cy_per_px``.
        """
        f = np.asarray(f_cy_per_px, dtype=float)
        y = self.mtf if channel is None else self.mtf_by_channel[channel]
        return np.interp(f, self.freq_cy_per_px, y)

    def mtf_samples_at(self, f_cy_per_px: Any) -> np.ndarray:
        """Bootstrap replicates interpolated at ``f_cy_per_px``: shape (n_boot, *f.shape).

        Same clamping rule as :meth:`mtf_at`.
        """
        f = np.asarray(f_cy_per_px, dtype=float)
        out = np.empty((self.mtf_samples.shape[0],) + f.shape)
        for i, s in enumerate(self.mtf_samples):
            out[i] = np.interp(f, self.freq_cy_per_px, s)
        return out

    def mtf_ci(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Pointwise percentile interval of the bootstrap replicates (lower, upper)."""
        if self.mtf_samples.shape[0] == 0:
            nan = np.full_like(self.mtf, np.nan)
            return nan, nan.copy()
        q = 100 * np.array([(1 - level) / 2, (1 + level) / 2])
        lo, hi = np.percentile(self.mtf_samples, q, axis=0)
        return lo, hi

    def mtf50_ci(self, level: float = 0.95) -> tuple[float, float]:
        """Percentile interval of the MTF50 replicates (NaN if unavailable)."""
        s = self.mtf50_samples[np.isfinite(self.mtf50_samples)]
        if s.size == 0:
            return math.nan, math.nan
        lo, hi = np.percentile(s, 100 * np.array([(1 - level) / 2, (1 + level) / 2]))
        return float(lo), float(hi)

    def to_dict(self, include_samples: bool = False) -> dict[str, Any]:
        """JSON-serialisable dictionary (NaN -> None).  Samples only on request."""

        def clean(v: Any) -> Any:
            if isinstance(v, np.ndarray):
                return clean(v.tolist())
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, (float, np.floating)):
                v = float(v)
                return None if not math.isfinite(v) else v
            if isinstance(v, np.integer):
                return int(v)
            return v

        lo, hi = self.mtf_ci()
        lo50, hi50 = self.mtf50_ci()
        d: dict[str, Any] = {
            "channel": self.channel,
            "orientation": self.orientation,
            "edge_angle_deg": self.edge_angle_deg,
            "mtf50_cy_per_px": self.mtf50_cy_per_px,
            "mtf50_ci95_cy_per_px": [lo50, hi50],
            "sampling_efficiency": self.sampling_efficiency,
            "npol": self.npol,
            "nbin": self.nbin,
            "window": self.window,
            "n_rows_used": self.n_rows_used,
            "n_phase_cycles": self.n_phase_cycles,
            "n_boot": int(self.mtf_samples.shape[0]),
            "roi": list(self.roi) if self.roi is not None else None,
            "source": self.source,
            "warnings": list(self.warnings),
            "freq_cy_per_px": self.freq_cy_per_px,
            "mtf": self.mtf,
            "mtf_ci95_low": lo,
            "mtf_ci95_high": hi,
            "mtf_by_channel": self.mtf_by_channel,
            "mtf50_by_channel_cy_per_px": self.mtf50_by_channel_cy_per_px,
            "sampling_efficiency_by_channel": self.sampling_efficiency_by_channel,
        }
        if include_samples:
            d["mtf_samples"] = self.mtf_samples
            d["mtf50_samples"] = self.mtf50_samples
        return clean(d)


# --------------------------------------------------------------------------------------
# Summary figures of an MTF curve (sfrmat conventions)
# --------------------------------------------------------------------------------------
def _crossing_cy_per_px(freq: np.ndarray, mtf: np.ndarray, level: float) -> np.ndarray:
    """First crossing of ``level`` (sfrmat ``findfreq``), vectorised over leading axes.

    Linear interpolation between the last point >= level and the first point < level.
    NaN where the curve never drops below ``level``.
    """
    mtf = np.atleast_2d(mtf)
    below = mtf < level
    has = below.any(axis=-1)
    k = np.argmax(below, axis=-1)
    ok = has & (k >= 1)
    k1 = np.clip(k, 1, None)
    y0 = np.take_along_axis(mtf, (k1 - 1)[:, None], -1)[:, 0]
    y1 = np.take_along_axis(mtf, k1[:, None], -1)[:, 0]
    f0 = freq[k1 - 1]
    df = freq[k1] - f0
    with np.errstate(divide="ignore", invalid="ignore"):
        f = f0 + (y0 - level) / (y0 - y1) * df
    return np.where(ok, f, np.nan)


def _sampling_efficiency(freq: np.ndarray, mtf: np.ndarray) -> float:
    """sfrmat ``sampeff``: min(f(MTF=0.1) / 0.495, 1); f = last frequency if no crossing."""
    f10 = float(_crossing_cy_per_px(freq, mtf, 0.1)[0])
    if not math.isfinite(f10):
        f10 = float(freq[-1])
    f10 = min(max(f10, 0.0), _EFFICIENCY_HALF_SAMPLING_CY_PER_PX)
    return min(f10 / _EFFICIENCY_HALF_SAMPLING_CY_PER_PX, 1.0)
