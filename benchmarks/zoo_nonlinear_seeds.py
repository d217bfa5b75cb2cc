"""The non-linear zoo on several independent simulation seeds: is a shape's coverage a seed's luck
or a bias?

    python benchmarks/run.py zoo_nonlinear_seeds      # writes benchmarks/results/zoo_nonlinear_seeds.md
    python benchmarks/zoo_nonlinear_seeds.py --seeds 5 --workers 2
    python benchmarks/zoo_nonlinear_seeds.py --only two_slope --seeds 3   # printed only

With 6 sensors (21 checks) per shape, a perfectly calibrated 95 % interval gives at most one miss
in only ~72 % of shapes, so one seed of ``benchmarks/zoo_nonlinear.py`` cannot tell a calibrated
shape from a biased one. Here every sensor of :func:`bayescap.validation.zoo_nonlinear.nonlinear_zoo`
is simulated again from ``--seeds`` independent seeds (:func:`~bayescap.validation.zoo_nonlinear.reseeded`:
new frames, not only a new MCMC seed; replicate 0 is the zoo's own seed) and fitted at ``fast`` on
all rows and on the rows below 70 % (the fast path misses the same checks as ``standard`` on the
zoo's seed). Per shape and per photons / no photons:

* checks held / total with a Wilson 95 % interval for the coverage (the target, 92 %, should be
  inside or below it; a calibrated 95 % interval gives 95 %);
* K overlap (all rows against rows below 70 %), tight misses (> 3 half-widths);
* the signed z of K, (posterior mean − truth)/posterior sd: mean and its standard error over the
  sensors × seeds, and the root mean square (≈ 1 when the interval's width matches the error;
  a mean away from 0 is a bias, an RMS above 1 intervals too narrow).

The fits and the reports reuse :mod:`zoo_nonlinear`'s ``fit_one``, ``summary_of`` and ``overlap``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "zoo_nonlinear_seeds.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache" / "nonlinear"
NOISE = ("read_noise_e", "dark_noise_e")


def wilson(k: int, n: int, z: float = 1.959963984540054):
    """Wilson score 95 % interval of a binomial proportion k/n."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def _work(job):
    """One sensor on one replicate: fast on all rows and on the rows below 70 %; CPU seconds."""
    from zoo_nonlinear import fit_one, summary_of

    from bayescap.validation.zoo_nonlinear import ensure_csvs, has_photons, reseeded, scored_truths, shape_of

    z0, rep, cache = job
    z = reseeded(z0, rep)
    c0 = time.process_time()
    p_all, p_low = ensure_csvs(z, cache)
    tr = scored_truths(z)
    row = {
        "name": z.name,
        "replicate": rep,
        "seed": z.seed,
        "shape": shape_of(z),
        "camera": z.tags[2],
        "photons": has_photons(z),
        "truths": {p: v[:2] for p, v in tr.items()},
    }
    row["standard"] = summary_of(fit_one(p_all, "fast", n_jobs=1), tr)  # the key shape_stats reads
    row["low70"] = summary_of(
        fit_one(p_low, "fast", n_jobs=1), {"conversion_gain_e_per_dn": tr["conversion_gain_e_per_dn"]}
    )
    row["cpu_s"] = time.process_time() - c0
    return row


def k_z(row):
    """(posterior mean − truth) / posterior sd of K, or None."""
    m = row["standard"].get("moments", {}).get("conversion_gain_e_per_dn")
    t = row["truths"].get("conversion_gain_e_per_dn")
    if not m or not t or m[1] <= 0:
        return None
    return (m[0] - t[0]) / m[1]


def group_line(label, rows):
    from zoo_nonlinear import shape_stats

    st, extra = shape_stats(rows)
    c, e = st["all"], extra["all"]
    held = sum(v[0] for v in c.values())
    tot = sum(v[1] for v in c.values())
    lo, hi = wilson(held, tot)
    kh, kn = c["conversion_gain_e_per_dn"]
    nh, nn = c["noise"]
    z = np.array([v for v in (k_z(r) for r in rows) if v is not None])
    zcell = (
        f"{z.mean():+.2f} ± {z.std(ddof=1) / np.sqrt(z.size):.2f} | {np.sqrt(np.mean(z**2)):.2f}"
        if z.size > 1
        else "– | –"
    )
    flag = " ⚠" if tot and hi < 0.92 else ""
    return (
        f"| {label} | {len(rows)} | **{held}/{tot} ({100 * held / tot:.1f} %)** [{100 * lo:.0f}, {100 * hi:.0f}]{flag} "
        f"| {kh}/{kn} | {nh}/{nn} | {e['ov'][0]}/{e['ov'][1]} | {e['tight']} | {zcell} |"
        + (f" ({e['failed']} failed)" if e["failed"] else "")
    )


def report(rows, note, cpu_s, wall_s, workers):
    from _machine import describe_machine
    from zoo_nonlinear import _commit

    from bayescap.validation.zoo_nonlinear import FAMILY

    reps = sorted({r["replicate"] for r in rows})
    L = [
        "# Non-linear zoo on several simulation seeds",
        "",
        f"`python benchmarks/run.py zoo_nonlinear_seeds` (this file: `python benchmarks/zoo_nonlinear_seeds.py "
        f"--seeds {len(reps)} --workers {workers}`). {len({r['name'] for r in rows})} sensors of "
        "`bayescap.validation.zoo_nonlinear` × "
        f"{len(reps)} independent simulation seeds (replicate 0 the zoo's own, r adds 100 000·r: new frames), "
        f"{len(rows)} sensor-seeds, each fitted at `fast` (fit seed 1) on all rows and on the rows below 70 % of "
        f"the top signal. Code at commit {_commit()}. CPU {cpu_s / 60:.1f} min (every worker's fits and "
        f"simulations), wall {wall_s / 60:.1f} min on {workers} worker(s). Machine: {describe_machine()}.",
        "",
        *([note, ""] if note else []),
        "Checks: K, read noise (dark noise with one exposure time), η (photon counts only) and full well, truth "
        "inside the 95 % interval (as `zoo_nonlinear.md`). The bracket is the Wilson 95 % interval of the "
        "coverage; ⚠ where it lies wholly below the 92 % target (a systematic shortfall, not a seed's luck). "
        "*z(K)* = (posterior mean − truth) / posterior sd of K over the sensor-seeds: mean ± standard error "
        "(a bias when it is several standard errors from 0) and RMS (≈ 1 for a well-calibrated width; above 1 the "
        "intervals are too narrow for the errors).",
        "",
        "## Per shape",
        "",
        "| shape | sensor-seeds | all checks [95 % CI] | K | noise | K overlap | tight misses | z(K) mean ± se | z(K) RMS |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    by = defaultdict(list)
    for r in rows:
        by[r["shape"]].append(r)
    for s in FAMILY:
        if by[s]:
            L.append(group_line(s, by[s]))
    L.append(group_line("all", rows))
    L += [
        "",
        "## Per shape, with and without photon counts",
        "",
        "| shape, photons | sensor-seeds | all checks [95 % CI] | K | noise | K overlap | tight misses | z(K) mean ± se | z(K) RMS |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in [*FAMILY, "all"]:
        for ph in (True, False):
            sub = [r for r in rows if (s == "all" or r["shape"] == s) and r["photons"] == ph]
            if sub:
                L.append(group_line(f"{s}, {'photons' if ph else 'no photons'}", sub))
    L += [
        "",
        "## Per sensor (z(K) per seed; misses listed as parameter:half-widths)",
        "",
        "| sensor | z(K) per seed | misses | K overlap | fits failed |",
        "|---|---|---|---|---|",
    ]
    from zoo_nonlinear import SHORT, overlap

    names = list(dict.fromkeys(r["name"] for r in rows))
    for n in names:
        rs = sorted((r for r in rows if r["name"] == n), key=lambda r: r["replicate"])
        zs = " ".join("–" if k_z(r) is None else f"{k_z(r):+.1f}" for r in rs)
        miss = []
        for r in rs:
            for p, rec in r["standard"].get("score", {}).items():
                if rec["status"] == "identifiable" and rec["verdict"] not in ("ok", "absent"):
                    h = rec.get("miss_half_widths")
                    miss.append(f"s{r['replicate']} {SHORT[p]}:{'?' if h is None else f'{h:.1f}'}")
        ov = [overlap(r) for r in rs]
        L.append(
            f"| {n} | {zs} | {', '.join(miss) or '–'} | {sum(bool(o) for o in ov)}/{sum(o is not None for o in ov)} "
            f"| {sum('score' not in r['standard'] for r in rs)} |"
        )
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="simulation seeds per sensor (replicates 0..N-1)")
    ap.add_argument("--workers", type=int, default=2, help="processes, one fit each at a time (fits use n_jobs=1)")
    ap.add_argument("--only", default=None, help="sensors whose name contains one of these texts; printed only")
    ap.add_argument("--quick", action="store_true", help="3 seeds")
    ap.add_argument("--cache", default=str(CACHE), help="folder of the simulated CSVs")
    ap.add_argument("--jsonl", default=None, help="every sensor-seed's record, as it runs")
    ap.add_argument("--from-log", default=None, help="write the results file from a run's --jsonl log")
    ap.add_argument("--note", default="", help="a sentence for the results file's header")
    a = ap.parse_args(argv)
    from _machine import emit

    if a.from_log:
        rows = [json.loads(line) for line in open(a.from_log)]
        meta = rows.pop(0) if rows and "meta" in rows[0] else {"meta": {}}
        m = meta["meta"]
        emit(
            report(rows, a.note, m.get("cpu_s", float("nan")), m.get("wall_s", float("nan")), m.get("workers", 0)), OUT
        )
        return 0
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from bayescap.validation.zoo_nonlinear import nonlinear_zoo

    n_seeds = 3 if a.quick else a.seeds
    only = None if a.only is None else a.only.split(",")
    sensors = [z for z in nonlinear_zoo() if only is None or any(o in z.name for o in only)]
    jobs = [(z, rep, a.cache) for rep in range(n_seeds) for z in sensors]
    jsonl = Path(a.jsonl or Path(a.cache) / "seeds_last_run.jsonl")
    jsonl.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    with open(jsonl.with_suffix(".partial"), "w") as log, ProcessPoolExecutor(a.workers) as pool:
        for r in pool.map(_work, jobs):
            s = r["standard"]
            kz = k_z(r)
            print(
                f"{r['name']:32s} s{r['replicate']} K {s.get('k')} z {'–' if kz is None else f'{kz:+.2f}'} "
                f"overlap {__import__('zoo_nonlinear').overlap(r)} cpu {r['cpu_s']:.1f}s",
                flush=True,
            )
            log.write(json.dumps(r, default=float) + "\n")
            log.flush()
            rows.append(r)
    wall = time.perf_counter() - t0
    cpu = sum(r["cpu_s"] for r in rows)
    with open(jsonl, "w") as f:
        f.write(json.dumps({"meta": {"cpu_s": cpu, "wall_s": wall, "workers": a.workers}}) + "\n")
        for r in rows:
            f.write(json.dumps(r, default=float) + "\n")
    note = a.note + (" A --quick run (3 seeds)." if a.quick else "")
    emit(report(rows, note.strip(), cpu, wall, a.workers), None if a.only else OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
