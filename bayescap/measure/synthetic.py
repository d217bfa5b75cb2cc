"""Synthetic slanted edges with a known MTF, for testing the e-SFR measurement."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import special

__all__ = [
    "synthetic_edge",
    "synthetic_edge_mtf",
]


def synthetic_edge_mtf(
    f_cy_per_px: Any, *, sigma_px: float, fill_factor: float = 1.0, angle_deg: float = 0.0
) -> np.ndarray:
    """Analytic MTF of :func:`synthetic_edge` along the edge normal.

    ``|sinc(a f cos t) sinc(a f sin t)| * exp(-2 pi^2 sigma^2 f^2)`` with ``a =
    sqrt(fill_factor)`` the width of the square pixel aperture and ``t`` the edge angle from
    the nearest pixel axis; for ``angle_deg = 0`` this is ``|sinc(a f)| exp(-2 pi^2 sigma^2
    f^2)`` (the square aperture seen along a slanted normal is the convolution of two boxes
    of widths ``a cos t`` and ``a sin t``).  ``np.sinc(x) = sin(pi x)/(pi x)``.
    """
    f = np.asarray(f_cy_per_px, dtype=float)
    a = math.sqrt(fill_factor)
    t = math.radians(angle_deg)
    return np.abs(np.sinc(a * f * math.cos(t)) * np.sinc(a * f * math.sin(t))) * np.exp(
        -2 * np.pi**2 * sigma_px**2 * f**2
    )


def _blurred_step_antiderivative(d: np.ndarray, sigma: float) -> np.ndarray:
    """Antiderivative of the Gaussian-blurred unit step Phi(d/sigma) with respect to d."""
    if sigma <= 0:
        return np.maximum(d, 0.0)
    t = d / sigma
    return sigma * (t * special.ndtr(t) + np.exp(-0.5 * t * t) / math.sqrt(2 * math.pi))


def synthetic_edge(
    shape: tuple[int, int],
    angle_deg: float,
    mtf_kind: str = "gaussian",
    *,
    sigma_px: float = 0.5,
    fill_factor: float = 1.0,
    contrast: float = 0.6,
    mean_level: float = 0.5,
    noise_sd: float = 0.0,
    seed: int | None = 0,
    supersample: int = 32,
    center: tuple[float, float] | None = None,
) -> np.ndarray:
    """Render a slanted edge with known MTF (:func:`synthetic_edge_mtf`).

    The scene is a unit step across a straight edge through ``center`` (default: image
    centre), blurred by an isotropic Gaussian PSF of standard deviation ``sigma_px`` and
    integrated over a centred square pixel aperture of width ``sqrt(fill_factor)`` px.  The
    integral over the aperture is exact (closed form ``t Phi(t) + phi(t)``) along the
    pixel axis closest to the edge normal and a ``supersample``-point midpoint rule along
    the other axis.

    Parameters
    ----------
    shape : (rows, cols)
    angle_deg : float
        Edge angle from the vertical in the sfrmat convention used by
        :attr:`SFRResult.edge_angle_deg` (about 5: near-vertical edge, about 85 or 95:
        near-horizontal edge).  The bright side is to the right (vertical edges).
    mtf_kind : "gaussian"
        Only Gaussian blur x pixel aperture is implemented (``sigma_px = 0``: aperture only).
    contrast : float
        Michelson contrast (bright - dark)/(bright + dark); levels are
        ``mean_level * (1 -/+ contrast)``.
    noise_sd : float
        Standard deviation of additive white Gaussian noise (seeded by ``seed``).

    Returns
    -------
    (rows, cols) float64 array.
    """
    if mtf_kind != "gaussian":
        raise ValueError(f"mtf_kind {mtf_kind!r} not implemented (only 'gaussian')")
    if sigma_px < 0 or not 0 < fill_factor <= 1:
        raise ValueError("need sigma_px >= 0 and 0 < fill_factor <= 1")
    rows, cols = shape
    cy, cx = ((rows - 1) / 2, (cols - 1) / 2) if center is None else (center[1], center[0])
    # Normal of the edge (pointing to the bright side).  The sfrmat convention measures the
    # angle as atan(-dx/dy) of the edge line in (column, row) coordinates.
    t = math.radians(angle_deg)
    nx, ny = math.cos(t), math.sin(t)
    a = math.sqrt(fill_factor)
    u = (np.arange(supersample) + 0.5) / supersample * a - a / 2  # midpoint offsets
    yy, xx = np.mgrid[0:rows, 0:cols].astype(float)
    dx, dy = xx - cx, yy - cy
    if abs(nx) >= abs(ny):  # exact along x, sampled along y
        base = dx[..., None] * nx + (dy[..., None] + u) * ny
        lo, hi = base - a / 2 * nx, base + a / 2 * nx
        val = (_blurred_step_antiderivative(hi, sigma_px) - _blurred_step_antiderivative(lo, sigma_px)) / (a * nx)
    else:  # exact along y, sampled along x
        base = (dx[..., None] + u) * nx + dy[..., None] * ny
        lo, hi = base - a / 2 * ny, base + a / 2 * ny
        val = (_blurred_step_antiderivative(hi, sigma_px) - _blurred_step_antiderivative(lo, sigma_px)) / (a * ny)
    frac = val.mean(axis=-1)
    dark, bright = mean_level * (1 - contrast), mean_level * (1 + contrast)
    img = dark + (bright - dark) * frac
    if noise_sd > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sd, img.shape)
    return img
