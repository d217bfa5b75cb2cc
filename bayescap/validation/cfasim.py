"""A frame-level Bayer (CFA) camera simulator from spectral sensitivities, written independently of
the likelihood and of :mod:`bayescap.colour`.

The scene is a uniform flat field: an illuminant (colour-science's ``SDS_ILLUMINANTS``) reflected
by a diffuse white (or any reflectance), imaged onto an RGGB mosaic. The channel responses come from
measured camera spectral sensitivities (colour-science's ``MSDS_CAMERA_SENSITIVITIES``, BSD-3:
``"Nikon 5100 (NPL)"``, ``"Sigma SDMerill (NPL)"``), each normalised to a peak of one in the dataset;
here they are scaled by ``peak_qe``. The effective quantum efficiency of channel c under the light is

    QE_c = peak_qe · ∫ S_c(λ) E(λ) R(λ) λ dλ / ∫ E(λ) R(λ) λ dλ

(``λ`` turns the illuminant's energy spectrum into a photon spectrum), so that a pixel of channel c
receives ``μ_p · QE_c`` photo-electrons when ``μ_p`` photons (over the band) reach it; ``μ_p`` is what
the tables report as ``photons_per_pixel``. Gb may differ from Gr by ``gb_qe_ratio``.

The pixel chain, per frame and pixel i of channel c (one readout chain: K, read noise, dark current,
well and ADC are shared by the four channels; QE and PRNU are each channel's own):

* photo-electrons ~ Poisson(μ_p · QE_c · (1 + PRNU_c · N_i)), dark electrons ~ Poisson(D · t);
* the charge clips at the well W; Gaussian read noise (e⁻) is added;
* the value in DN is black + charge / K, rounded to the nearest integer and clipped to the ADC range.

Per exposure the simulator makes a flat pair and a dark pair of full mosaics, splits each mosaic
into its four planes (R = [0::2, 0::2], Gr = [0::2, 1::2], Gb = [1::2, 0::2], B = [1::2, 1::2]) and
computes the photon-transfer statistics per plane as EMVA 1288 does (the columns of
``CONTRACT.md`` §1, with ``spatial_var_dn2`` the spatial variance of the pair's average).

The truth it returns per channel is the noise model the capacity code uses, in DN at the raw signal S
(DN above black): ``σ²(S) = c0 + c1·S + c2·S²`` with ``c0 = read²/K² + 1/12 + D·t/K²``, ``c1 = 1/K``,
``c2 = PRNU_c²``, and the clip level ``min(W/K, 2^bits − 1 − black)``. PRNU and QE there are the
values the pattern is drawn from (the population, what the model estimates); the drawn pattern's own
values (``truth["realized"]``, :func:`realized_pattern`) differ from them by its sampling, a PRNU by
about ``1/√(2n)`` relative over n pixels (0.9 % for a 160 × 160 mosaic's planes).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from functools import lru_cache

import numpy as np

__all__ = [
    "CHANNELS",
    "CFACamera",
    "CFAAcquisition",
    "channel_qe",
    "realized_pattern",
    "reflectance_responses",
    "simulate_cfa_pairs",
    "simulate_cfa_ptc",
    "split_planes",
    "truth_of",
]

CHANNELS = ("R", "Gr", "Gb", "B")
_PLANE_SLICES = {
    "R": (slice(0, None, 2), slice(0, None, 2)),
    "Gr": (slice(0, None, 2), slice(1, None, 2)),
    "Gb": (slice(1, None, 2), slice(0, None, 2)),
    "B": (slice(1, None, 2), slice(1, None, 2)),
}
_SENSOR_INDEX = {"R": 0, "Gr": 1, "Gb": 1, "B": 2}
_SHAPE = (400.0, 700.0, 5.0)  # the band every dataset covers (the Sigma set starts at 400 nm, ends at 680)


@dataclass(frozen=True)
class CFACamera:
    """A Bayer camera, pixel by pixel. Charges in e⁻, K in e⁻/DN, black level in DN; the mosaic is
    ``height_px × width_px`` (even), each channel plane a quarter of it."""

    k_e_per_dn: float = 2.0
    read_noise_e: float = 3.0
    full_well_e: float = 12000.0
    peak_qe: float = 0.6
    prnu_frac: tuple = (0.008, 0.006, 0.006, 0.010)  # R, Gr, Gb, B
    dark_current_e_per_s: float = 0.0
    adc_bits: int = 12
    black_level_dn: float = 64.0
    width_px: int = 160
    height_px: int = 160
    sensitivities: str = "Nikon 5100 (NPL)"
    illuminant: str = "D65"
    gb_qe_ratio: float = 1.0
    pixel_pitch_um: float = 4.0

    def __post_init__(self):
        if self.width_px % 2 or self.height_px % 2:
            raise ValueError("the mosaic needs an even width and height (whole RGGB quads)")
        if len(self.prnu_frac) != 4:
            raise ValueError("prnu_frac needs four values (R, Gr, Gb, B)")

    @property
    def adc_max_dn(self) -> int:
        return 2**self.adc_bits - 1


@dataclass(frozen=True)
class CFAAcquisition:
    """Exposures: photons per pixel over the band (what the tables report) at one exposure time."""

    photons_per_pixel: tuple
    exposure_time_s: float = 0.01

    @classmethod
    def spanning(cls, camera: CFACamera, n_rows: int = 14, lo_frac: float = 0.003, hi_frac: float = 1.15):
        """Log-spaced exposures from ``lo_frac`` of the most sensitive channel's clip to ``hi_frac``
        of the least sensitive one's, so that every channel reaches its clip."""
        qe = channel_qe(camera).values()
        clip_e = min(camera.full_well_e, (camera.adc_max_dn - camera.black_level_dn) * camera.k_e_per_dn)
        mu = np.geomspace(lo_frac * clip_e / max(qe), hi_frac * clip_e / min(qe), n_rows)
        return cls(photons_per_pixel=tuple(float(x) for x in mu))


@lru_cache(maxsize=16)
def _spectra(sensitivities: str, illuminant: str):
    import colour  # colour-science: spectral datasets (imported here: the module loads slowly)

    shape = colour.SpectralShape(*_SHAPE)
    sens = (
        colour.MSDS_CAMERA_SENSITIVITIES[sensitivities]
        .copy()
        .align(shape, extrapolator_kwargs={"method": "Constant", "left": 0.0, "right": 0.0})
    )
    ill = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape)
    lam = shape.wavelengths
    return lam, np.asarray(sens.values, float), np.asarray(ill.values, float)


def _responses(camera: CFACamera, reflectances: np.ndarray, *, per_reflected_photon: bool) -> np.ndarray:
    """(n, 3) electrons in the sensor's R, G, B per photon: per photon the reflectance (n, λ) sends
    (``per_reflected_photon``, the QE of a flat of that reflectance) or per photon of the light."""
    lam, s, e = _spectra(camera.sensitivities, camera.illuminant)
    photons = e * lam  # photon spectrum of the light (relative)
    num = (reflectances * photons) @ s  # (n, 3)
    den = (reflectances * photons).sum(axis=1, keepdims=True) if per_reflected_photon else photons.sum()
    return camera.peak_qe * num / den


def channel_qe(camera: CFACamera, reflectance=None) -> dict:
    """Effective QE of R, Gr, Gb, B for a flat field of ``reflectance`` (default: a perfect white)."""
    lam, _, _ = _spectra(camera.sensitivities, camera.illuminant)
    refl = np.ones((1, lam.size)) if reflectance is None else np.atleast_2d(reflectance)
    r = _responses(camera, refl, per_reflected_photon=True)[0]
    return {"R": float(r[0]), "Gr": float(r[1]), "Gb": float(r[1] * camera.gb_qe_ratio), "B": float(r[2])}


def reflectance_responses(camera: CFACamera, chart: str = "ColorChecker N Ohta") -> tuple[np.ndarray, list]:
    """Raw R, G, B responses of the patches of a colour-science reflectance set
    (``SDS_COLOURCHECKERS``) under the camera's illuminant, in electrons per photon of the light
    falling on the patch: (n, 3), and the patch names. A perfect white gives :func:`channel_qe`'s
    R, Gr, B. They span the colours this camera can record from that set."""
    import colour

    shape = colour.SpectralShape(*_SHAPE)
    sds = colour.SDS_COLOURCHECKERS[chart]
    names = list(sds)
    refl = np.array([np.asarray(sds[n].copy().align(shape).values, float) for n in names])
    return _responses(camera, refl, per_reflected_photon=False), names


def truth_of(camera: CFACamera, exposure_time_s: float = 0.0) -> dict:
    """The known values: shared K, read noise, well; per channel QE, PRNU, the DN noise coefficients
    ``var_coeffs_dn2`` (4, 3) = (c0, c1, c2) and ``clip_dn`` (4,), channels R, Gr, Gb, B."""
    k = camera.k_e_per_dn
    qe = channel_qe(camera)
    c0 = (camera.read_noise_e**2 + camera.dark_current_e_per_s * exposure_time_s) / k**2 + 1.0 / 12.0
    coeffs = np.array([[c0, 1.0 / k, p**2] for p in camera.prnu_frac])
    clip_dn = min(camera.full_well_e / k, camera.adc_max_dn - camera.black_level_dn)
    return {
        "k_e_per_dn": k,
        "read_noise_e": camera.read_noise_e,
        "full_well_e": camera.full_well_e,
        "dark_current_e_per_s": camera.dark_current_e_per_s,
        "quantum_efficiency": qe,
        "prnu_frac": dict(zip(CHANNELS, camera.prnu_frac)),
        "var_coeffs_dn2": coeffs,
        "clip_dn": np.full(4, clip_dn),
        "channels": CHANNELS,
        "camera": asdict(camera),
    }


def split_planes(mosaic: np.ndarray) -> dict:
    """The four RGGB planes of a mosaic (..., H, W) as views: {"R", "Gr", "Gb", "B"}."""
    return {c: mosaic[(..., *sl)] for c, sl in _PLANE_SLICES.items()}


@dataclass
class _Mosaic:
    camera: CFACamera
    rng: np.random.Generator
    qe_map: np.ndarray = field(init=False)

    def __post_init__(self):
        cam = self.camera
        qe = channel_qe(cam)
        self.qe_map = np.empty((cam.height_px, cam.width_px))
        for c, sl in _PLANE_SLICES.items():
            p = cam.prnu_frac[CHANNELS.index(c)]
            plane = self.qe_map[sl]
            plane[...] = qe[c] * (1.0 + p * self.rng.standard_normal(plane.shape))
        np.clip(self.qe_map, 0.0, None, out=self.qe_map)

    def frame(self, rng, photons: float, t: float) -> np.ndarray:
        cam = self.camera
        q = rng.poisson(photons * self.qe_map).astype(np.float64)
        if cam.dark_current_e_per_s > 0 and t > 0:
            q += rng.poisson(cam.dark_current_e_per_s * t, size=q.shape)
        np.minimum(q, cam.full_well_e, out=q)
        q += cam.read_noise_e * rng.standard_normal(q.shape)
        x = np.rint(cam.black_level_dn + q / cam.k_e_per_dn)
        return np.clip(x, 0.0, float(cam.adc_max_dn)).astype(np.uint16)


def _seeds(seed: int):
    """The fixed pattern's and the frames' seed sequences of ``seed``."""
    return np.random.SeedSequence(seed).spawn(2)


def realized_pattern(camera: CFACamera, seed: int) -> dict:
    """The fixed pattern :func:`simulate_cfa_pairs` draws for ``seed``, per channel plane: its mean QE
    and its PRNU (the sample sd of the plane's QE map over its mean, ddof 1): {"quantum_efficiency":
    {c: ...}, "prnu_frac": {c: ...}}. These are the realisation on the simulated pixels; the camera's
    ``prnu_frac`` and :func:`channel_qe` are the values it is drawn from (the population), which the
    model's ``prnu_percent`` and QE estimate (the model treats the pixels' pattern as one sample of
    it: ``bayescap.model.prediction``'s ROI latents)."""
    mosaic = _Mosaic(camera, np.random.default_rng(_seeds(seed)[0]))
    planes = split_planes(mosaic.qe_map)
    return {
        "quantum_efficiency": {c: float(planes[c].mean()) for c in CHANNELS},
        "prnu_frac": {c: float(np.std(planes[c], ddof=1) / planes[c].mean()) for c in CHANNELS},
    }


def simulate_cfa_pairs(camera: CFACamera, acq: CFAAcquisition, seed: int) -> list[dict]:
    """Flat and dark mosaic pairs per exposure: a list of {"photons_per_pixel", "exposure_time_s",
    "flat": (A, B), "dark": (A, B)} with uint16 (H, W) RGGB mosaics. The fixed pattern (PRNU) is
    drawn once from ``seed`` (:func:`realized_pattern`); same seed, same frames."""
    map_seq, frame_seq = _seeds(seed)
    mosaic = _Mosaic(camera, np.random.default_rng(map_seq))
    out = []
    for mu, seq in zip(acq.photons_per_pixel, frame_seq.spawn(len(acq.photons_per_pixel))):
        rng = np.random.default_rng(seq)
        t = acq.exposure_time_s
        flat = (mosaic.frame(rng, mu, t), mosaic.frame(rng, mu, t))
        dark = (mosaic.frame(rng, 0.0, t), mosaic.frame(rng, 0.0, t))
        out.append({"photons_per_pixel": float(mu), "exposure_time_s": float(t), "flat": flat, "dark": dark})
    return out


def _pair_stats(a, b):
    a, b = a.astype(np.float64), b.astype(np.float64)
    ma, mb = float(a.mean()), float(b.mean())
    d = a - b
    return (ma + mb) / 2.0, (float(np.mean(d * d)) - (ma - mb) ** 2) / 2.0


def simulate_cfa_ptc(seed: int, camera: CFACamera | None = None, acq: CFAAcquisition | None = None) -> dict:
    """Photon-transfer rows per CFA channel from simulated mosaics, with the truth.

    Returns ``{"R"|"Gr"|"Gb"|"B": {"rows": {column: np.ndarray}, "metadata": {...}}, "truth": truth_of(...)}``;
    ``truth["realized"]`` is the drawn pattern's own QE and PRNU per plane (:func:`realized_pattern`);
    each channel's ``rows`` + ``metadata`` make a contract table
    (``bayescap.io.ptc_csv.write_ptc_csv(rows, path, metadata=metadata)``), with the spatial columns
    (the pair's average, ``n_frames`` = 2) on every row so that PRNU is measurable.
    """
    camera = camera or CFACamera()
    acq = acq or CFAAcquisition.spanning(camera)
    pairs = simulate_cfa_pairs(camera, acq, seed)
    out: dict = {}
    for c in CHANNELS:
        cols: dict = {
            k: []
            for k in (
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
        }
        for p in pairs:
            fa, fb = (split_planes(x)[c] for x in p["flat"])
            da, db = (split_planes(x)[c] for x in p["dark"])
            m, v = _pair_stats(fa, fb)
            dm, dv = _pair_stats(da, db)
            cols["exposure_time_s"].append(p["exposure_time_s"])
            cols["mean_dn"].append(m)
            cols["temporal_var_dn2"].append(v)
            cols["dark_mean_dn"].append(dm)
            cols["dark_temporal_var_dn2"].append(dv)
            cols["n_pixels"].append(fa.size)
            cols["photons_per_pixel"].append(p["photons_per_pixel"])
            cols["frac_saturated"].append(float(np.mean(fa >= camera.adc_max_dn)))
            cols["spatial_var_dn2"].append(float(np.var((fa.astype(float) + fb) / 2.0, ddof=1)))
            cols["dark_spatial_var_dn2"].append(float(np.var((da.astype(float) + db) / 2.0, ddof=1)))
            cols["n_frames"].append(2)
        out[c] = {
            "rows": {k: np.asarray(v) for k, v in cols.items()},
            "metadata": {
                "sensor": f"cfasim {camera.sensitivities} seed {seed}",
                "manufacturer": "simulated (bayescap.validation.cfasim)",
                "channel": c,
                "adc_bits": camera.adc_bits,
                "black_level_dn": round(camera.black_level_dn),
                "width_px": camera.width_px // 2,
                "height_px": camera.height_px // 2,
                "pixel_pitch_um": camera.pixel_pitch_um,
            },
        }
    out["truth"] = truth_of(camera, acq.exposure_time_s)
    out["truth"]["seed"] = seed
    out["truth"]["realized"] = realized_pattern(camera, seed)
    return out
