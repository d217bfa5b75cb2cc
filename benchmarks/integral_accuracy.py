"""Accuracy and cost of the paper's integrals (issue 7, item 4).

1. Tonal range, Eq. 7: ∫ dS / max(σ(S), floor) with σ² = a + bS + cS², by the closed form in
   :func:`bayescap.capacity.integral_inv_sqrt_quadratic`, against Simpson's rule on log- and
   linear-spaced signal grids and against adaptive quadrature (``scipy.integrate.quad``,
   epsrel 1e-13, split at the floor crossing; mpmath is not installed here).
2. MTF loss, Eq. 9: :func:`bayescap.capacity.mtf_loss_bits` with n Gauss–Legendre nodes against
   closed forms (constant MTF: (π/2)·log2 m; Gaussian MTF exp(−2π²σ²f²):
   −π³σ²f_N²/(2 ln 2)) and against quad for the pixel aperture and a diffraction lens whose
   cut-off lies inside the band (log singularity at the cut-off).
3. Propagation: 10 000 posterior draws through TR, DR, SNR, Δs and capacity
   (``FitResult._derive``), best of 7.

    python benchmarks/integral_accuracy.py      # writes results/integral_accuracy.md
"""
from __future__ import annotations

import datetime
import os
import platform
import time
import warnings
from pathlib import Path

import numpy as np
from scipy import integrate

from bayescap.physics.capacity import integral_inv_sqrt_quadratic, mtf_loss_bits
from bayescap.physics.optics import DiffractionLens, GaussianCrosstalk, MTFProduct, PixelAperture

OUT = Path(__file__).resolve().parent / "results" / "integral_accuracy.md"

#: (name, a e⁻², b, c, s1 e⁻, s2 e⁻, floor e⁻)
TR_CASES = [
    ("typical: σr 5 e⁻, PRNU 0.5 %, FW 10⁴ (no floor)", 25.0 + 1 / 12, 1.0, 0.005**2, 5.0, 1e4, 0.0),
    ("typical with the 8-bit floor (FW/256)", 25.0 + 1 / 12, 1.0, 0.005**2, 5.0, 1e4, 1e4 / 256),
    ("large PRNU 3 %, FW 10⁵", 100.0, 1.0, 0.03**2, 10.0, 1e5, 1e5 / 256),
    ("read noise 0.05 e⁻, from S = 0, no floor", 0.05**2, 1.0, 1e-6, 0.0, 1e3, 0.0),
    ("read noise 0.05 e⁻, from S = 0, floor", 0.05**2, 1.0, 1e-6, 0.0, 1e3, 1e3 / 256),
    ("read noise 200 e⁻, FW 10⁶ (floor)", 200.0**2, 1.0, 0.01**2, 200.0, 1e6, 1e6 / 256),
]


def tr_reference(a, b, c, s1, s2, floor):
    f = lambda s: 1.0 / max(np.sqrt(a + b * s + c * s * s), floor)  # noqa: E731
    d = a - floor * floor
    pts = []
    if d < 0:
        s_star = (-2.0 * d) / (b + np.sqrt(b * b - 4 * c * d))
        if s1 < s_star < s2:
            pts = [s_star]
    edges = [s1] + pts + [s2]
    tot, err = 0.0, 0.0
    for lo, hi in zip(edges[:-1], edges[1:]):
        # substitute s = lo + u² near a 1/sqrt singularity at s = 0 (a → 0): smooth integrand
        g = lambda u: 2.0 * u * f(lo + u * u)  # noqa: E731
        v, e = integrate.quad(g, 0.0, np.sqrt(hi - lo), epsabs=0.0, epsrel=1e-13, limit=500)
        tot, err = tot + v, err + e
    return tot, err


def tr_simpson(a, b, c, s1, s2, floor, n, grid):
    if grid == "log":
        lo = s1 if s1 > 0 else 1e-6 * s2   # a log grid cannot start at 0
        s = np.geomspace(lo, s2, n)
    else:
        s = np.linspace(s1, s2, n)
    y = 1.0 / np.maximum(np.sqrt(a + b * s + c * s * s), floor)
    return float(integrate.simpson(y, x=s))


def mtf_cases():
    sigma = 0.4
    return [
        ("constant 0.5", lambda f: np.full_like(np.asarray(f, float), 0.5), 0.5 * np.pi * np.log2(0.5), "closed form"),
        (f"Gaussian σ = {sigma} px", GaussianCrosstalk(sigma_px=sigma),
         -np.pi**3 * sigma**2 * 0.25 / (2 * np.log(2)), "closed form"),
        ("pixel aperture (ff = 1)", PixelAperture(1.0), None, "quad"),
        ("aperture × diffraction f/2.8, 1.75 µm", MTFProduct((PixelAperture(1.0), DiffractionLens(2.8, 555.0, 1.75))), None, "quad"),
        ("diffraction f/8, 1.4 µm (cut-off 0.315 cy/px < Nyquist)", DiffractionLens(8.0, 555.0, 1.4), None, "quad"),
    ]


def ds_reference(mtf):
    fn = 0.5
    cutoff = float(getattr(mtf, "cutoff_cy_per_px", np.inf))
    f_end = min(fn, cutoff)
    r = mtf.radial if hasattr(mtf, "radial") else mtf
    g = lambda f: f * np.log2(max(float(r(np.array([f]))[0]), 1e-300))  # noqa: E731
    if f_end < fn:
        # the integrand has a log singularity at the cut-off: f = f_end (1 − t²) makes it t·log t
        h = lambda t: 2.0 * f_end * t * g(f_end * (1.0 - t * t))  # noqa: E731
        with warnings.catch_warnings():   # quad reports roundoff near 1e-13: converged to that
            warnings.simplefilter("ignore", integrate.IntegrationWarning)
            v, _ = integrate.quad(h, 0.0, 1.0, epsabs=0.0, epsrel=1e-13, limit=500)
    else:
        v, _ = integrate.quad(g, 0.0, f_end, epsabs=0.0, epsrel=1e-13, limit=500)
    cut = 2.0 * np.log2(f_end / fn) if f_end < fn else 0.0
    return np.pi / fn**2 * v + cut


def propagation_timing(n_draws=10_000, repeat=7):
    import bayescap
    from bayescap.inference.fast import fast_posterior
    from bayescap.posterior import FitResult
    from bayescap.model.ptc_model import PTCModel

    d = bayescap.load(Path(__file__).resolve().parents[1] / "data" / "emva1288_basler_ccd12.csv")
    m = PTCModel(d)
    ch, _ = fast_posterior(m, seed=1, n_draws=n_draws)
    from bayescap.api import METADATA_DEFAULTS, mtf_from_metadata

    res = FitResult.from_chains(m, ch, metadata={**METADATA_DEFAULTS, **d.metadata},
                                scene=bayescap.default_scene(d), mtf=mtf_from_metadata(d.metadata),
                                seed=1, quality="fast")
    flat = ch.chain.reshape(-1, m.ndim)
    best_phys = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        m.physical(flat)
        best_phys = min(best_phys, time.perf_counter() - t)
    best = np.inf
    for _ in range(repeat):
        res.notes.clear()
        t = time.perf_counter()
        res._derive()
        best = min(best, time.perf_counter() - t)
    # TR alone
    coeffs = res._noise_coefficients(res.draws, res.scene.exposure_time_s)
    smax, _ = res.signal_max_e()
    from bayescap.physics.capacity import tonal_range

    best_tr = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        tonal_range(coeffs, smax)
        best_tr = min(best_tr, time.perf_counter() - t)
    return n_draws, best, best_tr, best_phys


def main():
    t0 = time.perf_counter()
    L = ["# Integral accuracy", "",
         f"Generated by `python benchmarks/integral_accuracy.py` on "
         f"{datetime.datetime.now().isoformat(timespec='minutes')}; numpy {np.__version__}, "
         f"Python {platform.python_version()}; load average {', '.join(f'{x:.2f}' for x in os.getloadavg())}.",
         "", "## Tonal range integral ∫ dS / max(σ(S), floor)", "",
         "Relative error against adaptive quadrature (scipy quad, epsrel 1e-13, substitution S = s₁ + u², "
         "split at the floor crossing; its own error estimate in the last column).", "",
         "| case | closed form | Simpson log n=100 | log 1000 | log 10⁴ | Simpson linear n=100 | linear 1000 | linear 10⁴ | quad err est |",
         "|---|---|---|---|---|---|---|---|---|"]
    tr_rows = []
    for name, a, b, c, s1, s2, fl in TR_CASES:
        ref, err = tr_reference(a, b, c, s1, s2, fl)
        cf = float(integral_inv_sqrt_quadratic(a, b, c, s1, s2, floor=fl))
        cells = [abs(cf / ref - 1)]
        for grid in ("log", "linear"):
            for n in (100, 1000, 10_000):
                cells.append(abs(tr_simpson(a, b, c, s1, s2, fl, n, grid) / ref - 1))
        tr_rows.append((name, cells))
        L.append(f"| {name} | " + " | ".join(f"{x:.1e}" for x in cells) + f" | {err / ref:.0e} |")
    L += ["", "A log grid cannot start at S = 0: there it starts at 10⁻⁶·S_max, which misses the part of "
          "the integral below (the error shown).", ""]
    # MTF
    L += ["## MTF loss Δs (Eq. 9): Gauss–Legendre nodes", "",
          "Absolute error in bits against the closed form or quad (epsrel 1e-13).", ""]
    ns = (4, 8, 16, 32, 64, 128, 256, 1024)
    L.append("| MTF | reference Δs (bits) | " + " | ".join(f"n={n}" for n in ns) + " |")
    L.append("|---|---|" + "---|" * len(ns))
    worst = {n: 0.0 for n in ns}      # over the MTFs whose band is not cut
    worst_cut = {n: 0.0 for n in ns}
    for name, mtf, exact, how in mtf_cases():
        cut = float(getattr(mtf, "cutoff_cy_per_px", np.inf)) < 0.5
        ref = exact if exact is not None else ds_reference(mtf)
        errs = []
        for n in ns:
            v = float(mtf_loss_bits(mtf, n_nodes=n).delta_s_bits)
            errs.append(abs(v - ref))
            (worst_cut if cut else worst)[n] = max((worst_cut if cut else worst)[n], errs[-1])
        L.append(f"| {name} ({how}) | {ref:.12f} | " + " | ".join(f"{e:.1e}" for e in errs) + " |")
    lines = []
    for preset, tol in (("fast", 1e-4), ("standard", 1e-6), ("accurate", 1e-10)):
        ok = [n for n in ns if worst[n] <= tol]
        okc = [n for n in ns if worst_cut[n] <= tol]
        lines.append(f"{preset} (≤ {tol:g} bits): n = {ok[0] if ok else '> ' + str(ns[-1])} without a band cut, "
                     f"n = {okc[0] if okc else '> ' + str(ns[-1])} with one")
    L += ["", "Smallest n whose worst error is below each preset's tolerance: " + "; ".join(lines) + ". "
          "Without a cut the integrand is analytic and Gauss–Legendre converges geometrically; with a lens "
          "cut-off inside the band the log singularity at the cut-off makes the error fall only as ~1/n². "
          "Δs is computed once per fit (the MTF has no draws unless measured), so n costs microseconds.", ""]
    # propagation
    n, t_all, t_tr, t_phys = propagation_timing()
    L += ["## Propagation of posterior draws", "",
          f"{n} draws (Basler CCD, Laplace–IS draws): TR, DR, SNR, Δs and capacity (`FitResult._derive`) "
          f"{t_all * 1e3:.1f} ms, plus {t_phys * 1e3:.1f} ms to map the draws to physical parameters "
          f"(`PTCModel.physical`); TR alone (closed form) {t_tr * 1e3:.2f} ms (best of 7; target ≤ 50 ms).", ""]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join(L) + "\n")
    print("\n".join(L))
    print(f"({time.perf_counter() - t0:.0f} s) wrote {OUT}")


if __name__ == "__main__":
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        main()
