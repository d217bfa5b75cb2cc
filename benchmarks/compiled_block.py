"""Would a compiled likelihood be faster here? The robust gamma block, three ways.

    python benchmarks/compiled_block.py

The robust gamma block of ``bayescap.model.PTCModel._block_loglik`` (the gamma log density with its
Stirling term, the outlier component and ``_logaddexp``: ~36 % of a 6 000-draw Basler ``log_prob``
call) on 6 000 draws × 51 rows of synthetic inputs (ratios 0.9-1.1, gamma shapes 200-50 000):

* numpy float64, as bayescap computes it;
* a fused loop compiled by numba, when numba is importable (it is not a bayescap dependency: install
  it in another environment, e.g. ``python3 -m venv /tmp/nb && /tmp/nb/bin/pip install numba scipy``
  and run this script with that interpreter; ``numba -s`` says whether SVML is operational);
* the same loop in C, compiled here with gcc when ``gcc`` is on the PATH, twice: with ``-ffast-math``
  (which lets gcc call glibc's SIMD ``exp``/``log``/``log1p`` of libmvec, AVX-512 where the CPU has
  it) and without (scalar libm calls, as numba makes them); loaded with ctypes from a temporary
  directory, nothing kept. This is the most a hand-written compiled likelihood could gain on this
  block, with the error ``-ffast-math`` costs;
* numpy float32, with its error against float64 per element and on a 51-row sum.

Best of 5 × 20 calls, one thread. Prints the figures (docs/performance.md, "2026-11-25, 03:06–")."""
import ctypes
import shutil
import subprocess
import sys
import tempfile
import time
from math import exp, log, log1p
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bayescap.model import ptc_model as M  # noqa: E402

LOG_2PI, REL, RATE, BADC = M._LOG_2PI, M.OUTLIER_REL_SD, M.OUTLIER_RATE, M._BAD_GAMMA_CONST


def numpy_block(obs, model, shape):
    good, lr = M._gamma_logpdf_and_log_ratio(obs, model, shape)
    bad = (-0.5 / REL**2) * lr * lr + BADC
    return M._logaddexp(np.log1p(-RATE) + good, bad) - np.log(obs)


def numpy32_block(o, m, k):
    one = np.float32(1)
    d = o / m - one
    lr = np.log1p(d)
    inv = one / k
    st = (np.float32(0.5) * np.log(k) - np.float32(0.5 * LOG_2PI)
          - inv * (np.float32(1 / 12) - inv * inv * np.float32(1 / 360)))
    a = np.float32(np.log1p(-RATE)) + k * (lr - d) + st
    bad = np.float32(-0.5 / REL**2) * lr * lr + np.float32(BADC)
    top = np.maximum(a, bad)
    return top + np.log(one + np.exp(-np.minimum(np.abs(a - bad), np.float32(50)))) - np.log(o)


def fused_loop(obs, model, shape, out):
    n, m = model.shape
    l1r = log1p(-RATE)
    for i in range(n):
        for j in range(m):
            k = shape[i, j]
            v = obs[0, j]
            d = v / model[i, j] - 1.0
            lr = log1p(d)
            inv = 1.0 / k
            a = l1r + k * (lr - d) + 0.5 * log(k) - 0.5 * LOG_2PI - inv * (1.0 / 12.0 - inv * inv * (1.0 / 360.0))
            bad = (-0.5 / (REL * REL)) * lr * lr + BADC
            top = a if a > bad else bad
            out[i, j] = top + log(1.0 + exp(-min(abs(a - bad), 50.0))) - log(v)
    return out


C_SOURCE = r"""
#include <math.h>
void block(const double *obs, const double *model, const double *shape, double *out, long n, long m,
           double l1r, double rel, double badc, double log2pi) {
  for (long i = 0; i < n; i++) {
    const double *mo = model + i * m, *sh = shape + i * m; double *o = out + i * m;
    #pragma omp simd
    for (long j = 0; j < m; j++) {
      double k = sh[j], v = obs[j];
      double d = v / mo[j] - 1.0;
      double lr = log1p(d);
      double inv = 1.0 / k;
      double a = l1r + k * (lr - d) + 0.5 * log(k) - 0.5 * log2pi - inv * (1.0 / 12.0 - inv * inv * (1.0 / 360.0));
      double bad = (-0.5 / (rel * rel)) * lr * lr + badc;
      double top = a > bad ? a : bad;
      double df = fabs(a - bad);
      df = df < 50.0 ? df : 50.0;
      o[j] = top + log(1.0 + exp(-df)) - log(v);
    }
  }
}
"""
C_BUILDS = {   # label -> gcc flags
    "-O3 -march=native -ffast-math (libmvec SIMD)":
        ["-O3", "-march=native", "-mprefer-vector-width=512", "-ffast-math", "-fopenmp-simd"],
    "-O3 -march=native (scalar libm)": ["-O3", "-march=native", "-fno-math-errno", "-fopenmp-simd"],
}


def c_blocks(tmp):
    """{label: callable(obs, model, shape, out)} of the C loop built with each of C_BUILDS ({} without gcc)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return {}
    src = Path(tmp) / "block.c"
    src.write_text(C_SOURCE)
    P = ctypes.POINTER(ctypes.c_double)
    out = {}
    for i, (label, flags) in enumerate(C_BUILDS.items()):
        lib_path = Path(tmp) / f"block{i}.so"
        r = subprocess.run([gcc, *flags, "-shared", "-fPIC", str(src), "-o", str(lib_path), "-lm", "-lmvec"],
                           capture_output=True, text=True)
        if r.returncode != 0:
            print(f"C {label}: gcc failed: {r.stderr.strip()[:200]}")
            continue
        lib = ctypes.CDLL(str(lib_path))
        lib.block.argtypes = [P, P, P, P, ctypes.c_long, ctypes.c_long] + [ctypes.c_double] * 4
        simd = sorted({ln.split("<")[1].split(">")[0] for ln in subprocess.run(
            ["objdump", "-d", str(lib_path)], capture_output=True, text=True).stdout.splitlines()
            if "call" in ln and "<_ZGV" in ln}) if shutil.which("objdump") else []

        def fn(obs, model, shape, res, lib=lib):
            n, m = model.shape
            lib.block(*(a.ctypes.data_as(P) for a in (obs, model, shape, res)), n, m,
                      float(np.log1p(-RATE)), REL, BADC, LOG_2PI)

        out[label + (f" [calls {', '.join(s.split('@')[0] for s in simd)}]" if simd else "")] = fn
    return out


def best_ms(f, repeat=20):
    best = np.inf
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(repeat):
            f()
        best = min(best, (time.perf_counter() - t) / repeat)
    return best * 1e3


def main():
    rng = np.random.default_rng(0)
    n, m = 6000, 51
    obs = rng.uniform(0.5, 2.0, (1, m)) * 100.0
    model = obs * rng.uniform(0.9, 1.1, (n, m))
    shape = rng.uniform(200, 5e4, (n, m))
    ref = numpy_block(obs, model, shape)
    t64 = best_ms(lambda: numpy_block(obs, model, shape))
    print(f"numpy float64: {t64:.2f} ms ({t64 / ref.size * 1e6:.1f} ns an element)")
    try:
        import numba
    except ImportError:
        print("numba: not importable here (see the module docstring)")
    else:
        for fm in (False, True):
            fn = numba.njit(fastmath=fm, error_model="numpy")(fused_loop)
            out = np.empty_like(ref)
            fn(obs, model, shape, out)
            t = best_ms(lambda: fn(obs, model, shape, out))
            print(f"numba {numba.__version__} fused loop, fastmath={fm}: {t:.2f} ms ({t / ref.size * 1e6:.1f} ns), "
                  f"max |diff| {np.max(np.abs(out - ref)):.1e}")
    with tempfile.TemporaryDirectory() as tmp:
        for label, fn in c_blocks(tmp).items():
            out = np.empty_like(ref)
            fn(obs, model, shape, out)
            t = best_ms(lambda: fn(obs, model, shape, out))
            print(f"C {label}: {t:.2f} ms ({t / ref.size * 1e6:.1f} ns), max |diff| {np.max(np.abs(out - ref)):.1e} "
                  f"(relative {np.max(np.abs(out - ref) / np.abs(ref)):.1e})")
    o32, m32, k32 = (a.astype(np.float32) for a in (obs, model, shape))
    r32 = numpy32_block(o32, m32, k32)
    t32 = best_ms(lambda: numpy32_block(o32, m32, k32))
    print(f"numpy float32: {t32:.2f} ms ({t32 / ref.size * 1e6:.1f} ns); error up to {np.max(np.abs(r32 - ref)):.1e} "
          f"nats an element, {np.max(np.abs(r32.astype(float).sum(1) - ref.sum(1))):.1e} on a {m}-row sum")


if __name__ == "__main__":
    main()
