"""The non-linear zoo: sensors whose response is not the model's, simulated frame by frame.

Seven shapes (:data:`FAMILY`): the six response shapes of :mod:`.responses` (quadratic, cubic and
quartic compression, S-shaped, a soft knee before saturation, a two-slope ADC) and brighter-fatter
(Astier's a₀₀ of −1 to −3·10⁻⁶ per e⁻, a linear response). Each in three cameras (:data:`CAMERAS`:
bit depth, gain, read noise, ROI, levels, strength) and each with and without ``photons_per_pixel``
(without, the means cannot pin the shape; the temporal PTC's curvature must): 7 × 3 × 2 = 42
sensors, as :class:`~bayescap.validation.zoo.ZooSensor` so the linear zoo's truths and scorer
(:func:`~bayescap.validation.zoo.truths`, :func:`~bayescap.validation.zoo.score`) apply unchanged.

Conventions of the truths: K is the small-signal gain (every shape has unit slope at zero);
``full_well_e`` is the charge at which the mean pixel's output clips (CONTRACT.md), through the
inverse of the response when the ADC clips first; η is the simulator's QE (scored only with photon
counts); read noise, or the dark noise with one exposure time, as in the linear zoo. The response's
charge scale is the ADC clip's charge, so every shape is at x = 1 at the top of the unclipped range
and the brightest row sits at 1.25 of it.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from bayescap.validation.framesim import Acquisition, FrameSensor, clip_charge_e, simulate_rows, write_csv
from bayescap.validation.responses import Response
from bayescap.validation.zoo import ZooSensor, truths

__all__ = [
    "FAMILY",
    "CAMERAS",
    "SCORED",
    "nonlinear_zoo",
    "scored_truths",
    "output_clip_e",
    "ensure_csvs",
    "shape_of",
    "has_photons",
    "reseeded",
]

FAMILY = ("quadratic", "cubic", "quartic", "s_shape", "soft_knee", "two_slope", "brighter_fatter")

#: the parameters the issue's targets count (read noise or, with one exposure time, dark noise)
SCORED = ("conversion_gain_e_per_dn", "read_noise_e", "dark_noise_e", "quantum_efficiency", "full_well_e")

#: camera -> (bits, K e⁻/DN, read noise DN, dark e⁻/s, ROI side, levels, t_max s); brighter-fatter
#: gets large wells (a₀₀·μ up to 0.4): its own cameras
CAMERAS = {
    "8bit": (8, 50.0, 0.7, 20.0, 256, 50, 0.02),
    "12bit": (12, 10.0, 3.0, 20.0, 200, 50, 0.05),
    "16bit": (16, 1.5, 2.0, 5.0, 100, 40, 0.05),
}
BF_CAMERAS = {
    "12bit": (12, 30.0, 0.5, 5.0, 100, 40, 0.5),
    "14bit": (14, 8.0, 0.7, 5.0, 100, 40, 0.5),
    "16bit": (16, 2.0, 3.0, 5.0, 100, 40, 0.5),
}
#: shape -> strength per camera (mild, medium, strong) and the knee/break position
STRENGTH = {
    "quadratic": ((0.03, 0.06, 0.10), 0.75),
    "cubic": ((0.04, 0.08, 0.12), 0.75),
    "quartic": ((0.03, 0.05, 0.07), 0.75),
    "s_shape": ((0.03, 0.045, 0.06), 0.75),
    "soft_knee": ((0.35, 0.25, 0.15), 0.75),
    "two_slope": ((0.1, 0.2, 0.3), 0.6),
    "brighter_fatter": ((1e-6, 2e-6, 3e-6), None),
}
_BLACK = {8: 6, 12: 240, 14: 800, 16: 1600}
FILL = 1.25  # brightest row, in units of the clip charge
WELL = 1.4  # the wells, beyond the ADC clip (the ADC clips first)


def shape_of(zs: ZooSensor) -> str:
    return zs.tags[0]


def has_photons(zs: ZooSensor) -> bool:
    return "photons" in zs.tags


def _sensor(shape, cam, strength, knee, photons, seed) -> ZooSensor:
    bits, k, read_dn, dark, roi, levels, t_max = (BF_CAMERAS if shape == "brighter_fatter" else CAMERAS)[cam]
    black = float(max(_BLACK[bits], math.ceil(6 * read_dn + 2)))
    y_clip = (2**bits - 1 - black) * k  # charge-equivalent signal at the ADC maximum
    resp, a00 = None, 0.0
    if shape == "brighter_fatter":
        clip_e = y_clip
        a00 = -strength
    else:
        probe = Response(shape, strength, 1.0, knee=knee, x_max=WELL + 0.05)
        clip_e = y_clip / float(probe.f(1.0))  # the response's charge scale: x = 1 at the ADC clip
        resp = Response(shape, strength, clip_e, knee=knee, x_max=WELL + 0.05)
    s = FrameSensor(
        k_e_per_dn=k,
        read_noise_e=read_dn * k,
        full_well_e=WELL * clip_e,
        quantum_efficiency=0.55,
        dark_current_e_per_s=dark,
        prnu_frac=0.01,
        dsnu_e=0.3 * k,
        adc_bits=bits,
        black_level_dn=black,
        width_px=roi,
        height_px=roi,
        response=resp,
        bf_a00_per_e=a00,
    )
    clip_true, _ = clip_charge_e(s)
    frac = np.linspace(0.02, FILL, levels)
    charge = frac * clip_true
    t = t_max * frac / FILL
    photons_pp = np.maximum(charge - dark * t, 0.0) / s.quantum_efficiency
    sp = tuple(sorted(set(np.linspace(0, levels - 1, 5).round().astype(int).tolist())))
    acq = Acquisition(tuple(t.tolist()), tuple(photons_pp.tolist()), sp, 2)
    tag_p = "photons" if photons else "no-photons"
    what = f"a00 {-a00:.0e}/e-" if shape == "brighter_fatter" else f"strength {strength:g}"
    name = f"nl_{shape}_{cam}_{'ph' if photons else 'noph'}"
    return ZooSensor(name, s, acq, seed, (shape, tag_p, cam), f"{shape}, {what}, {cam}, {tag_p}")


def nonlinear_zoo() -> list[ZooSensor]:
    """The 42 sensors (module docstring), in the order shape × camera × photons."""
    out = []
    for i, shape in enumerate(FAMILY):
        strengths, knee = STRENGTH[shape]
        cams = BF_CAMERAS if shape == "brighter_fatter" else CAMERAS
        for j, cam in enumerate(cams):
            for photons in (True, False):
                seed = 4600 + 10 * i + 2 * j + (0 if photons else 1)
                out.append(_sensor(shape, cam, strengths[j], knee if knee is not None else 0.75, photons, seed))
    return out


def reseeded(zs: ZooSensor, replicate: int) -> ZooSensor:
    """The same sensor and acquisition simulated from an independent seed (new frames, hence new
    means and variances): replicate 0 is the zoo's own seed; replicate r adds 100 000·r, far from
    every zoo seed. The CSV cache tells the replicates apart by the seed in :meth:`ZooSensor.key`."""
    if replicate < 0:
        raise ValueError(f"replicate must be >= 0, got {replicate}")
    return replace(zs, seed=zs.seed + 100_000 * int(replicate))


def scored_truths(zs: ZooSensor) -> dict:
    """The linear zoo's truths restricted to :data:`SCORED`; η only with photon counts."""
    t = truths(zs)
    out = {p: v for p, v in t.items() if p in SCORED}
    if not has_photons(zs):
        out.pop("quantum_efficiency", None)
    return out


def output_clip_e(zs: ZooSensor) -> float:
    """The clip in output terms: (ADC max − black) · K, the charge-equivalent signal at which the
    output clips (the charge itself only for a linear response). Not a truth of the contract's
    ``full_well_e`` (a charge); the benchmark shows it beside, to tell a convention from a miss."""
    s = zs.sensor
    return (s.adc_max_dn - s.black_level_dn) * s.k_e_per_dn


def _columns(zs: ZooSensor, rows) -> list:
    cols = [c for c in rows[0]] + [c for c in ("spatial_var_dn2", "dark_spatial_var_dn2", "n_frames")]
    seen = []
    for c in cols:
        if c not in seen and (has_photons(zs) or c != "photons_per_pixel"):
            seen.append(c)
    return seen


def ensure_csvs(zs: ZooSensor, folder, low_frac: float = 0.7) -> tuple[Path, Path]:
    """The sensor's CSV with every row, and with the rows whose signal (mean − dark mean) is below
    ``low_frac`` of the largest (EMVA 1288's range); generated once, named with a hash of the
    definition."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    base = f"{zs.name}-{zs.key()}"
    p_all, p_low = folder / f"{base}.csv", folder / f"{base}-low{int(100 * low_frac)}.csv"
    if not (p_all.exists() and p_low.exists()):
        rows = simulate_rows(zs.sensor, zs.acq, zs.seed)
        sig = np.array([r["mean_dn"] - r["dark_mean_dn"] for r in rows])
        low = [r for r, s in zip(rows, sig) if s < low_frac * sig.max()]
        cols = _columns(zs, rows)
        for path, rr in ((p_all, rows), (p_low, low)):
            tmp = path.with_suffix(".tmp")
            write_csv(tmp, rr, zs.metadata(), columns=cols)
            tmp.replace(path)
    return p_all, p_low
