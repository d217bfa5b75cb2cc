"""The zoo's weak-dark-ramp family and its photon-counting seeds (issue 51), simulated by
:mod:`.framesim` (independent of the likelihood) through :mod:`.zoo`'s sensor builder.

:func:`dark_family` lists sensors whose dark signal at the longest exposure, D·t_max, is 10⁻³ to 1 of
the read variance σ_read² (log-spaced), over 8-16 bit, with and without DSNU, some with a one-frame
spatial variance (``n_frames = 1``): the gains, read noises and exposure times are drawn (seeded)
from the ranges real cameras span, so nobody picked the values. :func:`score_dark` says whether a
fit's dark current holds the truth (inside its 95 % interval, or below its printed upper limit) and
whether it claims a detection where the data cannot make one (D·t_max below
:data:`INVISIBLE_RATIO` of σ_read²).

:func:`photon_counting_seeds` lists photon-counting sensors (K < 1 e⁻/DN) each over many seeds of
the frames, for the conversion gain's coverage. Every sensor is scored on its other parameters by
:func:`bayescap.validation.zoo.score`.
"""

from __future__ import annotations

import math

import numpy as np

from bayescap.validation.zoo import ZooSensor, _make

__all__ = ["dark_family", "dark_ratio", "score_dark", "photon_counting_seeds", "INVISIBLE_RATIO", "K_RANGE"]

#: below this D·t_max / σ_read² a detection is never right to claim (issue 51's acceptance)
INVISIBLE_RATIO = 0.01

#: conversion gains (e⁻/DN) drawn per bit depth, as the main zoo's
K_RANGE = {8: (20, 200), 10: (2, 20), 12: (0.5, 10), 14: (0.2, 4), 16: (0.05, 2)}


def dark_family(n: int = 24) -> list[ZooSensor]:
    """``n`` weak-dark-ramp sensors, D·t_max / σ_read² log-spaced over [10⁻³, 1] (module docstring).

    Sensor i: bit depth (8, 10, 12, 14, 16)[i % 5]; DSNU of 0.5-3 DN on odd i; a one-frame spatial
    variance on every row when i % 3 == 2 (spatial columns on five rows otherwise, two-frame
    averages); K log-uniform over :data:`K_RANGE`, read noise log-uniform over 1-10 e⁻ but at least
    0.05 DN with DSNU and 0.3 DN without (every pixel at one offset far below a DN is the all-zero
    dark-variance regime, over 10 minutes a fit: ``benchmarks/subdn_speed.py``), t_max log-uniform over
    5-50 ms, 30 exposure times up to t_max."""
    out = []
    for i in range(n):
        rng = np.random.default_rng(5100 + i)
        ratio = 10.0 ** (-3.0 + 3.0 * i / max(n - 1, 1))
        bits = (8, 10, 12, 14, 16)[i % 5]
        lo, hi = K_RANGE[bits]
        k = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        read_e = float(np.exp(rng.uniform(np.log(1.0), np.log(10.0))))
        t_max = float(np.exp(rng.uniform(np.log(0.005), np.log(0.05))))
        dsnu_dn = float(rng.uniform(0.5, 3.0)) if i % 2 else 0.0
        read_dn = max(read_e / k, 0.05 if dsnu_dn else 0.3)
        read_e = read_dn * k
        dark = ratio * read_e**2 / t_max
        nf1 = i % 3 == 2
        out.append(
            _make(
                f"dark{i:02d}_{bits}bit_r{ratio:.0e}".replace("e-0", "e-"),
                bits,
                k,
                read_dn,
                seed=5200 + i,
                dsnu_dn=dsnu_dn,
                dark=dark,
                t_max=t_max,
                levels=30,
                spatial="all" if nf1 else "some",
                n_frames=1 if nf1 else 2,
                tags=("weak-dark",),
                notes=f"D.t_max = {ratio:.2g} of the read variance ({dark * t_max:.3g} e- against {read_e**2:.3g} e-2)",
            )
        )
    return out


def dark_ratio(zs: ZooSensor) -> float:
    """D·t_max / σ_read² of a zoo sensor (inf without read noise)."""
    s = zs.sensor
    t_max = float(max(zs.acq.exposure_time_s))
    return s.dark_current_e_per_s * t_max / s.read_noise_e**2 if s.read_noise_e > 0 else math.inf


def score_dark(zs: ZooSensor, result: dict) -> dict:
    """The dark current of a fit's JSON against the truth: ``{"truth", "ratio", "reported"
    ("detection" | "limit" | "absent"), "holds" (inside the 95 % interval, or below the upper limit),
    "false_detection" (a detection where D·t_max < INVISIBLE_RATIO·σ_read²), "verdict"}``; verdict
    ``ok`` when it holds the truth and claims no false detection, else ``false-detection``,
    ``limit-wrong`` (a limit below the truth) or ``miss`` (an interval that excludes it)."""
    truth = zs.sensor.dark_current_e_per_s
    ratio = dark_ratio(zs)
    p = (result.get("parameters") or {}).get("dark_current_e_per_s")
    rec = {"truth": truth, "ratio": ratio}
    if p is None:
        rec.update(reported="absent", holds=False, false_detection=False, verdict="absent")
        return rec
    lim = p.get("limit") or {}
    if p.get("constrained") is False and lim.get("kind") == "upper":
        rec["reported"] = "limit"
        rec["value"] = lim["value"]
        rec["holds"] = truth <= lim["value"]
        rec["false_detection"] = False
    else:
        lo, hi = p["ci95"]
        rec["reported"] = "detection"
        rec["interval"] = [lo, hi]
        rec["median"] = p["median"]
        rec["holds"] = lo is not None and hi is not None and lo <= truth <= hi
        rec["false_detection"] = ratio < INVISIBLE_RATIO
    if rec["false_detection"]:
        rec["verdict"] = "false-detection"
    elif rec["holds"]:
        rec["verdict"] = "ok"
    else:
        rec["verdict"] = "limit-wrong" if rec["reported"] == "limit" else "miss"
    return rec


def photon_counting_seeds(n_seeds: int = 24) -> list[ZooSensor]:
    """Photon-counting sensors (K < 1 e⁻/DN), each over seeds of its frames: issue 37's/51's 16-bit
    K 0.25 e⁻/DN, read 0.3 e⁻ sensor (40 exposure times) on ``n_seeds`` seeds, and a qCMOS-like
    K 0.1 e⁻/DN, read 0.27 e⁻ one and a truncating K 0.5 e⁻/DN, read 0.8 e⁻ one on half as many."""
    out = []
    for j in range(n_seeds):
        out.append(_make(f"pc_k0p25_s{j:02d}", 16, 0.25, 1.2, seed=6000 + j, dark=0.5, levels=40))
    for j in range(n_seeds // 2):
        out.append(_make(f"pc_k0p1_s{j:02d}", 16, 0.1, 2.7, seed=6100 + j, dark=0.5, levels=30))
        out.append(
            _make(
                f"pc_k0p5_floor_s{j:02d}", 16, 0.5, 1.6, seed=6200 + j, dark=1.0, adc="floor", black="rand", levels=30
            )
        )
    return out
