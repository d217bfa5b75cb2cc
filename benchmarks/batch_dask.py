"""The batch on a Dask cluster against the local process pool (issue 41).

The first ``--n`` ROIs of ``bayescap.batch.gpixel_sensors(seed=1)`` (32 × 32 pixels, 30 levels),
fast preset with the MCMC fallback, seed 1, fitted three ways on this machine:

1. ``fit_many(datas, n_jobs=2, summary_only=True)``: the local batch, every result kept in memory;
2. ``fit_many(datas, n_jobs=2, out=DIR)``: the local pool, each ``DIR/<name>/result.json`` written as
   its chunk finishes;
3. ``fit_many(datas, client=client, out=DIR)`` on a ``LocalCluster`` of 2 single-threaded worker
   processes (started before the clock; its start-up time is given apart).

Wall times; the ratio of (3) to (1), the issue's target being 1.15 or less; and the sensors' numbers
compared between (2) and (3). The machine's load average is printed before and after: on a shared
machine, other work inflates every figure.

    python benchmarks/batch_dask.py [--n 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _machine import describe_machine, emit  # noqa: E402


def _load():
    try:
        return "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg())
    except OSError:
        return "n/a"


def _numbers(doc):
    doc = dict(doc)
    doc.pop("batch", None)
    doc["diagnostics"] = {k: v for k, v in doc["diagnostics"].items() if not k.endswith("wall_s")}
    return doc


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000, help="sensors (default 1000)")
    a = ap.parse_args(argv)
    import distributed

    from bayescap import retain_freed_memory
    from bayescap.batch import fit_many, gpixel_sensors
    from bayescap.batch.cluster import local_cluster
    from bayescap.batch.runner import _chunks

    retain_freed_memory()
    datas, _ = gpixel_sensors(n_max=a.n, seed=1)
    load0 = _load()
    tmp = Path(tempfile.mkdtemp(prefix="batch_dask_"))
    try:
        t = time.perf_counter()
        mem = fit_many(datas, seed=1, n_jobs=2, summary_only=True)
        t_mem = time.perf_counter() - t
        t = time.perf_counter()
        rep_pool = fit_many(datas, seed=1, n_jobs=2, out=tmp / "pool")
        t_pool = time.perf_counter() - t
        t = time.perf_counter()
        cluster = local_cluster(2)  # the cluster `bayescap fit --dask 2` starts
        client = distributed.Client(cluster)
        t_start = time.perf_counter() - t
        try:
            t = time.perf_counter()
            rep_dask = fit_many(datas, seed=1, client=client, out=tmp / "dask")
            t_dask = time.perf_counter() - t
        finally:
            client.close()
            cluster.close()
        load1 = _load()
        same = sum(
            _numbers(json.loads((tmp / "pool" / p["name"] / "result.json").read_text()))
            == _numbers(json.loads((tmp / "dask" / d["name"] / "result.json").read_text()))
            for p, d in zip(rep_pool, rep_dask)
            if p["status"] == d["status"] == "fitted"
        )
        n_fitted = sum(r["status"] == "fitted" for r in rep_dask)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n_fallback = sum(not r.get("accepted", True) for r in mem)
    n_err = sum("error" in r for r in mem)
    from bayescap.inference.lockstep import stack_groups
    from bayescap.model import PTCModel, select_terms

    models = [PTCModel(d, terms=select_terms(d)) for d in datas]
    groups = [ix for g in stack_groups(models) for ix in g]
    chunks = _chunks(groups, 128, 2)
    sizes = [sum(map(len, c)) for c in chunks]
    lines = [
        "# The batch on a Dask LocalCluster against the local process pool",
        "",
        f"Command: `python benchmarks/batch_dask.py --n {a.n}`  ",
        f"Machine: {describe_machine()}; dask {distributed.__version__}  ",
        f"Load average (1, 5, 15 min) before: {load0}; after: {load1} (a shared machine: other work inflates every time)",
        "",
        f"{a.n} simulated Gpixel ROIs (32 × 32 pixels, 30 levels), fast preset with the MCMC fallback "
        f"({n_fallback} sensors fell back, {n_err} errors), seed 1, 2 worker processes each way. "
        f"Tasks with `out`: {len(chunks)} chunks of {min(sizes)}–{max(sizes)} sensors "
        f"({len(groups)} stack groups) plus one task per fallback.",
        "",
        "| run | wall (s) | sensors/s | vs local in-memory |",
        "|---|---:|---:|---:|",
        f"| local pool, in memory: `fit_many(n_jobs=2, summary_only=True)` | {t_mem:.1f} | {a.n / t_mem:.1f} | 1.00 |",
        f"| local pool, written as it runs: `fit_many(n_jobs=2, out=DIR)` | {t_pool:.1f} | {a.n / t_pool:.1f} | {t_pool / t_mem:.2f} |",
        f"| Dask LocalCluster, 2 workers: `fit_many(client=..., out=DIR)` | {t_dask:.1f} | {a.n / t_dask:.1f} | {t_dask / t_mem:.2f} |",
        "",
        f"LocalCluster start-up (not in the times above): {t_start:.1f} s.  ",
        f"Dask run against the issue's target (within 15 % of the local batch): "
        f"{'met' if t_dask <= 1.15 * t_mem else 'NOT met'} ({100 * (t_dask / t_mem - 1):+.0f} %).  ",
        f"Same numbers: {same} of {n_fitted} sensors' result.json identical between the local pool and Dask "
        "(wall times aside).",
    ]
    emit(lines, HERE / "results" / "batch_dask.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
