"""Frame-level sensor simulator: pixel arrays from a known sensor truth, and contract CSVs.

Per frame and pixel (EMVA 1288's linear camera model, with the fixed patterns of Eq. 1):

    e   = Poisson(QE·μp·(1 + PRNU map)) + Poisson(D·t) + DSNU map        [e⁻]
    e   = min(e, full well of the pixel)                                  (the well clips)
    y   = black + (r(e) + N(0, σ_read²)) / K                              [DN]
    y   = clip(round(y), 0, 2^bits − 1)                                   (quantization, ADC)

The PRNU, DSNU and full-well maps are fixed for a simulated sensor (drawn once from its seed);
shot and read noise are drawn anew for every frame. Rounding without dither gives the 1/12 DN²
quantization variance.

The response ``r`` of the charge-to-voltage conversion is linear by default (``r(e) = e``);
``response_nonlinearity = c`` makes it compressive, ``r(e) = e / (1 + b·e/e_top)`` with
``b = c/(1 − c)``, so that the output falls short of the linear response by the fraction ``c`` at
``e_top = (ADC maximum − black)·K`` (the charge that would reach the ADC maximum if linear). It
acts on the collected charge, before the read noise.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from bayescap.io.ptc_csv import PTCData, read_ptc_csv, write_ptc_csv

__all__ = ["SensorTruth", "simulate_frames", "simulate_ptc", "exposure_series"]


@dataclass(frozen=True)
class SensorTruth:
    """The true parameters of a simulated sensor (units in the names)."""

    conversion_gain_e_per_dn: float
    read_noise_e: float
    full_well_e: float
    dark_current_e_per_s: float = 0.0
    quantum_efficiency: float = 0.6
    prnu_frac: float = 0.0
    dsnu_e: float = 0.0
    full_well_spread_frac: float = 0.0
    adc_bits: int = 12
    black_level_dn: float = 64.0
    response_nonlinearity: float = 0.0

    def response_e(self, e):
        """The charge-to-voltage response r(e) in e⁻ (module docstring): e itself when linear."""
        c = self.response_nonlinearity
        if c == 0.0:
            return e
        e_top = (self.adc_max_dn - self.black_level_dn) * self.conversion_gain_e_per_dn
        return e / (1.0 + (c / (1.0 - c)) * e / e_top)

    @property
    def adc_max_dn(self) -> float:
        return float(2**self.adc_bits - 1)

    @property
    def clip_charge_e(self) -> float:
        """Charge at which the output clips: the full well or the ADC maximum, whichever first
        (what bayescap reports as ``full_well_e``)."""
        return float(min(self.full_well_e, (self.adc_max_dn - self.black_level_dn) * self.conversion_gain_e_per_dn))

    @property
    def adc_clips_first(self) -> bool:
        return self.full_well_e > (self.adc_max_dn - self.black_level_dn) * self.conversion_gain_e_per_dn

    def to_dict(self):
        d = asdict(self)
        d["clip_charge_e"] = self.clip_charge_e
        return d


class _FixedPattern:
    def __init__(self, truth: SensorTruth, shape, rng):
        self.prnu = 1.0 + truth.prnu_frac * rng.standard_normal(shape) if truth.prnu_frac > 0 else None
        self.dsnu = truth.dsnu_e * rng.standard_normal(shape) if truth.dsnu_e > 0 else None
        if truth.full_well_spread_frac > 0:
            self.fw = truth.full_well_e * (1.0 + truth.full_well_spread_frac * rng.standard_normal(shape))
        else:
            self.fw = np.full(shape, float(truth.full_well_e))


def _frames(truth: SensorTruth, fp: _FixedPattern, photons, t_s, n, shape, rng):
    """n frames (n, *shape) in DN at mean photons per pixel ``photons`` and exposure ``t_s``."""
    lam = truth.quantum_efficiency * photons
    lam_map = lam * fp.prnu if fp.prnu is not None else np.full(shape, lam)
    lam_map = np.maximum(lam_map, 0.0)
    out = np.empty((n,) + tuple(shape))
    for i in range(n):
        e = rng.poisson(lam_map).astype(float)
        if truth.dark_current_e_per_s > 0 and t_s > 0:
            e += rng.poisson(truth.dark_current_e_per_s * t_s, size=shape)
        if fp.dsnu is not None:
            e += fp.dsnu
        e = truth.response_e(np.minimum(e, fp.fw))
        y = (
            truth.black_level_dn
            + (e + truth.read_noise_e * rng.standard_normal(shape)) / truth.conversion_gain_e_per_dn
        )
        out[i] = np.clip(np.floor(y + 0.5), 0.0, truth.adc_max_dn)
    return out


def simulate_frames(truth: SensorTruth, photons_per_pixel, exposure_time_s, *, shape=(128, 128), n_frames=2, seed=None):
    """Bright and dark frame stacks for one exposure level: (bright (n, H, W), dark (n, H, W))."""
    rng = np.random.default_rng(seed)
    fp = _FixedPattern(truth, shape, rng)
    b = _frames(truth, fp, float(photons_per_pixel), float(exposure_time_s), n_frames, shape, rng)
    d = _frames(truth, fp, 0.0, float(exposure_time_s), n_frames, shape, rng)
    return b, d


def _pair_stats(a, b):
    """Mean and temporal variance of a frame pair (EMVA 1288: (mean((A−B)²) − (mean A − mean B)²)/2)."""
    diff = a - b
    return 0.5 * (a.mean() + b.mean()), 0.5 * (np.mean(diff * diff) - diff.mean() ** 2)


def exposure_series(
    truth: SensorTruth, n_levels=50, *, max_fraction=1.15, min_fraction=0.002, t_max_s=0.02, spacing="linear"
):
    """Photons per pixel and exposure times of an exposure sweep at constant illumination,
    reaching ``max_fraction`` of the clip charge (values > 1 include saturated rows)."""
    top = max_fraction * truth.clip_charge_e / truth.quantum_efficiency
    if spacing == "log":
        frac = np.geomspace(min_fraction, 1.0, n_levels)
    else:
        frac = np.linspace(min_fraction, 1.0, n_levels)
    photons = top * frac
    t = t_max_s * frac
    return photons, t


def simulate_ptc(
    truth: SensorTruth,
    *,
    photons_per_pixel=None,
    exposure_time_s=None,
    n_levels=50,
    shape=(100, 100),
    spatial_frames: int = 0,
    spatial_every: int = 0,
    seed=None,
    include_photons=True,
    include_frac_saturated=True,
    path=None,
    metadata=None,
    max_fraction=1.15,
) -> PTCData:
    """Simulate a photon-transfer series frame by frame and return it as PTCData.

    With ``spatial_frames = L ≥ 1`` and ``spatial_every = k``, every k-th level also carries the
    spatial variances of L-frame averages (bright and dark); L = 1 and 2 use the pair's own frames
    (the first frame; the pair's average), L > 2 frames beyond the pair. If ``path`` is given, the contract
    CSV is written there (atomically) and read back, so the result is exactly what a user's
    file would give.
    """
    rng = np.random.default_rng(seed)
    if photons_per_pixel is None:
        photons_per_pixel, exposure_time_s = exposure_series(truth, n_levels, max_fraction=max_fraction)
    photons_per_pixel = np.asarray(photons_per_pixel, float)
    exposure_time_s = np.broadcast_to(np.asarray(exposure_time_s, float), photons_per_pixel.shape)
    fp = _FixedPattern(truth, shape, rng)
    cols = {
        k: []
        for k in ("exposure_time_s", "mean_dn", "temporal_var_dn2", "dark_mean_dn", "dark_temporal_var_dn2", "n_pixels")
    }
    extra = {
        "photons_per_pixel": [],
        "frac_saturated": [],
        "spatial_var_dn2": [],
        "dark_spatial_var_dn2": [],
        "n_frames": [],
    }
    npx = int(np.prod(shape))
    for i, (mu_p, t) in enumerate(zip(photons_per_pixel, exposure_time_s)):
        spatial = spatial_frames >= 1 and spatial_every and i % spatial_every == 0
        L = spatial_frames if spatial else 2
        b = _frames(truth, fp, mu_p, t, max(L, 2), shape, rng)
        d = _frames(truth, fp, 0.0, t, max(L, 2), shape, rng)
        m, v = _pair_stats(b[0], b[1])
        dm, dv = _pair_stats(d[0], d[1])
        cols["exposure_time_s"].append(t)
        cols["mean_dn"].append(m)
        cols["temporal_var_dn2"].append(max(v, 0.0))
        cols["dark_mean_dn"].append(dm)
        cols["dark_temporal_var_dn2"].append(max(dv, 0.0))
        cols["n_pixels"].append(npx)
        extra["photons_per_pixel"].append(mu_p)
        extra["frac_saturated"].append(float(np.mean(b[:2] >= truth.adc_max_dn)))
        if spatial:
            # the average of the first L frames (L = 1: the pair's first frame itself)
            extra["spatial_var_dn2"].append(float(b[:L].mean(axis=0).var(ddof=1)))
            extra["dark_spatial_var_dn2"].append(float(d[:L].mean(axis=0).var(ddof=1)))
            extra["n_frames"].append(L)
        else:
            extra["spatial_var_dn2"].append(np.nan)
            extra["dark_spatial_var_dn2"].append(np.nan)
            extra["n_frames"].append(np.nan)
    out = {k: np.asarray(v, float) for k, v in cols.items()}
    if include_photons:
        out["photons_per_pixel"] = np.asarray(extra["photons_per_pixel"])
    if include_frac_saturated:
        out["frac_saturated"] = np.asarray(extra["frac_saturated"])
    if spatial_frames >= 1 and spatial_every:
        for k in ("spatial_var_dn2", "dark_spatial_var_dn2", "n_frames"):
            out[k] = np.asarray(extra[k])
    md = {"sensor": "simulated", "adc_bits": truth.adc_bits, "width_px": 1920, "height_px": 1080}
    md.update(metadata or {})
    if path is not None:
        write_ptc_csv(out, path, metadata=md)
        return read_ptc_csv(path)
    from bayescap.io.ptc_csv import _readonly

    order = np.argsort(out["mean_dn"] - out["dark_mean_dn"], kind="stable")
    kw = {k: _readonly(v[order]) for k, v in out.items()}
    return PTCData(**kw, metadata=md, source="<simulated>", row_numbers=_readonly(order + 1))
