"""Where a fit's time goes: cProfile of one fit (or a batch), in one process.

    python benchmarks/profile_fit.py [--sensor basler|<quantization_regime label>|rois:N]
                                     [--quality standard|fast] [--repeat R] [--top K]

``basler``: the bundled CSV; a label of ``benchmarks/quantization_regime.py`` (``sbc-35``, ``sbc-s68``,
...): that sensor simulated as that script does; ``rois:N``: ``bayescap.batch.fit_many`` over the first N
simulated Gpixel ROIs (seed 1, no fallback). The fit runs once untimed (imports, caches), then R times
under cProfile with ``BAYESCAP_JOBS=1`` (the ensembles in this process, so their time is seen). Prints
the wall time of the profiled runs, the functions by their own time (``tottime``; numpy and scipy
ufuncs count in their caller's), and how much of it is in ``bayescap/model.py`` (the likelihood).
Profiling inflates many small calls: use it for shares, the other scripts for times
(docs/performance.md, "2026-11-25, 03:06–")."""
import argparse
import cProfile
import os
import pstats
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def _run_fn(sensor, quality):
    import bayescap

    if sensor == "basler":
        data = bayescap.load(str(ROOT / "data" / "emva1288_basler_ccd12.csv"))
        return lambda: bayescap.fit(data, seed=1, quality=quality)
    if sensor.startswith("rois:"):
        from bayescap.batch import fit_many, gpixel_sensors

        datas, _ = gpixel_sensors(n_max=int(sensor.split(":", 1)[1]), seed=1)
        return lambda: fit_many(datas, seed=1, n_jobs=1, fallback=False)
    from bayescap.simulate import SensorTruth, simulate_ptc
    from quantization_regime import SENSORS

    for i, (label, kw, spatial) in enumerate(SENSORS):
        if label == sensor:
            data = simulate_ptc(SensorTruth(**kw), seed=1000 + i, spatial_frames=8 if spatial else 0,
                                spatial_every=5 if spatial else 0)
            return lambda: bayescap.fit(data, seed=1, quality=quality)
    raise SystemExit(f"unknown sensor {sensor!r}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensor", default="basler")
    ap.add_argument("--quality", default="standard", choices=("standard", "fast"))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--top", type=int, default=20)
    a = ap.parse_args(argv)
    os.environ["BAYESCAP_JOBS"] = "1"
    warnings.simplefilter("ignore")
    run = _run_fn(a.sensor, a.quality)
    run()
    pr = cProfile.Profile()
    t0 = time.perf_counter()
    pr.enable()
    for _ in range(a.repeat):
        run()
    pr.disable()
    wall = (time.perf_counter() - t0) / a.repeat
    st = pstats.Stats(pr)
    rows = sorted(((tt, f"{Path(f).name}:{line}({fn})", nc) for (f, line, fn), (_, nc, tt, _, _) in st.stats.items()),
                  reverse=True)
    total = sum(r[0] for r in rows)
    model = sum(r[0] for r in rows if r[1].startswith("model.py"))
    what = "fast (fit_many)" if a.sensor.startswith("rois:") else a.quality
    print(f"{a.sensor}, {what}: {wall:.3f} s a run under cProfile; own time {total / a.repeat:.3f} s, "
          f"of which bayescap/model.py {model / a.repeat:.3f} s ({100 * model / total:.0f} %)")
    for tt, name, nc in rows[:a.top]:
        print(f"{tt / a.repeat * 1e3:9.1f} ms {nc // a.repeat:8d} calls  {name}")


if __name__ == "__main__":
    main()
