"""Where the fast path's time goes, and what is left when the likelihood alone is counted.

    python benchmarks/fast_budget.py [--n-sim 10] [--repeat 5] [--speedup 2.4]

For the bundled Basler CCD and the ``n_sim`` simulated sensors of ``speed_accuracy.py``
(``sensor_set``), runs ``bayescap.inference.fast.fast_posterior`` ``repeat`` times as
``bayescap.fit(quality="fast")`` runs it (the model of ``PTCModel.for_fit``, the result's derived
quantities as ``derived_fn``, whose interval ends the top-up covers too; one thread for BLAS, as
``fast_posterior`` sets; ``log_prob``'s own split of large calls over two threads as in a fit) and
keeps the fastest run. In it every ``PTCModel.log_prob`` call and every call of the derived
quantities (capacity, TR, DR, the linearity error, ...) is timed and put in the phase it was made
in: the optimiser (``laplace_start``: Newton's method and its finite-difference Hessians), the
tail probe (``_tail_probe``) and the importance draws (everything after). The rest of each phase is
the fast path's own work (proposals, Pareto smoothing, the interval-end tables, resampling).

The table's last columns are two lower bounds on the fast path's time with its present algorithm
and number of draws: the ``log_prob`` calls alone (every other step free), and the whole path with
``log_prob`` ``speedup`` times cheaper and nothing else changed (2.4: what a compiled loop with
glibc's SIMD ``exp``/``log`` gained over numpy on the likelihood's largest block, measured on this
machine). Writes ``benchmarks/results/fast_budget.md`` and prints it."""

import argparse
import contextlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _machine import emit  # noqa: E402
from speed_accuracy import machine, sensor_set  # noqa: E402

import bayescap.inference.fast as fast  # noqa: E402
from bayescap.api import _result_kw, mtf_from_metadata  # noqa: E402
from bayescap.model.ptc_model import PTCModel  # noqa: E402
from bayescap.posterior import FitResult  # noqa: E402

OUT = ROOT / "benchmarks" / "results" / "fast_budget.md"


class Recorder:
    """Times every ``PTCModel.log_prob`` call and files it under the current phase."""

    def __init__(self):
        self.phase = "importance"
        self.calls = []  # (phase, rows, seconds)

    @contextlib.contextmanager
    def installed(self):
        orig_lp, orig_start, orig_probe = PTCModel.log_prob, fast.laplace_start, fast._tail_probe
        rec = self

        def log_prob(model, theta, *a, **k):
            t = time.perf_counter()
            out = orig_lp(model, theta, *a, **k)
            rec.calls.append((rec.phase, int(np.atleast_2d(theta).shape[0]), time.perf_counter() - t))
            return out

        def in_phase(name, fn):
            def wrapped(*a, **k):
                before, rec.phase = rec.phase, name
                t = time.perf_counter()
                try:
                    return fn(*a, **k)
                finally:
                    rec.calls.append((name + ":wall", 0, time.perf_counter() - t))
                    rec.phase = before

            return wrapped

        PTCModel.log_prob = log_prob
        fast.laplace_start = in_phase("optimiser", orig_start)
        fast._tail_probe = in_phase("probe", orig_probe)
        try:
            yield self
        finally:
            PTCModel.log_prob, fast.laplace_start, fast._tail_probe = orig_lp, orig_start, orig_probe


class TimedDerived:
    """The result's derived quantities (``FitResult.derived_values_fn``), each call timed into
    ``rec`` as the phase ``derived`` (of each draw alone, as the wrapped function is)."""

    def __init__(self, fn, rec):
        self.fn, self.rec = fn, rec
        self.per_draw = getattr(fn, "per_draw", False)

    def __call__(self, x):
        t = time.perf_counter()
        out = self.fn(x)
        self.rec.calls.append(("derived", int(np.atleast_2d(x).shape[0]), time.perf_counter() - t))
        return out


def as_in_a_fit(data, seed):
    """The model and derived quantities ``bayescap.fit(data, quality="fast", seed=seed)`` hands the fast path."""
    m = PTCModel.for_fit(data)
    kw = _result_kw(m.data, mtf=mtf_from_metadata(m.data.metadata, []), scene=None, seed=seed)
    return m, FitResult.derived_values_fn(m, **kw)


def budget(data, seed, repeat):
    """The fastest of ``repeat`` fast paths on ``data``, split by phase (times in ms)."""
    best = None
    for _ in range(repeat):
        rec = Recorder()
        m, dfn = as_in_a_fit(data, seed)
        with rec.installed():
            t = time.perf_counter()
            _, dg = fast.fast_posterior(m, seed=seed, derived_fn=TimedDerived(dfn, rec))
            wall = time.perf_counter() - t
        if best is None or wall < best[0]:
            best = (wall, rec.calls, dg)
    wall, calls, dg = best
    row = {"wall": wall * 1e3, "draws": dg["n_proposals"], "accepted": dg["accepted"]}
    for ph in ("optimiser", "probe"):
        lp = sum(s for p, _, s in calls if p == ph)
        row[ph + "_lp"], row[ph + "_calls"] = lp * 1e3, sum(1 for p, _, _ in calls if p == ph)
        row[ph + "_wall"] = sum(s for p, _, s in calls if p == ph + ":wall") * 1e3
    row["is_lp"] = sum(s for p, _, s in calls if p == "importance") * 1e3
    row["is_rows"] = sum(n for p, n, _ in calls if p == "importance")
    row["derived"] = sum(s for p, _, s in calls if p == "derived") * 1e3
    row["derived_rows"] = sum(n for p, n, _ in calls if p == "derived")
    row["lp"] = row["optimiser_lp"] + row["probe_lp"] + row["is_lp"]
    row["is_wall"] = row["wall"] - row["optimiser_wall"] - row["probe_wall"] - row["derived"]
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-sim", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--speedup",
        type=float,
        default=2.4,
        help="log_prob this many times cheaper for the last column (a compiled loop's gain over numpy)",
    )
    a = ap.parse_args(argv)
    import arviz  # noqa: F401  (imports kept out of the timings)

    rows = []
    for i, (name, d, _) in enumerate(sensor_set(a.n_sim)):
        m, dfn = as_in_a_fit(d, a.seed + i)
        fast.fast_posterior(m, seed=a.seed + i, derived_fn=dfn)  # warm-up: caches, first calls
        r = budget(d, a.seed + i, a.repeat)
        r["name"] = name
        rows.append(r)
        print(f"{name}: {r['wall']:.0f} ms", flush=True)
    x = a.speedup
    L = [
        "# The fast path's time budget",
        "",
        f"Generated by `python benchmarks/fast_budget.py --n-sim {a.n_sim} --repeat {a.repeat} --speedup {x:g}`; "
        f"{machine()}. `fast_posterior` as `bayescap.fit(quality='fast')` runs it (`PTCModel.for_fit`, "
        f"the result's derived quantities as `derived_fn`), default `FastSettings`, seed {a.seed} + i; the "
        f"fastest of {a.repeat} runs a sensor. "
        "`lp`: the `PTCModel.log_prob` calls of the phase (ms); `own`: the rest of the phase (ms); "
        "`derived`: the derived quantities' calls (ms, and the draws they were computed on).",
        "",
        "| sensor | fast_posterior ms | optimiser lp / own (calls) | tail probe lp / own | importance draws: lp (draws) / own "
        f"| derived (draws) | log_prob share | bound: log_prob alone | bound: log_prob {x:g}× cheaper |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        L.append(
            f"| {r['name']} | {r['wall']:.0f} | {r['optimiser_lp']:.0f} / {r['optimiser_wall'] - r['optimiser_lp']:.0f} "
            f"({r['optimiser_calls']}) | {r['probe_lp']:.0f} / {r['probe_wall'] - r['probe_lp']:.0f} "
            f"| {r['is_lp']:.0f} ({r['is_rows']}) / {r['is_wall'] - r['is_lp']:.0f} "
            f"| {r['derived']:.0f} ({r['derived_rows']}) | {r['lp'] / r['wall']:.0%} "
            f"| {r['lp']:.0f} | {r['wall'] - r['lp'] * (1 - 1 / x):.0f} |"
        )
    med = lambda k: float(np.median([r[k] for r in rows]))
    bound = [r["wall"] - r["lp"] * (1 - 1 / x) for r in rows]
    L += [
        "",
        f"Median over the {len(rows)} sensors: fast_posterior {med('wall'):.0f} ms, of which log_prob "
        f"{med('lp'):.0f} ms ({np.median([r['lp'] / r['wall'] for r in rows]):.0%}) and the derived quantities "
        f"{med('derived'):.0f} ms (largest {max(r['derived'] for r in rows):.0f} ms); with log_prob {x:g}× cheaper "
        f"{np.median(bound):.0f} ms ({min(bound):.0f}–{max(bound):.0f}); "
        f"sensors whose log_prob calls alone take ≥ 50 ms: {sum(r['lp'] >= 50 for r in rows)}/{len(rows)}.",
    ]
    emit(L, OUT)


if __name__ == "__main__":
    main()
