"""Response shapes and brighter-fatter charge collection for the frame simulator.

Written independently of :mod:`bayescap.model` (which this module must never import): these are
the shapes real sensors have, not the shapes the likelihood assumes.

**Response shapes.** A :class:`Response` maps the collected charge q (e⁻) to the charge-equivalent
signal the read-out chain converts to DN, y = ref · f(q/ref), with f(0) = 0, f'(0) = 1 (so the
conversion gain K stays the small-signal gain) and f increasing up to ``x_max`` (checked at
construction). ``ref_e`` is a charge scale; the zoo sets it to the charge at which the ADC clips, so
x = 1 is the top of the unclipped range. Shapes of x = q/ref with strength s:

* ``quadratic``: f = x(1 − s·x), compressive, the textbook bend;
* ``cubic``: f = x(1 − s·x²); ``quartic``: f = x(1 − s·x³): compression concentrated near the top;
* ``s_shape``: f = x(1 + 2s·x − 3s·x²): expansive at low signal (the slope rises to 1 + 4s/9 at
  x = 2/9), compressive at high (slope 1 − 5s at x = 1, f(1) = 1 − s), a non-linear ramp ADC or
  source follower;
* ``soft_knee``: linear up to x_k = ``knee``, then f = x_k + w·tanh((x − x_k)/w) with w = s: a
  smooth roll-off before saturation (C¹ at the knee);
* ``two_slope``: slope 1 below x_b = ``knee``, slope 1 − s above (a companding, two-slope ADC;
  continuous, with a kink).

**Brighter-fatter.** :func:`collect_brighter_fatter` integrates the exposure in ``n_steps`` slices;
in each slice the charge a pixel collects is Poisson with mean (rate/n)·(1 + Σ_j a_j·Q_j), where
Q_j is the charge already in the pixel (j = 0, a₀₀ < 0: a full pixel shrinks) and in its four nearest
neighbours (a₀₁ = −a₀₀/4 each: the area it loses they gain, so the mean is kept). This is the
differential model of Astier et al. 2019 (PASP 131, 064002), whose first-order solution for a flat
is C₀₀ = μ + a₀₀·μ² (e⁻, and (e^{2a₀₀μg} − 1)/(2a₀₀g²) + n₀₀/g² in ADU for the a₀₀-only model).
With n slices frozen at their start the first-order term comes out as a₀₀·μ²·(n − 1)/n; the slice
coupling is therefore a·n/(n − 1), which makes the first order exact for any n (the higher orders
carry an O(1/n) difference). The ROI is periodic (np.roll), so charge is conserved at the edges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SHAPES", "Response", "collect_brighter_fatter", "bf_expected_var_e2"]

SHAPES = ("quadratic", "cubic", "quartic", "s_shape", "soft_knee", "two_slope")


@dataclass(frozen=True)
class Response:
    """y = ref_e · f(q / ref_e) (module docstring). ``knee``: x of the knee or the break (soft_knee,
    two_slope); ``x_max``: the largest x the response must stay increasing to."""

    kind: str
    strength: float
    ref_e: float
    knee: float = 0.75
    x_max: float = 1.6

    def __post_init__(self):
        if self.kind not in SHAPES:
            raise ValueError(f"response kind must be one of {SHAPES}, got {self.kind!r}")
        if not (self.ref_e > 0 and math.isfinite(self.ref_e)):
            raise ValueError("ref_e must be positive")
        if not 0 <= self.strength < 1:
            raise ValueError("strength must be in [0, 1)")
        x = np.linspace(0.0, self.x_max, 4001)
        if np.any(self.slope_x(x) <= 0):
            raise ValueError(f"{self.kind} with strength {self.strength} is not increasing up to x = {self.x_max}")

    # ---------------------------------------------------------------- in x = q / ref
    def f(self, x):
        x = np.asarray(x, float)
        s, k = self.strength, self.knee
        if self.kind == "quadratic":
            return x * (1.0 - s * x)
        if self.kind == "cubic":
            return x * (1.0 - s * x * x)
        if self.kind == "quartic":
            return x * (1.0 - s * x**3)
        if self.kind == "s_shape":
            return x * (1.0 + 2.0 * s * x - 3.0 * s * x * x)
        if self.kind == "soft_knee":
            w = max(s, 1e-12)
            return np.where(x <= k, x, k + w * np.tanh((x - k) / w))
        # two_slope
        return np.where(x <= k, x, k + (1.0 - s) * (x - k))

    def slope_x(self, x):
        x = np.asarray(x, float)
        s, k = self.strength, self.knee
        if self.kind == "quadratic":
            return 1.0 - 2.0 * s * x
        if self.kind == "cubic":
            return 1.0 - 3.0 * s * x * x
        if self.kind == "quartic":
            return 1.0 - 4.0 * s * x**3
        if self.kind == "s_shape":
            return 1.0 + 4.0 * s * x - 9.0 * s * x * x
        if self.kind == "soft_knee":
            w = max(s, 1e-12)
            return np.where(x <= k, 1.0, 1.0 / np.cosh((x - k) / w) ** 2)
        return np.where(x <= k, 1.0, 1.0 - s)

    # ---------------------------------------------------------------- in electrons
    def apply(self, q_e):
        """Charge-equivalent signal (e⁻) for the collected charge q (e⁻)."""
        return self.ref_e * self.f(np.asarray(q_e, float) / self.ref_e)

    def inverse(self, y_e: float) -> float:
        """The charge whose signal is y (bisection on the increasing branch up to x_max)."""
        lo, hi = 0.0, self.x_max
        target = float(y_e) / self.ref_e
        if target > float(self.f(hi)):
            raise ValueError(f"signal {y_e} e- is beyond the response's range")
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if float(self.f(mid)) < target:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi) * self.ref_e


def _neighbour_sum(q):
    """Sum of the four nearest neighbours over the last two axes (periodic)."""
    return np.roll(q, 1, -1) + np.roll(q, -1, -1) + np.roll(q, 1, -2) + np.roll(q, -1, -2)


def collect_brighter_fatter(rng: np.random.Generator, rate_e, a00_per_e: float, n_steps: int = 16):
    """Photo-electrons collected over one exposure with the brighter-fatter area change (module
    docstring). ``rate_e``: mean electrons per pixel for the whole exposure, array (..., H, W);
    ``a00_per_e`` ≤ 0 (Astier's a₀₀; 0 gives plain Poisson). Returns float64 charges."""
    rate = np.asarray(rate_e, float)
    if a00_per_e > 0:
        raise ValueError("a00 must be <= 0 (a pixel's area shrinks as it fills)")
    if a00_per_e == 0 or n_steps < 2:
        return rng.poisson(rate).astype(np.float64)
    step = rate / n_steps
    a = a00_per_e * n_steps / (n_steps - 1)
    q = np.zeros(rate.shape, np.float64)
    for _ in range(n_steps):
        area = 1.0 + a * q - 0.25 * a * _neighbour_sum(q)
        np.clip(area, 0.0, None, out=area)
        q += rng.poisson(step * area)
    return q


def bf_expected_var_e2(mu_e, a00_per_e: float, read_noise_e: float = 0.0):
    """Astier et al. 2019 Eq. 16 in electrons: (e^{2a₀₀μ} − 1)/(2a₀₀) + read² (to first order
    μ + a₀₀μ² + read²)."""
    mu = np.asarray(mu_e, float)
    if a00_per_e == 0:
        return mu + read_noise_e**2
    return np.expm1(2.0 * a00_per_e * mu) / (2.0 * a00_per_e) + read_noise_e**2
