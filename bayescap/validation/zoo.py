"""The sensor zoo: sensors nobody tuned the model to, simulated by :mod:`.framesim`, with their
truths in the fit's conventions and which of them the data can identify.

:func:`zoo` lists the sensors (hand-made edge cases from issue 37 plus a seeded random draw over
the ranges real cameras span); :func:`truths` gives each fitted parameter's truth and status:

* ``"identifiable"``: the data determine it; coverage counts it (truth inside the 95 % interval);
* ``"limit"``: the data cannot determine it; the fit must say so (``constrained: false``, an upper
  limit above the truth or a lower bound below it);
* ``"unscored"``: between the two (reported, not counted).

:func:`score` compares a fit's JSON (``FitResult.to_dict()``) with them. The conventions:
``read_noise_e`` excludes dark current (with one exposure time only ``dark_noise_e`` =
sqrt(read² + D·t) is identifiable); ``full_well_e`` is the charge at which the mean pixel's output
clips, (ADC max − black) · K for an ADC clip (a truncating ADC reads 0.5 DN low, so its black level
is 0.5 DN lower in the rounding-equivalent scale the model uses) or the mean well; ``prnu_percent``
and ``dsnu_e`` are the population values the maps are drawn from.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bayescap.validation.framesim import Acquisition, FrameSensor, clip_charge_e, simulate_rows, write_csv

__all__ = ["ZooSensor", "zoo", "truths", "score", "ensure_csv", "regime_of", "PARAMETERS"]

PARAMETERS = (
    "conversion_gain_e_per_dn",
    "read_noise_e",
    "dark_noise_e",
    "dark_current_e_per_s",
    "full_well_e",
    "quantum_efficiency",
    "prnu_percent",
    "dsnu_e",
)


@dataclass(frozen=True)
class ZooSensor:
    name: str
    sensor: FrameSensor
    acq: Acquisition
    seed: int
    tags: tuple = ()
    notes: str = ""

    @property
    def regime(self) -> str:
        return regime_of(self.sensor)

    def metadata(self) -> dict:
        s = self.sensor
        return {
            "sensor": f"zoo {self.name}",
            "adc_bits": s.adc_bits,
            "black_level_dn": round(s.black_level_dn) if s.adc == "round" else math.floor(s.black_level_dn),
            "width_px": s.width_px,
            "height_px": s.height_px,
            "manufacturer": "simulated (bayescap.validation.framesim)",
        }

    def key(self) -> str:
        blob = json.dumps([asdict(self.sensor), repr(self.acq), self.seed], sort_keys=True, default=str)
        return hashlib.sha1(blob.encode()).hexdigest()[:10]


def regime_of(s: FrameSensor) -> str:
    read_dn = s.read_noise_e / s.k_e_per_dn
    if s.adc_bits == 8:
        return "8-bit"
    if s.k_e_per_dn < 0.5 and s.read_noise_e < 1.5:
        return "photon-counting"
    if read_dn < 0.5:
        return "sub-DN"
    if s.adc_bits >= 14:
        return "scientific"
    return "typical"


# --------------------------------------------------------------------------- building sensors
_BASE_BLACK = {8: 4, 10: 64, 12: 240, 14: 800, 16: 1600}


def _black(bits, kind, read_dn, dsnu_dn, rng) -> float:
    base = max(_BASE_BLACK[bits], math.ceil(6 * math.hypot(read_dn, dsnu_dn) + 2))
    if kind == "half":
        return base + 0.5
    if kind == "rand":
        return base + float(rng.uniform(0, 1))
    return float(base)


def _make(
    name,
    bits,
    k,
    read_dn,
    *,
    seed,
    dsnu_dn=0.0,
    prnu=0.01,
    dark=20.0,
    qe=0.6,
    adc="round",
    black="int",
    clip="adc",
    well_spread=0.0,
    times="many",
    t_max=0.02,
    spatial="some",
    n_frames=2,
    levels=30,
    roi=100,
    fill=1.3,
    outliers=(),
    nonlin=0.0,
    tags=(),
    notes="",
    black_dn=None,
):
    rng = np.random.default_rng(seed + 7)
    b = float(black_dn) if black_dn is not None else _black(bits, black, read_dn, dsnu_dn, rng)
    adc_e = (2**bits - 1 - b - (0.5 if adc == "floor" else 0.0)) * k
    fw = 1.4 * adc_e if clip == "adc" else 0.8 * adc_e
    s = FrameSensor(
        k_e_per_dn=k,
        read_noise_e=read_dn * k,
        full_well_e=fw,
        quantum_efficiency=qe,
        dark_current_e_per_s=dark,
        prnu_frac=prnu,
        dsnu_e=dsnu_dn * k,
        well_spread_frac=well_spread,
        adc_bits=bits,
        black_level_dn=b,
        adc=adc,
        nonlinearity=nonlin,
        width_px=roi,
        height_px=roi,
    )
    clip_e = clip_charge_e(s)[0]
    frac = np.linspace(0.02, fill, levels) if levels > 1 else np.array([fill])
    charge = frac * clip_e
    if times == "many":
        t = t_max * frac / fill
    else:
        t = np.full(levels, t_max)
    photons = np.maximum(charge - dark * t, 0.0) / qe
    if spatial == "all":
        sp = tuple(range(levels))
    elif spatial == "some":
        sp = tuple(sorted(set(np.linspace(0, levels - 1, min(levels, 5)).round().astype(int).tolist())))
    else:
        sp = ()
    factors = {int(i) % levels: float(f) for i, f in outliers}
    acq = Acquisition(tuple(t.tolist()), tuple(photons.tolist()), sp, n_frames, factors)
    all_tags = tuple(tags) + (("one-t",) if times == "one" else ()) + (("floor",) if adc == "floor" else ())
    all_tags += ("n_frames=1",) if (sp and n_frames == 1) else ()
    all_tags += ("outliers",) if outliers else ()
    return ZooSensor(name, s, acq, seed, all_tags, notes)


def _hand() -> list[ZooSensor]:
    z = []
    a = z.append
    # issue 37's cases
    a(
        _make(
            "i37_8bit_k100_dsnu",
            8,
            100,
            0.05,
            seed=23,
            dsnu_dn=0.3,
            dark=10,
            black_dn=4,
            levels=40,
            t_max=0.05,
            notes="issue 37: 8-bit, K 100, DSNU 30 e-, black 4 DN",
        )
    )
    a(
        _make(
            "i37_8bit_floor_short_t",
            8,
            100,
            0.05,
            seed=24,
            dsnu_dn=0.3,
            dark=10,
            adc="floor",
            t_max=0.01,
            levels=40,
            notes="issue 37: truncating 8-bit, D.t <= 0.1 e- against 5 e- read",
        )
    )
    a(
        _make(
            "i37_10bit_read0p1_one_t",
            10,
            12,
            0.1,
            seed=25,
            dark=5,
            black="half",
            times="one",
            t_max=0.01,
            spatial="none",
            notes="issue 37: read 0.1 DN at the rounding boundary, one exposure time",
        )
    )
    a(
        _make(
            "i37_16bit_photon_counting",
            16,
            0.25,
            1.2,
            seed=26,
            dark=0.5,
            levels=40,
            notes="issue 37: photon-counting CMOS K 0.25, read 0.3 e-",
        )
    )
    a(
        _make(
            "i37_phone10_all_spatial",
            10,
            9.5,
            3 / 9.5,
            seed=27,
            dsnu_dn=0.2,
            spatial="all",
            levels=40,
            n_frames=16,
            notes="issue 37: typical phone, spatial on every row (slow case)",
        )
    )
    # photon counting / qCMOS
    a(_make("pc_k0p05_16bit", 16, 0.05, 10, seed=30, dark=0.2, prnu=0.005, fill=0.9, levels=30))
    a(_make("pc_qcmos_k0p1", 16, 0.1, 2.7, seed=31, dark=0.5, levels=30, roi=200))
    a(_make("pc_k0p3_floor", 16, 0.3, 2.0, seed=32, dark=1, adc="floor", black="rand", levels=25))
    # 8-bit
    a(
        _make(
            "b8_k200_dsnu50dn",
            8,
            200,
            0.3,
            seed=40,
            dsnu_dn=50,
            black_dn=16,
            levels=30,
            clip="well",
            notes="black level 16 DN under a 50 DN DSNU: dark pixels clip at 0 DN (a camera set up wrong; "
            "the model has no term for it and must flag it)",
        )
    )
    a(_make("b8_k40_read1", 8, 40, 1.0, seed=41, dsnu_dn=1, levels=30, adc="floor"))
    a(_make("b8_k20_half_black", 8, 20, 0.6, seed=42, black="half", levels=20, spatial="none"))
    # sub-DN and quantization boundaries
    a(_make("sub_12bit_read0p2_int", 12, 8, 0.2, seed=50, levels=40))
    a(_make("sub_12bit_read0p2_half", 12, 8, 0.2, seed=51, black="half", levels=40))
    a(_make("sub_10bit_read0p3_dsnu1", 10, 10, 0.3, seed=52, dsnu_dn=1.0, levels=40, spatial="all", n_frames=16))
    a(_make("sub_14bit_read0p4_floor", 14, 3, 0.4, seed=53, adc="floor", levels=30))
    # structure of the acquisition
    a(_make("acq_3_levels", 12, 2.0, 2.0, seed=60, levels=3, fill=1.2))
    a(_make("acq_500_levels", 12, 2.0, 2.0, seed=61, levels=500, roi=48, spatial="some"))
    a(_make("acq_roi_1000", 12, 3.0, 1.5, seed=62, levels=12, roi=1000, dsnu_dn=0.5))
    a(_make("acq_roi_32", 10, 5.0, 1.0, seed=63, levels=40, roi=32))
    a(_make("acq_one_t_light_sweep", 12, 1.5, 3.0, seed=64, times="one", t_max=0.1, dark=50))
    a(_make("acq_unsaturated_16bit", 16, 0.6, 3.0, seed=65, fill=0.5, levels=30))
    a(_make("acq_no_dark_current", 12, 2.0, 1.5, seed=66, dark=0.0))
    a(_make("acq_no_fpn", 12, 2.0, 1.5, seed=67, prnu=0.0, dsnu_dn=0.0, spatial="all"))
    a(_make("acq_well_clip_spread", 12, 1.0, 3.0, seed=68, clip="well", well_spread=0.03))
    a(_make("acq_outlier_first_row", 12, 3.5, 3.0, seed=69, outliers=((0, 0.8),), t_max=0.05))
    a(_make("acq_outlier_two_rows", 10, 6.0, 1.0, seed=70, outliers=((5, 1.04), (12, 0.95)), levels=25))
    a(_make("acq_nonlinear_1pc", 12, 2.5, 2.0, seed=71, nonlin=0.01, tags=("non-linear",)))
    a(_make("acq_nonlinear_3pc", 12, 2.5, 2.0, seed=72, nonlin=0.03, tags=("non-linear",)))
    # n_frames = 1 (single-frame total variance)
    a(_make("nf1_typical_12bit", 12, 2.0, 2.0, seed=80, n_frames=1, spatial="all", dsnu_dn=2))
    a(_make("nf1_8bit", 8, 60, 0.5, seed=81, n_frames=1, spatial="some", dsnu_dn=1))
    a(_make("nf1_phone10", 10, 9.5, 0.32, seed=82, n_frames=1, spatial="all", dsnu_dn=0.3))
    a(_make("nf1_16bit_pc", 16, 0.25, 1.2, seed=83, n_frames=1, spatial="some"))
    return z


def _drawn(n: int = 36) -> list[ZooSensor]:
    """Sensors drawn from ranges real cameras span (seeded; nobody picked the values)."""
    k_range = {8: (20, 200), 10: (2, 20), 12: (0.5, 10), 14: (0.2, 4), 16: (0.05, 2)}
    out = []
    for i in range(n):
        rng = np.random.default_rng(1000 + i)
        bits = (8, 10, 12, 14, 16)[i % 5]
        lo, hi = k_range[bits]
        k = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        read_e = float(np.exp(rng.uniform(np.log(0.3), np.log(30))))
        read_dn = float(np.clip(read_e / k, 0.05, 10))
        dsnu_dn = (
            0.0 if rng.uniform() < 0.4 else float(np.exp(rng.uniform(np.log(0.1), np.log(50 if bits >= 12 else 5))))
        )
        kw = dict(
            seed=2000 + i,
            dsnu_dn=dsnu_dn,
            prnu=float(rng.uniform(0.0, 0.02)),
            dark=float(np.exp(rng.uniform(np.log(0.1), np.log(1000)))),
            qe=float(rng.uniform(0.2, 0.9)),
            adc=("round", "floor")[int(rng.uniform() < 0.4)],
            black=("int", "half", "rand")[int(rng.integers(3))],
            clip=("adc", "well")[int(rng.uniform() < 0.4)],
            well_spread=float(rng.choice([0.0, 0.01, 0.03])),
            times=("many", "one")[int(rng.uniform() < 0.2)],
            t_max=float(np.exp(rng.uniform(np.log(1e-3), np.log(1.0)))),
            spatial=("all", "some", "none")[int(rng.integers(3))],
            n_frames=int(rng.choice([2, 16, 1], p=[0.45, 0.4, 0.15])),
            levels=int(np.exp(rng.uniform(np.log(3), np.log(120)))),
            roi=int(rng.choice([32, 64, 100, 200, 400])),
            fill=float(rng.choice([1.3, 1.5, 1.15, 0.6], p=[0.4, 0.25, 0.15, 0.2])),
            outliers=((int(rng.integers(0, 5)), float(rng.choice([0.9, 1.1]))),) if rng.uniform() < 0.15 else (),
        )
        out.append(_make(f"draw{i:02d}_{bits}bit", bits, k, read_dn, **kw))
    return out


def zoo() -> list[ZooSensor]:
    """Every zoo sensor (simulated; the real Basler set is added by the benchmark)."""
    return _hand() + _drawn()


# --------------------------------------------------------------------------- truths
def _status(z: float, hi: float = 8.0, lo: float = 1.5) -> str:
    return "identifiable" if z >= hi else ("limit" if z <= lo else "unscored")


def truths(zs: ZooSensor) -> dict:
    """{parameter: (truth, status, why)} in the fit's conventions (module docstring)."""
    s, acq = zs.sensor, zs.acq
    k, n = s.k_e_per_dn, s.width_px * s.height_px
    t = np.asarray(acq.exposure_time_s, float)
    mu_p = np.asarray(acq.photons_per_pixel, float)
    clip_e, clip_by = clip_charge_e(s)
    charge = mu_p * s.quantum_efficiency + s.dark_current_e_per_s * t
    unclipped = charge < 0.8 * clip_e
    read_dn = s.read_noise_e / k
    out = {"conversion_gain_e_per_dn": (k, "identifiable", "")}
    many_t = np.unique(t).size > 1
    dt_max = s.dark_current_e_per_s * float(t.max())
    dark_var_e2 = s.read_noise_e**2 + k**2 / 12 + dt_max + s.dsnu_e**2 * 0  # temporal only
    if many_t:
        if read_dn >= 0.5:
            out["read_noise_e"] = (s.read_noise_e, "identifiable", "")
        elif read_dn < 0.3:
            out["read_noise_e"] = (s.read_noise_e, "limit", "read noise below 0.3 DN")
        else:
            out["read_noise_e"] = (s.read_noise_e, "unscored", "read noise 0.3-0.5 DN")
        # slope of the dark variance against t, each row with relative error sqrt(2/n)
        z = dt_max / (dark_var_e2 * math.sqrt(2.0 / n)) * math.sqrt(t.size / 12.0)
        st = _status(z) if s.dark_current_e_per_s > 0 else "limit"
        out["dark_current_e_per_s"] = (s.dark_current_e_per_s, st, f"D.t_max / sd = {z:.3g}")
    else:
        dn = math.sqrt(s.read_noise_e**2 + dt_max)
        st = "identifiable" if dn / k >= 0.5 else ("limit" if dn / k < 0.3 else "unscored")
        out["dark_noise_e"] = (dn, st, "sqrt(read^2 + D.t), one exposure time")
        out["read_noise_e"] = (s.read_noise_e, "limit", "one exposure time")
        out["dark_current_e_per_s"] = (s.dark_current_e_per_s, "limit", "one exposure time")
    reach = float(charge.max()) / clip_e
    fw_status = "identifiable" if reach >= 1.1 else ("limit" if reach <= 0.7 else "unscored")
    out["full_well_e"] = (clip_e, fw_status, f"clip by {clip_by}; brightest row at {reach:.2f} of the clip")
    out["quantum_efficiency"] = (s.quantum_efficiency, "identifiable", "")
    if acq.spatial_rows:
        L = acq.n_frames
        sp = np.asarray(acq.spatial_rows, int)
        ok = sp[unclipped[sp]]
        if ok.size and s.prnu_frac > 0:
            sig_e = charge[ok] - s.dark_current_e_per_s * t[ok]
            fpn = (s.prnu_frac * sig_e) ** 2
            tvar = charge[ok] + s.read_noise_e**2 + k**2 / 12
            z = float(np.max(fpn / (fpn + tvar / L))) / math.sqrt(2.0 / n) * math.sqrt(ok.size)
            out["prnu_percent"] = (100 * s.prnu_frac, _status(z, hi=10, lo=2), f"z {z:.3g}")
        else:
            out["prnu_percent"] = (100 * s.prnu_frac, "limit", "no PRNU")
        d2 = s.dsnu_e**2
        tvar = s.read_noise_e**2 + k**2 / 12
        z = d2 / (d2 + tvar / L) / math.sqrt(2.0 / n) * math.sqrt(sp.size) if d2 > 0 else 0.0
        out["dsnu_e"] = (s.dsnu_e, _status(z, hi=10, lo=2), f"z {z:.3g}")
    return out


def _interval_check(p: dict, truth: float) -> tuple[bool, float]:
    lo, hi = p["ci95"]
    if lo is None or hi is None:
        return False, float("nan")
    inside = lo <= truth <= hi
    width = hi - lo
    dist = 0.0 if inside else (lo - truth if truth < lo else truth - hi)
    return inside, (dist / width if width > 0 else float("inf"))


def score(zs_truths: dict, result: dict) -> dict:
    """Per parameter: {"status", "truth", "inside", "miss_widths", "constrained", "verdict"}.

    verdict: ``ok`` / ``miss`` / ``MISS>3w`` for identifiable truths; for limits ``ok`` when the
    fit reports ``constrained: false`` with an upper limit above (lower bound below) the truth,
    ``detected`` when it gives a constrained 95 % interval that holds the truth (a truth whose
    expected significance is below the limit threshold can still stand out in one realisation: at
    an expected 1.1 sd, the fit's detection rule, about 2.5 sd, is passed ~8 % of the time),
    ``claims-constrained`` when that interval excludes the truth, ``limit-wrong`` when its limit
    excludes the truth; ``limited`` for an identifiable truth that the fit reports only as a lower
    limit holding it (flagged data, e.g. dark rows clipped at 0 DN); ``absent`` when the fit has no
    such parameter."""
    pars = result.get("parameters", {})
    out = {}
    for name, (truth, status, why) in zs_truths.items():
        p = pars.get(name)
        rec = {"status": status, "truth": truth, "why": why}
        if p is None:
            rec["verdict"] = "absent"
            out[name] = rec
            continue
        rec["constrained"] = p.get("constrained")
        if p.get("median") is None:
            lb = p.get("lower_bound")
            rec["inside"] = lb is not None and truth >= lb
            rec["miss_widths"] = float("nan")
        else:
            rec["inside"], rec["miss_widths"] = _interval_check(p, truth)
        if status == "limit":
            if p.get("constrained", True):
                rec["verdict"] = "detected" if rec["inside"] else "claims-constrained"
            elif "upper_limit_95" in p and truth > p["upper_limit_95"]:
                rec["verdict"] = "limit-wrong"
            elif "lower_bound" in p and p["lower_bound"] is not None and truth < p["lower_bound"]:
                rec["verdict"] = "limit-wrong"
            else:
                rec["verdict"] = "ok"
        elif (p.get("limit") or {}).get("kind") == "lower" and p.get("constrained") is False:
            # an identifiable truth the fit reports only as a lower limit (its data flagged as biased)
            rec["verdict"] = "limited" if truth >= p["limit"]["value"] else "limit-wrong"
        else:
            if rec["inside"]:
                rec["verdict"] = "ok"
            elif rec["miss_widths"] > 3:
                rec["verdict"] = "MISS>3w"
            else:
                rec["verdict"] = "miss"
        out[name] = rec
    return out


# --------------------------------------------------------------------------- files
def ensure_csv(zs: ZooSensor, folder: Path) -> Path:
    """The sensor's CSV in ``folder`` (generated once; the name carries a hash of the definition)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{zs.name}-{zs.key()}.csv"
    if not path.exists():
        rows = simulate_rows(zs.sensor, zs.acq, zs.seed)
        tmp = path.with_suffix(".tmp")
        write_csv(tmp, rows, zs.metadata())
        tmp.replace(path)
    return path
