"""The fast path with and without its log(clip − lower bound) coordinates, against an accurate
MCMC reference, on simulated Gpixel ROIs (``bayescap.batch.gpixel_sensors(seed=1)``).

    python benchmarks/fast_clip_coordinates.py 11 0 3 8      # ROI indices; ~2-4 min each (the reference)

Per ROI: the accurate reference (seed 7) and whether it converged; the fast path (seed 1, no
fallback) in the model's coordinates (``x``) and in ``LogClipCoordinates`` (``z``): k̂, accepted,
and the worst 95 % interval endpoint error over every parameter as a fraction of the reference's
width; the standard MCMC preset (seed 2) measured the same way."""
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import bayescap
from bayescap.inference import fast
from bayescap.batch import gpixel_sensors

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed_accuracy import errors_vs_ref  # noqa: E402


def worst_endpoint_error(r, ref):
    """(error, quantity): speed_accuracy's endpoint error over every physical parameter, the clip
    level included (speed_accuracy.quantiles leaves it out; here it is the quantity at stake)."""
    q = {n: np.quantile(x, [0.025, 0.5, 0.975]) for n, x in r.draws.items()}
    qref = {n: np.quantile(x, [0.025, 0.5, 0.975]) for n, x in ref.draws.items()}
    e, n, _, _ = errors_vs_ref(q, qref)
    return e, n


def main(argv=None):
    idx = [int(a) for a in (sys.argv[1:] if argv is None else argv)] or [11, 0, 3, 8]
    warnings.simplefilter("ignore")
    datas, _ = gpixel_sensors(n_max=max(idx) + 1, seed=1)
    orig = fast.LogClipCoordinates.applies
    for i in idx:
        t = time.perf_counter()
        ref = bayescap.fit(datas[i], seed=7, quality="accurate")
        t_ref = time.perf_counter() - t
        out = []
        try:
            for z in (False, True):
                fast.LogClipCoordinates.applies = staticmethod(orig) if z else staticmethod(lambda m: False)
                f = bayescap.fit(datas[i], seed=1, quality="fast", fallback=False)
                e, n = worst_endpoint_error(f, ref)
                out.append(f"{'z' if z else 'x'}: k̂ {f.diag['khat']:.2f} {'✓' if f.diag['converged'] else '✗'} "
                           f"err {e:.3f} ({n})")
        finally:
            fast.LogClipCoordinates.applies = staticmethod(orig)
        s = bayescap.fit(datas[i], seed=2, quality="standard")
        e, n = worst_endpoint_error(s, ref)
        print(f"ROI {i}: accurate reference {t_ref:.0f} s, converged {ref.diag['converged']} | " + " | ".join(out)
              + f" | standard err {e:.3f} ({n})", flush=True)


if __name__ == "__main__":
    main()
