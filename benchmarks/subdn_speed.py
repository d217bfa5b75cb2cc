"""Fit times of 8-bit sensors whose read noise is far below one DN, and the rounding moments' tiers.

    python benchmarks/subdn_speed.py              # writes benchmarks/results/subdn_speed.md
    python benchmarks/subdn_speed.py --grid       # the same with the boundary tier switched off
                                                  # (the exact periodic grid; printed only)

The zoo sensors ``draw25_8bit`` (K 132 e⁻/DN, read noise 0.05 DN, black level 4 DN, no spatial
columns) and ``draw20_8bit`` (K 76, read noise 0.05 DN, spatial columns on 5 rows) are simulated
by :func:`bayescap.validation.zoo.ensure_csv` (cached in ``benchmarks/.zoo_cache/``) and fitted with
``bayescap.fit(csv, seed=1)`` at ``fast`` and ``standard`` quality (imports excluded by a first fit
of the Basler CSV), each fit timed alone. For each fit: the wall time, the elements that
:func:`~bayescap.model.pixel_quantization._quantized_pixel_moments` received, how many of them each
tier served (the periodic grid by its size M), the time inside it (these three in the fitting
process only: the MCMC's worker processes are not counted), and the posterior medians and
95 % intervals of K and the read noise. ``--grid`` forces the exact grid (the boundary tier serves
nothing), for the before/after comparison of both the times and the numbers.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "subdn_speed.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache"
BASLER = ROOT / "data" / "emva1288_basler_ccd12.csv"
SENSORS = ("draw25_8bit", "draw20_8bit")
QUANTITIES = ("conversion_gain_e_per_dn", "read_noise_e")


class _Tally:
    """Wraps the moments' entry point and the grid, counting elements and time per tier."""

    def __init__(self, PQ):
        self.PQ = PQ
        self.calls = 0
        self.elements = 0
        self.seconds = 0.0
        self.grid = Counter()
        self.boundary = 0
        self._moments = PQ._quantized_pixel_moments
        self._grid = PQ._grid_moments
        self._boundary = PQ.boundary_moments

    def install(self, boundary_off=False):
        PQ, tally = self.PQ, self

        def moments(delta, s, so, exact=False):
            t = time.perf_counter()
            out = tally._moments(delta, s, so, exact)
            tally.seconds += time.perf_counter() - t
            tally.calls += 1
            tally.elements += np.size(delta)
            return out

        def grid(delta, s, so, at, M, V, E4, H):
            tally.grid[int(M)] += at.size
            return tally._grid(delta, s, so, at, M, V, E4, H)

        def boundary(delta, s, so):
            out = tally._boundary(delta, s, so)
            if boundary_off:
                out = (np.zeros_like(out[0]),) + out[1:]
            tally.boundary += int(out[0].sum())
            return out

        import bayescap.model.prediction as P

        P._quantized_pixel_moments = moments
        PQ._grid_moments = grid
        PQ.boundary_moments = boundary

    def reset(self):
        self.calls = self.elements = self.boundary = 0
        self.seconds = 0.0
        self.grid = Counter()


def _interval(d, q):
    p = d["parameters"].get(q) or d.get("derived", {}).get(q)
    if not p:
        return "–"
    lo, hi = p["ci95"]
    return f"{p['median']:.4g} [{lo:.4g}, {hi:.4g}]"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", action="store_true", help="switch the boundary tier off (printed only)")
    ap.add_argument("--only", default=None, help="sensor name (draw25_8bit or draw20_8bit)")
    ap.add_argument("--quality", default="fast,standard")
    a = ap.parse_args(argv)

    from _machine import describe_machine, emit

    import bayescap
    import bayescap.model.pixel_quantization as PQ
    from bayescap.validation.zoo import ensure_csv, zoo

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bayescap.fit(str(BASLER), seed=1, quality="fast")
    tally = _Tally(PQ)
    tally.install(boundary_off=a.grid)
    sensors = [z for z in zoo() if z.name in SENSORS and (a.only is None or z.name == a.only)]
    rows = []
    for z in sensors:
        path = ensure_csv(z, CACHE)
        for quality in a.quality.split(","):
            tally.reset()
            t = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = bayescap.fit(str(path), seed=1, quality=quality)
            wall = time.perf_counter() - t
            d = res.to_dict()
            grid = ", ".join(f"{m}: {n}" for m, n in sorted(tally.grid.items())) or "none"
            dg = d["diagnostics"]
            how = dg["method"] + ("" if dg.get("fast_path_accepted", True) else " (fast path rejected)")
            how += "" if dg.get("converged") else ", NOT CONVERGED"
            if dg.get("n_rounds"):
                how += (
                    f", {dg['n_ensembles']}×{dg['n_walkers']} walkers × {dg['n_steps']} steps, {dg['n_rounds']} rounds"
                )
            rows.append(
                f"| {z.name} | {quality} | {how} | {wall:.1f} | {tally.seconds:.1f} | {tally.calls} | {tally.elements} | "
                f"{tally.boundary} | {grid} | " + " | ".join(_interval(d, q) for q in QUANTITIES) + " |"
            )
            print(rows[-1], flush=True)
    try:
        load = " / ".join(f"{x:.1f}" for x in __import__("os").getloadavg())
    except OSError:
        load = "?"
    lines = [
        "# Sub-DN read noise: fit times and the rounding moments' tiers",
        "",
        "`python benchmarks/subdn_speed.py`" + (" `--grid` (boundary tier off: the exact grid)" if a.grid else ""),
        "",
        f"Machine: {describe_machine()}; load average at the end {load} (timings under that load).",
        "",
        "| sensor | quality | method | wall s | in moments s | calls | elements | boundary tier | grid elements by M | "
        + " | ".join(f"{q} median [95 %]" for q in QUANTITIES)
        + " |",
        "|---|---|---|---|---|---|---|---|---|" + "---|" * len(QUANTITIES),
        *rows,
    ]
    emit(lines, None if (a.grid or a.only or a.quality != "fast,standard") else OUT)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
