"""Error of the 9-node Gauss–Hermite sums that PTCModel used for the clip rows until 2026-11-23
(mean and within-pixel variance of clip(N(mu + τξ, s²), c) averaged over ξ) against an 8 001-point
sum, next to the closed forms now in PTCModel._clip_mean / _clip_moments; s = 1, mu from 6 s' below
to 6 s' above the clip.

    python benchmarks/clip_quadrature_error.py
"""
import numpy as np
from scipy.special import ndtr

from bayescap.model.ptc_model import PTCModel


def sums(mu, s, tau, c, xi, w):
    x = mu[:, None] + tau * xi
    a = (c - x) / s
    Phi, phi = ndtr(a), np.exp(-0.5 * a * a) / np.sqrt(2 * np.pi)
    m1 = c - (c - x) * Phi - s * phi
    m2 = (x * x + s * s) * Phi - s * phi * (x + c) + c * c * (1.0 - Phi)
    return m1 @ w, np.maximum(m2 - m1 * m1, 0.0) @ w


def main():
    gx, gw = np.polynomial.hermite_e.hermegauss(9)
    gw = gw / gw.sum()
    dx = np.linspace(-10, 10, 8001)
    dw = np.exp(-0.5 * dx**2)
    dw /= dw.sum()
    print("| τ/s | 9-node mean error (s) | 9-node variance error (s²) | closed-form mean | closed-form variance |")
    print("|---|---|---|---|---|")
    for r in (0.5, 1, 2, 5, 10, 30, 100):
        mu = np.linspace(-6, 6, 601) * np.hypot(1.0, r)
        ref = sums(mu, 1.0, r, 0.0, dx, dw)
        gh = sums(mu, 1.0, r, 0.0, gx, gw)
        full = [np.full_like(mu, v) for v in (1.0, r, 0.0)]
        cf = PTCModel._clip_moments(None, mu, *full)
        print(f"| {r:g} | {np.abs(gh[0] - ref[0]).max():.1e} | {np.abs(gh[1] - ref[1]).max():.1e} | "
              f"{np.abs(cf[0] - ref[0]).max():.1e} | {np.abs(cf[1] - ref[1]).max():.1e} |")


if __name__ == "__main__":
    main()
