"""Colour-correction matrices (CCMs) and their noise cost.

A CCM ``M`` maps white-balanced raw R, G, B to an output colour space (linear, e.g. sRGB). It mixes
the raw channels, and with them their noise: output i's noise grows by ``√Σⱼ Mᵢⱼ²``
(:func:`noise_gain`) for independent raw noise of equal size, and a large condition number
(:func:`condition_number`) marks sensitivities that overlap, whose differences the matrix must
amplify. Both are what makes a small-pixel sensor's colour noisy.

Sources:

* :func:`ccm_from_matrix`: a user's 3×3 (refused when singular or not finite).
* :func:`ccm_from_spectral`: from camera spectral sensitivities and a reflectance set under an
  illuminant (colour-science's ``MSDS_CAMERA_SENSITIVITIES``, ``SDS_COLOURCHECKERS``,
  ``SDS_ILLUMINANTS``): the camera's white-balanced responses to the patches
  (``colour.characterisation.training_data_sds_to_RGB``) against the patches' linear colour-space
  values (CIE 1931 2° XYZ under the illuminant, adapted to the space's white by Bradford), fitted by
  least squares (``matrix_colour_correction``, Cheung 2004), then scaled per row so that white
  stays white (``M·1 = 1``).
* The RAW file's metadata: :mod:`bayescap.colour.raw_metadata` (another module).

The CCM's source enters CS as a stated uncertainty, not as exactness: ``n_draws`` gives draws of M,
bootstrapped over the reflectance patches for a spectral CCM, or a relative spread ``rel_sd`` of its
elements for a given matrix. A row scaling of M does not change CS (each output channel is counted
on its own grid), but it does change the noise gain; the gains are quoted for white-preserving rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["CCM", "ccm_from_matrix", "ccm_from_spectral", "noise_gain", "condition_number", "white_preserving"]


@dataclass(frozen=True)
class CCM:
    """A colour-correction matrix, its optional draws and where it came from."""

    matrix: np.ndarray  # (3, 3) raw WB RGB -> output
    source: str
    colour_space: str = "sRGB (linear)"
    draws: np.ndarray | None = None  # (n, 3, 3)
    wb_gains: np.ndarray | None = None  # (3,) R, G, B (G = 1) for the source's illuminant
    uncertainty: str = "none: taken as exact"
    notes: list = field(default_factory=list)

    def as_draws(self, n: int, seed: int = 0) -> np.ndarray:
        """(n, 3, 3): the draws resampled to n (with replacement, seeded), or M repeated if exact."""
        if self.draws is None:
            return np.broadcast_to(self.matrix, (n, 3, 3)).copy()
        idx = (
            np.random.default_rng(seed).integers(0, self.draws.shape[0], size=n)
            if n != self.draws.shape[0]
            else slice(None)
        )
        return self.draws[idx].copy()

    def noise_gain(self):
        return noise_gain(self.matrix)

    def condition_number(self):
        return condition_number(self.matrix)

    def to_dict(self) -> dict:
        out = {
            "matrix": np.asarray(self.matrix).tolist(),
            "source": self.source,
            "colour_space": self.colour_space,
            "uncertainty": self.uncertainty,
            "noise_gain": noise_gain(self.matrix).tolist(),
            "condition_number": float(condition_number(self.matrix)),
            "notes": list(self.notes),
        }
        if self.wb_gains is not None:
            out["wb_gains"] = np.asarray(self.wb_gains).tolist()
        if self.draws is not None:
            g = noise_gain(self.draws)
            out["noise_gain_interval_95"] = np.quantile(g, [0.025, 0.975], axis=0).T.tolist()
        return out


def noise_gain(m) -> np.ndarray:
    """Per output channel ``√Σⱼ Mᵢⱼ²`` (the output noise for unit, independent raw noise); (..., 3)."""
    m = np.asarray(m, float)
    return np.sqrt(np.sum(m * m, axis=-1))


def condition_number(m) -> np.ndarray:
    """2-norm condition number of M (largest over smallest singular value); (...)."""
    return np.linalg.cond(np.asarray(m, float))


def white_preserving(m) -> np.ndarray:
    """M with each row scaled to sum to one (white in, white out); (..., 3, 3)."""
    m = np.asarray(m, float)
    return m / m.sum(axis=-1, keepdims=True)


def _check_matrix(m, what: str) -> np.ndarray:
    try:
        a = np.asarray(m, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: the colour-correction matrix must be 3×3 numbers") from None
    if a.shape != (3, 3):
        raise ValueError(f"{what}: the colour-correction matrix must be 3×3, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: the colour-correction matrix has non-finite entries")
    cond = np.linalg.cond(a)
    if not np.isfinite(cond) or cond > 1e12:
        raise ValueError(f"{what}: the colour-correction matrix is singular (condition number {cond:.3g})")
    if np.any(a.sum(axis=1) <= 0):
        raise ValueError(f"{what}: the colour-correction matrix maps white to a non-positive output (a row sum ≤ 0)")
    return a


def ccm_from_matrix(
    m,
    *,
    source: str = "user",
    colour_space: str = "sRGB (linear)",
    rel_sd: float = 0.0,
    n_draws: int | None = None,
    seed: int = 0,
    wb_gains=None,
) -> CCM:
    """A user-supplied 3×3 (raw white-balanced RGB → output). ``rel_sd`` > 0 with ``n_draws``
    gives draws ``Mᵢⱼ·(1 + rel_sd·εᵢⱼ)``, ε standard normal: the stated uncertainty of the source."""
    a = _check_matrix(m, source)
    if rel_sd < 0 or not np.isfinite(rel_sd):
        raise ValueError(f"rel_sd must be ≥ 0, got {rel_sd}")
    draws, unc = None, "none: taken as exact"
    if n_draws:
        rng = np.random.default_rng(seed)
        draws = a[None] * (1.0 + rel_sd * rng.standard_normal((int(n_draws), 3, 3)))
        unc = f"each element ×(1 + {rel_sd:g}·N(0, 1)), {n_draws} draws, seed {seed}"
    wb = None if wb_gains is None else np.asarray(wb_gains, float)
    return CCM(matrix=a, source=source, colour_space=colour_space, draws=draws, wb_gains=wb, uncertainty=unc)


def _training(reflectances, shape):
    import colour

    if isinstance(reflectances, str):
        sds = colour.SDS_COLOURCHECKERS[reflectances]
        name = reflectances
    else:
        sds, name = reflectances, "user reflectances"
    msds = colour.colorimetry.sds_and_msds_to_msds([sd.copy().align(shape) for sd in sds.values()])
    return msds, name


def _fit(rgb, rgb_target):
    from colour.characterisation import matrix_colour_correction

    m = matrix_colour_correction(rgb, rgb_target, method="Cheung 2004")
    return white_preserving(m)


def ccm_from_spectral(
    sensitivities: str = "Nikon 5100 (NPL)",
    reflectances="ColorChecker N Ohta",
    illuminant: str = "D65",
    *,
    colour_space: str = "sRGB",
    n_draws: int | None = None,
    seed: int = 0,
) -> CCM:
    """Least-squares CCM from spectral sensitivities (a colour-science camera name or an
    ``RGB_CameraSensitivities``) and a reflectance set (an ``SDS_COLOURCHECKERS`` name or a dict of
    spectral distributions) under an illuminant (``SDS_ILLUMINANTS`` name), to a linear RGB
    colour space. With ``n_draws``: draws of M from refits on patches resampled with replacement
    (the uncertainty of fitting 3×3 to a finite set), seeded."""
    import colour
    from colour.characterisation import training_data_sds_to_RGB

    sens = colour.MSDS_CAMERA_SENSITIVITIES[sensitivities] if isinstance(sensitivities, str) else sensitivities
    shape = sens.shape
    ill_sd = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape)
    training, train_name = _training(reflectances, shape)
    rgb, rgb_w = training_data_sds_to_RGB(training, sens, ill_sd)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    xyz = colour.msds_to_XYZ(training, cmfs, ill_sd, method="Integration", shape=shape) / 100.0
    xy_ill = colour.XYZ_to_xy(colour.sd_to_XYZ(ill_sd, cmfs, method="Integration") / 100.0)
    target = colour.XYZ_to_RGB(xyz, colour_space, illuminant=xy_ill, chromatic_adaptation_transform="Bradford")
    m = _fit(rgb, target)
    _check_matrix(m, f"spectral CCM ({sens.name})")
    draws, unc = None, "none: taken as exact"
    if n_draws:
        rng = np.random.default_rng(seed)
        n_p = rgb.shape[0]
        draws = np.empty((int(n_draws), 3, 3))
        for i in range(int(n_draws)):
            idx = rng.integers(0, n_p, size=n_p)
            draws[i] = _fit(rgb[idx], target[idx])
        unc = f"bootstrap over the {n_p} patches ({n_draws} refits, seed {seed})"
    wb = np.asarray(rgb_w, float) / float(rgb_w[1])
    src = f"spectral: {sens.name} × {train_name} under {illuminant} → {colour_space} (Cheung 2004 least squares, rows to white)"
    return CCM(matrix=m, source=src, colour_space=f"{colour_space} (linear)", draws=draws, wb_gains=wb, uncertainty=unc)
