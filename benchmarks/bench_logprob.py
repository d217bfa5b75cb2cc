"""Time of one vectorised log-probability call (128 walkers at the model's start) for the bundled and
benchmark CSVs and four sensors of the zoo whose rows need the rounding moments (8-bit, sub-DN,
phone): the number to compare before and after a likelihood change, on the same machine and load.
For the zoo sensors the same call is also timed with the moments' Fourier series off (the exact
evaluation of every element, ``bayescap.model.offset_fourier``), alternating with it, so the
speed-up is measured under the same load. With ``--baseline DIR`` (a directory holding another
version's ``bayescap`` package, e.g. ``git archive <commit> bayescap | tar -x -C DIR``) every call is
also timed with that version's code on the same draws, alternately, and the two results compared
(before/after a speed change on a loaded machine: the same load for both).

    python benchmarks/bench_logprob.py [--walkers 128] [--repeat 30] [--baseline DIR]

Writes ``benchmarks/results/bench_logprob.md`` (ms per call and ns per walker and data row)."""

import argparse
import glob
import importlib
import os
import sys
import time
from pathlib import Path

import numpy as np
from _machine import describe_machine, emit

from bayescap.io.ptc_csv import read_ptc_csv
from bayescap.model.ptc_model import PTCModel

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "bench_logprob.md"
ZOO = ("i37_phone10_all_spatial", "i37_8bit_floor_short_t", "sub_12bit_read0p2_half", "i37_8bit_k100_dsnu")


def _exact_moments(on):
    """Switch the moments' Fourier series off (``on``) or back on."""
    import bayescap.model.pixel_quantization as pq
    from bayescap.model.offset_fourier import offset_fourier_moments

    def none(delta, s, so):
        z = np.zeros(np.shape(delta), bool)
        return z, z + np.nan, z + np.nan, z + np.nan

    pq.offset_fourier_moments = none if on else offset_fourier_moments


def _best_ms(m, th, repeat, exact=None):
    """Best of 3 × ``repeat`` calls (ms); with ``exact`` given, alternating the exact moments and the
    series: (series ms, exact ms)."""
    modes = (False,) if exact is None else (False, True)
    best = dict.fromkeys(modes, np.inf)
    for _ in range(3):
        for mode in modes:
            _exact_moments(mode)
            m.log_prob(th)
            t0 = time.perf_counter()
            for _ in range(repeat):
                m.log_prob(th)
            best[mode] = min(best[mode], (time.perf_counter() - t0) / repeat * 1e3)
    _exact_moments(False)
    return tuple(best[k] for k in modes)


def _baseline_code(tree):
    """``read_ptc_csv`` and ``PTCModel`` of the ``bayescap`` package in ``tree``, imported beside this
    version's (whose modules are put back in ``sys.modules`` afterwards)."""
    mine = lambda k: k == "bayescap" or k.startswith("bayescap.")  # noqa: E731
    saved = {k: v for k, v in sys.modules.items() if mine(k)}
    for k in saved:
        del sys.modules[k]
    sys.path.insert(0, str(tree))
    try:
        read = importlib.import_module("bayescap.io.ptc_csv").read_ptc_csv
        model = importlib.import_module("bayescap.model.ptc_model").PTCModel
    finally:
        sys.path.remove(str(tree))
        for k in [k for k in sys.modules if mine(k)]:
            del sys.modules[k]
        sys.modules.update(saved)
    return read, model


def _versus_ms(m, base, th, repeat):
    """The fastest of 3 × ``repeat`` calls (ms) of ``m`` and of the baseline's model ``base`` on
    ``th``, call by call alternately (the fastest: the call least disturbed by the machine's other
    load), the median over the alternations of the baseline's time over this one's (each pair ran
    under nearly the same load); and whether the two give the same numbers bit for bit (−inf
    included) and their largest relative difference."""
    times = np.empty((3 * repeat, 2))
    for r in range(3 * repeat):
        for i, mod in enumerate((m, base)):
            t0 = time.perf_counter()
            mod.log_prob(th)
            times[r, i] = (time.perf_counter() - t0) * 1e3
    a, b = m.log_prob(th), base.log_prob(th)
    fin = np.isfinite(a) & np.isfinite(b)
    rel = float(np.max(np.abs(a[fin] - b[fin]) / np.maximum(np.abs(b[fin]), 1.0), initial=0.0))
    best = times.min(axis=0)
    return best[0], best[1], float(np.median(times[:, 1] / times[:, 0])), bool(np.array_equal(a, b)), rel


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--walkers", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--baseline", type=Path, default=None, help="a directory holding another version's bayescap")
    a = ap.parse_args(argv)
    baseline = _baseline_code(a.baseline) if a.baseline is not None else None
    files = [ROOT / "data" / "emva1288_basler_ccd12.csv"] + sorted(
        map(Path, glob.glob(str(ROOT / "data" / "benchmark" / "*.csv")))
    )
    cmd = (
        "python benchmarks/bench_logprob.py"
        + (f" --walkers {a.walkers}" if a.walkers != 128 else "")
        + (f" --repeat {a.repeat}" if a.repeat != 30 else "")
        + (f" --baseline {a.baseline}" if a.baseline is not None else "")
    )
    L = [
        "# Cost of one `PTCModel.log_prob` call",
        "",
        f"Generated by `{cmd}`; machine: {describe_machine()}; load average before the run "
        f"{os.getloadavg()[0]:.2f}. One call of {a.walkers} walkers at the model's initial guess, best of 3 × "
        f"{a.repeat} calls (zoo sensors: the walkers spread by 1e-3 about it, and the call with the exact moments "
        "timed alternately with it, under the same load).",
        "",
        "| data | rows | parameters | ms per call | ns per walker and row | ms, exact moments | speed-up |",
        "|---|---|---|---|---|---|---|",
    ]
    from bayescap.validation.zoo import ensure_csv, zoo

    zoo_files = [ensure_csv(z, ROOT / "benchmarks" / ".zoo_cache") for z in zoo() if z.name in ZOO]
    for f in files + zoo_files:
        m = PTCModel(read_ptc_csv(f))
        th = np.repeat(m.initial_guess()[None], a.walkers, 0)
        rows = len(m.data.mean_dn)
        if f in zoo_files:
            # walkers spread about the start (1e-3 in every coordinate): elements of their own
            th = th + 1e-3 * np.random.default_rng(0).normal(size=th.shape)
            best, exact = _best_ms(m, th, a.repeat, exact=True)
            name = f.name.rsplit("-", 1)[0] + " (zoo)"
            L.append(
                f"| {name} | {rows} | {m.ndim} | {best:.2f} | {best * 1e6 / (a.walkers * rows):.0f} | "
                f"{exact:.2f} | {exact / best:.1f}× |"
            )
        else:
            (best,) = _best_ms(m, th, a.repeat)
            L.append(f"| {f.name} | {rows} | {m.ndim} | {best:.2f} | {best * 1e6 / (a.walkers * rows):.0f} | | |")
    if baseline is not None:
        read_base, model_base = baseline
        L += [
            "",
            f"## Against the baseline `{a.baseline}`",
            "",
            f"The same draws as above, each call timed with this version's code and the baseline's "
            f"alternately: the fastest of 3 × {a.repeat} alternations each, their ratio, and the median "
            "over the alternations of the baseline's time over this version's (each pair ran under nearly the "
            "same load); `same bits`: the two log-probabilities "
            "equal bit for bit (−inf included), else their largest relative difference.",
            "",
            "| data | ms per call | ms, baseline | speed-up | median paired speed-up | same bits |",
            "|---|---|---|---|---|---|",
        ]
        for f in files + zoo_files:
            m, mb = PTCModel(read_ptc_csv(f)), model_base(read_base(f))
            th = np.repeat(m.initial_guess()[None], a.walkers, 0)
            if f in zoo_files:
                th = th + 1e-3 * np.random.default_rng(0).normal(size=th.shape)
            new, old, ratio, same, rel = _versus_ms(m, mb, th, a.repeat)
            name = f.name.rsplit("-", 1)[0] + " (zoo)" if f in zoo_files else f.name
            L.append(
                f"| {name} | {new:.2f} | {old:.2f} | {old / new:.2f}× | {ratio:.2f}× | "
                f"{'yes' if same else f'no ({rel:.1e})'} |"
            )
    emit(L, OUT)


if __name__ == "__main__":
    main()
