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
(:func:`bayescap.physics.capacity.mtf_loss_bits`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "OPTICAL_FORMATS",
    "MTFComponent",
    "PixelAperture",
    "DiffractionLens",
    "TabulatedMTF",
    "MTFProduct",
    "default_mtf",
    "LShapedAperture",
    "GaussianCrosstalk",
    "mtf50_cy_per_px",
]

#: nominal active area (width, height in mm) of common optical formats, 4:3 (the diagonal is the
#: "inch" size × 16 mm for formats ≥ 1/2", × 18 mm below; values as used for phone/compact sensors)
OPTICAL_FORMATS = {
    "1/4": (3.6, 2.7),
    "1/3.6": (4.0, 3.0),
    "1/3.2": (4.54, 3.42),
    "1/3": (4.8, 3.6),
    "1/2.7": (5.37, 4.04),
    "1/2.5": (5.76, 4.29),
    "1/2.3": (6.17, 4.55),
    "1/2": (6.4, 4.8),
    "1/1.8": (7.18, 5.32),
    "2/3": (8.8, 6.6),
    "1": (12.8, 9.6),
    "4/3": (17.3, 13.0),
    "full-frame": (36.0, 24.0),
}


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
        return {
            "name": self.name,
            "n_freq": int(self.freq_cy_per_px.size),
            "max_freq_cy_per_px": self.max_freq_cy_per_px,
            "n_draws": 0 if self.samples is None else int(self.samples.shape[0]),
        }


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


def default_mtf(
    *,
    fill_factor: float = 1.0,
    f_number: float | None = 2.8,
    wavelength_nm: float = 555.0,
    pixel_pitch_um: float | None = None,
) -> MTFProduct:
    """The core's default MTF: ideal pixel aperture x diffraction-limited lens.

    The lens needs the pixel pitch to convert its cut-off to cycles per pixel; without a pitch
    (or with ``f_number=None``) only the pixel aperture is used, and the caller must report that
    the lens term is missing.
    """
    comps = [PixelAperture(fill_factor=fill_factor)]
    if pixel_pitch_um is not None and f_number is not None:
        comps.append(DiffractionLens(f_number=f_number, wavelength_nm=wavelength_nm, pixel_pitch_um=pixel_pitch_um))
    return MTFProduct(components=tuple(comps))


@dataclass(frozen=True)
class LShapedAperture(MTFComponent):
    """L-shaped active area with uniform response: the 2-D MTF of Eq. 3 (Fig. 1), σ = 0.

    Dimensions are in pixel pitches (pixel units, P = 1): an ``A × B`` bounding box with an
    ``a × b`` notch, ``a ≤ A ≤ 1``, ``b ≤ B ≤ 1``. The L is the union of an ``a × (B − b)``
    rectangle and an ``(A − a) × B`` rectangle; Eq. 3 is the sum of their Fourier transforms
    weighted by their areas over ``AB − ab``. The paper's angular frequency ``w = 2πf`` (rad per
    pixel) is converted here: ``sin(½·a·w)/(½·a·w) = np.sinc(a·f)`` with ``f`` in cy/px, and the
    phase ``e^{±j·½·a·w} = e^{±jπaf}``. Fig. 1: ``A = B ≈ P``, ``a ≈ 0.55P``, ``b ≈ 0.28P``
    (the defaults). The active area is ``AB − ab = 0.846`` pixel areas with these values; the
    Fig. 3 caption's "fill factor ≈ 0.45 × 0.72" is ``(A − a)(B − b) = 0.324`` instead (see
    docs/physics.md).

    The MTF is symmetric about DC but not isotropic (Fig. 1b-c); ``mtf2d`` is the exact
    Eq. 3 with ``G_σ = 1`` (multiply by :class:`GaussianCrosstalk` for σ > 0). ``radial(f)``
    is the mean of the horizontal and vertical slices, the paper's (ISO 12233) practice of
    averaging the H and V SFRs for Eq. 9.
    """

    A: float = 1.0
    B: float = 1.0
    a: float = 0.55
    b: float = 0.28
    name: str = "l_shaped_aperture"

    def __post_init__(self):
        if not (0 < self.A <= 1 and 0 < self.B <= 1 and 0 <= self.a < self.A and 0 <= self.b < self.B):
            raise ValueError(
                "need 0 <= a < A <= 1 and 0 <= b < B <= 1 (pixel units), got "
                f"A={self.A}, B={self.B}, a={self.a}, b={self.b}"
            )

    @property
    def fill_factor(self) -> float:
        """Active area / pixel area = AB − ab (pixel units)."""
        return self.A * self.B - self.a * self.b

    def otf2d(self, fx_cy_per_px, fy_cy_per_px):
        """Complex OTF of Eq. 3 (normalised to 1 at DC); ``f`` in cy/px."""
        A, B, a, b = self.A, self.B, self.a, self.b
        f1 = np.asarray(fx_cy_per_px, float)
        f2 = np.asarray(fy_cy_per_px, float)
        area = A * B - a * b
        t1 = (
            a
            * (B - b)
            / area
            * np.sinc(a * f1)
            * np.sinc((B - b) * f2)
            * np.exp(1j * np.pi * a * f1)
            * np.exp(-1j * np.pi * (B - b) * f2)
        )
        t2 = (
            (B * (A - a))
            / area
            * np.sinc((A - a) * f1)
            * np.sinc(B * f2)
            * np.exp(-1j * np.pi * (A - a) * f1)
            * np.exp(-1j * 2 * np.pi * (0.5 * B - b) * f2)
        )
        return t1 + t2

    def mtf2d(self, fx_cy_per_px, fy_cy_per_px):
        return np.abs(self.otf2d(fx_cy_per_px, fy_cy_per_px))

    def radial(self, f_cy_per_px):
        f = np.asarray(f_cy_per_px, float)
        return 0.5 * (self.mtf2d(f, 0.0) + self.mtf2d(0.0, f))

    def describe(self):
        return {"name": self.name, "A": self.A, "B": self.B, "a": self.a, "b": self.b, "fill_factor": self.fill_factor}


@dataclass(frozen=True)
class GaussianCrosstalk(MTFComponent):
    """Gaussian blur kernel ``G_σ`` of Eq. 3 (optical + electronic crosstalk).

    ``MTF(fx, fy) = exp(−2π²(σx²fx² + σy²fy²))`` with σ in pixels and ``f`` in cy/px (the Fourier
    transform of a normalised Gaussian of standard deviation σ). ``sigma_y_px=None`` makes it
    isotropic. Never zero, so it never cuts the band. ``radial`` is the mean of the two axis
    slices (exact when isotropic).
    """

    sigma_px: float = 0.0
    sigma_y_px: float | None = None
    name: str = "crosstalk"

    def __post_init__(self):
        sy = self.sigma_px if self.sigma_y_px is None else self.sigma_y_px
        if not (self.sigma_px >= 0 and sy >= 0 and np.isfinite(self.sigma_px) and np.isfinite(sy)):
            raise ValueError(f"sigma_px and sigma_y_px must be finite and >= 0, got {self.sigma_px}, {sy}")

    @property
    def _sy(self) -> float:
        return self.sigma_px if self.sigma_y_px is None else self.sigma_y_px

    def mtf2d(self, fx_cy_per_px, fy_cy_per_px):
        fx = np.asarray(fx_cy_per_px, float)
        fy = np.asarray(fy_cy_per_px, float)
        return np.exp(-2.0 * np.pi**2 * (self.sigma_px**2 * fx * fx + self._sy**2 * fy * fy))

    def radial(self, f_cy_per_px):
        f = np.asarray(f_cy_per_px, float)
        return 0.5 * (self.mtf2d(f, 0.0) + self.mtf2d(0.0, f))

    def describe(self):
        return {"name": self.name, "sigma_px": self.sigma_px, "sigma_y_px": self._sy}


def mtf50_cy_per_px(mtf, *, level: float = 0.5, f_max_cy_per_px: float = 2.0) -> float:
    """MTF50: the lowest frequency (cy/px) where the radial MTF falls to ``level`` (Section 2.3).

    ``mtf`` is a component or a callable of ``f`` (cy/px). Scans a fine grid up to
    ``f_max_cy_per_px`` and refines the first crossing with Brent's method; NaN if the MTF
    stays above ``level``.
    """
    from scipy.optimize import brentq

    fn = mtf.radial if hasattr(mtf, "radial") else mtf
    f = np.linspace(0.0, f_max_cy_per_px, 2001)
    m = np.asarray(fn(f), float) - level
    idx = np.nonzero(m <= 0)[0]
    if idx.size == 0:
        return float("nan")
    i = int(idx[0])
    if i == 0:
        return 0.0
    return float(brentq(lambda x: float(fn(np.array([x]))[0]) - level, f[i - 1], f[i], xtol=1e-12))
