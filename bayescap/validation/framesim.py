"""A frame-level image-sensor simulator written independently of the likelihood.

It shares no code with :mod:`bayescap.model` or :mod:`bayescap.simulate`: pixels are drawn one by
one as a camera makes them, and the photon-transfer statistics are computed from the frames as
EMVA 1288 (Release 4.0) prescribes, so that a fit checked against it is not checked against its own
assumptions.

The pixel chain, per frame and pixel i:

* photo-electrons ~ Poisson(μ_p · QE · (1 + PRNU_i)) and dark electrons ~ Poisson(D · t);
* the charge clips at the pixel's own well W_i = W · (1 + s · N_i) (full-well spread s);
* with ``bf_a00_per_e`` < 0 the photo-electrons are collected with the brighter-fatter area change
  (:func:`.responses.collect_brighter_fatter`: Astier 2019's a₀₀, nearest neighbours gaining what
  a full pixel loses);
* an optional non-linear response q → q · (1 − a · q / W) (a = ``nonlinearity``), or any shape of
  :class:`.responses.Response` (``response``: quadratic, cubic, quartic, S-shaped, soft knee,
  two-slope ADC; unit slope at zero, so K stays the small-signal gain);
* the read-out adds the pixel's fixed offset DSNU_i (e⁻) and Gaussian read noise (e⁻);
* the analog value in DN is black + (charge + DSNU_i + read) / K; the ADC rounds it to the nearest
  integer or truncates it (floor), and clips to [0, 2^bits − 1].

PRNU, DSNU and the well map are drawn once per sensor (one ROI). Statistics per row:

* ``mean_dn``: mean of the pair's average; ``temporal_var_dn2``: (mean((A−B)²) − (mean A − mean B)²)/2;
* the same for a dark pair at the row's exposure time;
* ``spatial_var_dn2``/``dark_spatial_var_dn2`` (where requested): the spatial variance (ddof 1) of the
  average of ``n_frames`` frames (the pair's frames are the first two; ``n_frames = 1`` uses A);
* ``frac_saturated``: fraction of frame A's pixels at the ADC maximum;
* ``photons_per_pixel``: the photon count per pixel the experimenter *reports* (an outlier row
  reports a count that differs from the light delivered).

Frames are generated level by level (memory: a few ROI-sized arrays, 8 MB each at 1000²).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayescap.validation.responses import Response, collect_brighter_fatter

__all__ = ["FrameSensor", "Acquisition", "simulate_rows", "write_csv", "CSV_COLUMNS"]

CSV_COLUMNS = (
    "exposure_time_s",
    "mean_dn",
    "temporal_var_dn2",
    "dark_mean_dn",
    "dark_temporal_var_dn2",
    "n_pixels",
    "photons_per_pixel",
    "frac_saturated",
    "spatial_var_dn2",
    "dark_spatial_var_dn2",
    "n_frames",
)


@dataclass(frozen=True)
class FrameSensor:
    """A sensor, pixel by pixel. Charges in electrons, K in e⁻/DN, black level in DN (analog
    offset before the ADC; need not be an integer)."""

    k_e_per_dn: float
    read_noise_e: float
    full_well_e: float
    quantum_efficiency: float = 0.5
    dark_current_e_per_s: float = 0.0
    prnu_frac: float = 0.0
    dsnu_e: float = 0.0
    well_spread_frac: float = 0.0
    adc_bits: int = 12
    black_level_dn: float = 64.0
    adc: str = "round"  # "round" or "floor"
    nonlinearity: float = 0.0
    width_px: int = 100
    height_px: int = 100
    response: Response | None = None
    bf_a00_per_e: float = 0.0
    bf_steps: int = 16

    @property
    def adc_max_dn(self) -> int:
        return 2**self.adc_bits - 1


@dataclass(frozen=True)
class Acquisition:
    """What is measured: per row an exposure time and the mean photons per pixel delivered.

    ``spatial_rows``: indices of the rows that get spatial columns (averages of ``n_frames``
    frames). ``photon_report_factor``: {row: factor}, the reported photon count is the delivered
    one times the factor (a shutter or lamp error: an outlier row)."""

    exposure_time_s: tuple
    photons_per_pixel: tuple
    spatial_rows: tuple = ()
    n_frames: int = 2
    photon_report_factor: dict = field(default_factory=dict)

    def __post_init__(self):
        if len(self.exposure_time_s) != len(self.photons_per_pixel):
            raise ValueError("exposure_time_s and photons_per_pixel differ in length")
        if self.n_frames < 1:
            raise ValueError("n_frames must be >= 1")


class _Pixels:
    """The fixed pattern of one ROI (drawn once) and the frame generator."""

    def __init__(self, sensor: FrameSensor, rng: np.random.Generator):
        self.s = sensor
        shape = (sensor.height_px, sensor.width_px)
        self.gain_map = 1.0 + sensor.prnu_frac * rng.standard_normal(shape)
        np.clip(self.gain_map, 0.0, None, out=self.gain_map)
        self.offset_e = sensor.dsnu_e * rng.standard_normal(shape)
        self.well_e = sensor.full_well_e * (1.0 + sensor.well_spread_frac * rng.standard_normal(shape))
        np.clip(self.well_e, 0.0, None, out=self.well_e)

    def frame(self, rng: np.random.Generator, photons, t: float) -> np.ndarray:
        """One frame in DN (float64 holding integers); ``photons`` an array of shape (L,) gives L
        frames at once, shape (L, H, W) (the brighter-fatter slices then run on all of them)."""
        s = self.s
        rate = np.asarray(photons, float)[..., None, None] * s.quantum_efficiency * self.gain_map
        if s.bf_a00_per_e:
            q = collect_brighter_fatter(rng, rate, s.bf_a00_per_e, s.bf_steps)
        else:
            q = rng.poisson(rate).astype(np.float64)
        if s.dark_current_e_per_s > 0 and t > 0:
            q += rng.poisson(s.dark_current_e_per_s * t, size=q.shape)
        np.minimum(q, self.well_e, out=q)
        if s.nonlinearity:
            q *= 1.0 - s.nonlinearity * q / s.full_well_e
        if s.response is not None:
            q = s.response.apply(q)
        q += self.offset_e
        q += s.read_noise_e * rng.standard_normal(q.shape)
        x = s.black_level_dn + q / s.k_e_per_dn
        x = np.floor(x, out=x) if s.adc == "floor" else np.rint(x, out=x)
        return np.clip(x, 0.0, float(s.adc_max_dn), out=x)


def _pair_stats(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    ma, mb = float(a.mean()), float(b.mean())
    d = a - b
    var = (float(np.mean(d * d)) - (ma - mb) ** 2) / 2.0
    return (ma + mb) / 2.0, var


def _spatial(pix: _Pixels, rng, photons, t, a, b, n_frames) -> float:
    if n_frames == 1:
        avg = a
    else:
        avg = a + b
        for _ in range(n_frames - 2):
            avg += pix.frame(rng, photons, t)
        avg /= n_frames
    return float(np.var(avg, ddof=1))


def simulate_rows(sensor: FrameSensor, acq: Acquisition, seed: int) -> list[dict]:
    """Simulate every row's frames (level by level) and return the contract rows as dicts."""
    if sensor.adc not in ("round", "floor"):
        raise ValueError(f"adc must be 'round' or 'floor', got {sensor.adc!r}")
    ss = np.random.SeedSequence(seed)
    map_seq, frame_seq = ss.spawn(2)
    pix = _Pixels(sensor, np.random.default_rng(map_seq))
    row_seqs = frame_seq.spawn(len(acq.exposure_time_s))
    spatial = set(int(i) for i in acq.spatial_rows)
    n = sensor.width_px * sensor.height_px
    rows = []
    for i, (t, mu_p) in enumerate(zip(acq.exposure_time_s, acq.photons_per_pixel)):
        rng = np.random.default_rng(row_seqs[i])
        t, mu_p = float(t), float(mu_p)
        a, b = pix.frame(rng, mu_p, t), pix.frame(rng, mu_p, t)
        mean, var = _pair_stats(a, b)
        frac_sat = float(np.mean(a >= sensor.adc_max_dn))
        da, db = pix.frame(rng, 0.0, t), pix.frame(rng, 0.0, t)
        dmean, dvar = _pair_stats(da, db)
        row = {
            "exposure_time_s": t,
            "mean_dn": mean,
            "temporal_var_dn2": var,
            "dark_mean_dn": dmean,
            "dark_temporal_var_dn2": dvar,
            "n_pixels": n,
            "photons_per_pixel": mu_p * float(acq.photon_report_factor.get(i, 1.0)),
            "frac_saturated": frac_sat,
        }
        if i in spatial:
            row["spatial_var_dn2"] = _spatial(pix, rng, mu_p, t, a, b, acq.n_frames)
            row["dark_spatial_var_dn2"] = _spatial(pix, rng, 0.0, t, da, db, acq.n_frames)
            row["n_frames"] = acq.n_frames
        rows.append(row)
    return rows


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))


def write_csv(path, rows: list[dict], metadata: dict, columns=None) -> None:
    """Write a contract CSV: ``# key: value`` lines, the header, one line per row (sparse spatial
    columns empty where a row has none). ``columns``: write only these (in this order), e.g.
    without ``photons_per_pixel``; default every contract column the rows have."""
    has_spatial = any("spatial_var_dn2" in r for r in rows)
    cols = [c for c in CSV_COLUMNS if has_spatial or c not in ("spatial_var_dn2", "dark_spatial_var_dn2", "n_frames")]
    if columns is not None:
        cols = [c for c in columns if c in cols or any(c in r for r in rows)]
    lines = [f"# {k}: {v}" for k, v in metadata.items()]
    lines.append(",".join(cols))
    for r in rows:
        lines.append(",".join(_fmt(r.get(c)) for c in cols))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")


def expected_temporal_var_dn2(sensor: FrameSensor, photons: float, t: float) -> float:
    """Analytic temporal variance (DN²) of an unclipped pixel, population-averaged over the PRNU
    map, with Sheppard's 1/12 DN² (valid where the noise exceeds ~0.6 DN)."""
    k = sensor.k_e_per_dn
    e = photons * sensor.quantum_efficiency + sensor.dark_current_e_per_s * t
    return e / k**2 + sensor.read_noise_e**2 / k**2 + 1.0 / 12.0


def adc_offset_dn(sensor: FrameSensor) -> float:
    """Mean offset of the ADC's output from the analog value for a noise well above a DN:
    0 when rounding, −0.5 DN when truncating."""
    return -0.5 if sensor.adc == "floor" else 0.0


def clip_charge_e(sensor: FrameSensor) -> tuple[float, str]:
    """Charge (e⁻) at which the output clips for the mean pixel, and which mechanism clips first:
    the ADC maximum (in the rounding-equivalent analog scale; through the inverse of ``response``
    where there is one) or the well."""
    black_eff = sensor.black_level_dn + adc_offset_dn(sensor)
    adc_e = (sensor.adc_max_dn - black_eff) * sensor.k_e_per_dn
    if sensor.response is not None:
        r = sensor.response
        adc_e = r.inverse(adc_e) if adc_e <= float(r.apply(r.x_max * r.ref_e)) else float("inf")
    if sensor.full_well_e < adc_e:
        return float(sensor.full_well_e), "well"
    return float(adc_e), "adc"


__all__ += ["expected_temporal_var_dn2", "adc_offset_dn", "clip_charge_e"]
