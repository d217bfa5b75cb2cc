"""Optics and detector MTF components (Tisse et al. 2008, Section 2.2 and Fig. 3).

The system MTF is a product of independent components. Each component is a small object with

* ``name``: a short label for reports;
* ``radial(f_cy_per_px)``: the 1-D (radial) MTF at spatial frequency ``f`` in cycles per pixel,
  used by Eq. 9; returns an array broadcast against ``f``; a component that carries
  measurement uncertainty may return shape ``(n_draws, *f.shape)`` when called with
  ``draws=True`` (see :class:`TabulatedMTF`);
* ``mtf2d(fx_cy_per_px, fy_cy_per_px)``: the 2-D MTF for Eq. 8 (isotropic components use the
  radius).

Frequencies are in cycles per pixel throughout (Nyquist = 0.5 cy/px), so a component that depends
on physical size (the lens) is told the pixel pitch.

Because log2 of a product is a sum, the MTF loss Δs of Eq. 8/9 adds over components
(:func:`bayescap.capacity.mtf_loss_bits`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "MTFComponent",
    "PixelAperture",
    "DiffractionLens",
    "TabulatedMTF",
    "MTFProduct",
    "default_mtf",
]


class MTFComponent:
    """Base class of MTF components (see module docstring for the protocol)."""

    name = "mtf"
    #: frequency (cy/px) above which the component is exactly zero (np.inf if never)
    cutoff_cy_per_px = np.inf

    def radial(self, f_cy_per_px):  # pragma: no cover - interface
        raise NotImplementedError

    def mtf2d(self, fx_cy_per_px, fy_cy_per_px):
        return self.radial(np.hypot(fx_cy_per_px, fy_cy_per_px))

    def describe(self) -> dict:
        return {"name": self.name}


@dataclass(frozen=True)
class PixelAperture(MTFComponent):
    """Ideal square pixel aperture with uniform response (geometric PRF).

    The active area is a square of side ``sqrt(fill_factor)`` pixel pitches; its MTF along one
    axis is ``|sinc(sqrt(ff) * f)|`` with ``np.sinc(x) = sin(pi x)/(pi x)`` and ``f`` in cy/px.
    The 2-D MTF is the separable product. Because it depends on ``f`` only in cycles per pixel,
    its Δs is the same at every pixel pitch (paper, Section 3).
    """

    fill_factor: float = 1.0
    name: str = "pixel_aperture"

    def __post_init__(self):
        if not (0.0 < self.fill_factor <= 1.0):
            raise ValueError(f"fill_factor must be in (0, 1], got {self.fill_factor}")

    @property
    def width_px(self) -> float:
        return float(np.sqrt(self.fill_factor))

    def radial(self, f_cy_per_px):
        return np.abs(np.sinc(self.width_px * np.asarray(f_cy_per_px, dtype=float)))

    def mtf2d(self, fx_cy_per_px, fy_cy_per_px):
        w = self.width_px
        return np.abs(np.sinc(w * np.asarray(fx_cy_per_px, float)) * np.sinc(w * np.asarray(fy_cy_per_px, float)))

    @property
    def cutoff_cy_per_px(self):
        # first zero of the sinc at f = 1/width >= 1 cy/px: outside the Nyquist band
        return 1.0 / self.width_px

    def describe(self):
        return {"name": self.name, "fill_factor": self.fill_factor}


@dataclass(frozen=True)
class DiffractionLens(MTFComponent):
    """Diffraction-limited lens with a circular pupil (incoherent MTF).

    MTF(f) = (2/π)[acos(f/f₀) − (f/f₀)·sqrt(1 − (f/f₀)²)] for f < f₀, 0 beyond, with cut-off
    f₀ = 1/(λ·N). (The paper's Fig. 3 caption prints the square-root term with exponent −1/2:
    a typo; the standard form has +1/2.) In cycles per pixel f₀ = pitch/(λ·N).
    """

    f_number: float = 2.8
    wavelength_nm: float = 555.0
    pixel_pitch_um: float = 1.75
    name: str = "diffraction"

    def __post_init__(self):
        for k in ("f_number", "wavelength_nm", "pixel_pitch_um"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{k} must be positive and finite, got {v}")

    @property
    def cutoff_cy_per_mm(self) -> float:
        return 1.0 / (self.wavelength_nm * 1e-6 * self.f_number)

    @property
    def cutoff_cy_per_px(self) -> float:
        return self.pixel_pitch_um * 1e-3 * self.cutoff_cy_per_mm

    def radial(self, f_cy_per_px):
        x = np.clip(np.asarray(f_cy_per_px, dtype=float) / self.cutoff_cy_per_px, 0.0, 1.0)
        return (2.0 / np.pi) * (np.arccos(x) - x * np.sqrt(1.0 - x * x))

    def describe(self):
        return {
            "name": self.name,
            "f_number": self.f_number,
            "wavelength_nm": self.wavelength_nm,
            "pixel_pitch_um": self.pixel_pitch_um,
            "cutoff_cy_per_px": self.cutoff_cy_per_px,
        }


@dataclass(frozen=True)
class TabulatedMTF(MTFComponent):
    """A measured MTF table (frequency in cy/px, MTF), optionally with draws for uncertainty.

    Linear interpolation; beyond the last tabulated frequency the last value is held (and
    the caller is told through ``max_freq_cy_per_px``). ``samples`` has shape
    ``(n_draws, n_freq)``; ``radial(f, draws=True)`` returns one curve per draw.
    """

    freq_cy_per_px: np.ndarray
    mtf: np.ndarray
    samples: np.ndarray | None = None
    name: str = "measured"

    def __post_init__(self):
        f = np.asarray(self.freq_cy_per_px, float)
        m = np.asarray(self.mtf, float)
        if f.ndim != 1 or f.shape != m.shape or f.size < 2:
            raise ValueError("freq_cy_per_px and mtf must be 1-D arrays of the same length >= 2")
        if np.any(np.diff(f) <= 0):
            raise ValueError("freq_cy_per_px must be strictly increasing")
        object.__setattr__(self, "freq_cy_per_px", f)
        object.__setattr__(self, "mtf", m)
        if self.samples is not None:
            s = np.asarray(self.samples, float)
            if s.ndim != 2 or s.shape[1] != f.size:
                raise ValueError("samples must have shape (n_draws, n_freq)")
            object.__setattr__(self, "samples", s)

    @property
    def max_freq_cy_per_px(self) -> float:
        return float(self.freq_cy_per_px[-1])

    @property
    def cutoff_cy_per_px(self):
        zero = np.nonzero(self.mtf <= 0)[0]
        return float(self.freq_cy_per_px[zero[0]]) if zero.size else np.inf

    def radial(self, f_cy_per_px, draws: bool = False):
        f = np.asarray(f_cy_per_px, float)
        if not draws or self.samples is None:
            return np.clip(np.interp(f, self.freq_cy_per_px, self.mtf), 0.0, None)
        flat = f.ravel()
        # vectorised interpolation of every draw: weights are shared
        idx = np.clip(np.searchsorted(self.freq_cy_per_px, flat) - 1, 0, self.freq_cy_per_px.size - 2)
        f0, f1 = self.freq_cy_per_px[idx], self.freq_cy_per_px[idx + 1]
        w = np.clip((flat - f0) / (f1 - f0), 0.0, 1.0)
        out = self.samples[:, idx] * (1 - w) + self.samples[:, idx + 1] * w
        return np.clip(out, 0.0, None).reshape((self.samples.shape[0],) + f.shape)

    def describe(self):
        return {"name": self.name, "n_freq": int(self.freq_cy_per_px.size),
                "max_freq_cy_per_px": self.max_freq_cy_per_px,
                "n_draws": 0 if self.samples is None else int(self.samples.shape[0])}


@dataclass(frozen=True)
class MTFProduct(MTFComponent):
    """Product of MTF components (the system MTF)."""

    components: tuple = field(default_factory=tuple)
    name: str = "system"

    def radial(self, f_cy_per_px):
        out = np.ones_like(np.asarray(f_cy_per_px, float))
        for c in self.components:
            out = out * c.radial(f_cy_per_px)
        return out

    def mtf2d(self, fx_cy_per_px, fy_cy_per_px):
        out = np.ones(np.broadcast_shapes(np.shape(fx_cy_per_px), np.shape(fy_cy_per_px)))
        for c in self.components:
            out = out * c.mtf2d(fx_cy_per_px, fy_cy_per_px)
        return out

    @property
    def cutoff_cy_per_px(self):
        return min([c.cutoff_cy_per_px for c in self.components], default=np.inf)

    def describe(self):
        return {"name": self.name, "components": [c.describe() for c in self.components]}


def default_mtf(*, fill_factor: float = 1.0, f_number: float | None = 2.8,
                wavelength_nm: float = 555.0, pixel_pitch_um: float | None = None) -> MTFProduct:
    """The core's default MTF: ideal pixel aperture x diffraction-limited lens.

    The lens needs the pixel pitch to convert its cut-off to cycles per pixel; without a pitch
    (or with ``f_number=None``) only the pixel aperture is used, and the caller must report that
    the lens term is missing.
    """
    comps = [PixelAperture(fill_factor=fill_factor)]
    if pixel_pitch_um is not None and f_number is not None:
        comps.append(DiffractionLens(f_number=f_number, wavelength_nm=wavelength_nm,
                                     pixel_pitch_um=pixel_pitch_um))
    return MTFProduct(components=tuple(comps))
