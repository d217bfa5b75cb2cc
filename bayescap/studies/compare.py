"""Comparing sensors (Tisse et al. 2008, Section 4, Fig. 8): capacity at full resolution and at a
fixed imaging area, tonal range at a common average exposure H₀, and pairwise posterior
probabilities.

    bayescap compare A.csv B.csv ... [--area 1/4in] [--h0 0.4] [--json] [--out DIR]

Conventions (docs/compare.md):

* **Imaging area.** An optical format is the nominal active area of :data:`OPTICAL_FORMATS`
  (4:3, e.g. 1/4" = 3.6 × 2.7 mm). A sensor larger than the area is cropped to the pixels that fit
  at its pitch, ``floor(width_mm·1000/pitch)`` × ``floor(height_mm·1000/pitch)``; a smaller one
  keeps its own size and is flagged ``smaller_than_area`` (when short by more than
  :data:`AREA_TOLERANCE` in either direction: formats are nominal).
* **Exposure calibration** (sensitivity, e⁻ per lux·s, per posterior draw), first available of:
  the ``exposure_lux_s`` column (slope of the dark-subtracted signal against H over the linear rows,
  times the conversion-gain draws); the ``sensitivity_e_per_lux_s`` metadata key (a fixed value);
  the ``photons_per_pixel`` column with the pixel pitch: the quantum-efficiency draws times Eq. 4's
  photons per lux·s on a pixel, ``4090.7·P²`` at 555 nm (monochromatic equivalent).
* **TR at an average exposure H₀** (Fig. 8(a)). The scene's mean signal ``S̄ = sensitivity·H₀`` is
  placed at mid-grey, a fraction ``mid_grey = 0.18`` of the top of the signal range, by analog gain:
  ``S_max = min(clip, S̄/0.18)``. TR (Eq. 7, 8-bit-equivalent scale of
  :func:`bayescap.physics.capacity.tonal_range`) is integrated over ``[σ(0), S_max]``. Above
  ``H₀ = 0.18·clip/sensitivity`` the sensor works at base gain and TR is that of the full range;
  below, the gain raises and the range shrinks. The noise is the fitted (base-gain) model with the
  quantization term scaled by the gain; read noise is not lowered with gain (conservative).
* **Capacity** ``C = s·2^Δs·b'`` (Eq. 6) with ``b'`` = log2 TR at H₀ when the sensor has an exposure
  calibration, else TR over the full range (the fit's own ``capacity_bits``); each pair is compared
  on a common basis.
* **Pairs.** The posteriors of different sensors are independent, so ``P(C_A > C_B)`` is the mean
  over *all* pairs of draws (ties count one half): exact, without random pairing. The ratio
  ``C_A/C_B`` pairs the thinned draws by a seeded random permutation.
* **Practical difference.** ``P(C_A > C_B)`` says which is larger, not whether it matters: two
  sensors 0.2 % apart can give 0.99. Beside it, with a practical difference ``δ``
  (``practical_difference``, ``--practical-difference``; default :data:`DEFAULT_PRACTICAL_DIFFERENCE`),
  ``P(C_A > (1+δ)·C_B)``, ``P(C_B > (1+δ)·C_A)`` and their complement, the probability that the two
  are practically equivalent (the ratio inside ``[1/(1+δ), 1+δ]``: the region of practical
  equivalence), all over all pairs of draws.
"""

from __future__ import annotations

import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bayescap._progress import bar
from bayescap.exceptions import CompareInputError
from bayescap.physics.capacity import N_GREY_LEVELS, information_capacity_bits, tonal_range_bits
from bayescap.physics.optics import OPTICAL_FORMATS
from bayescap.posterior import FitResult, rerun_advice, summarize
from bayescap.posterior.summary import json_safe
from bayescap.studies.area import AREA_TOLERANCE, AreaCrop, area_crop, parse_area
from bayescap.studies.compare_defaults import (
    DEFAULT_AREA,
    DEFAULT_H0_LUX_S,
    DEFAULT_PRACTICAL_DIFFERENCE,
    DEFAULT_QUALITY,
)
from bayescap.studies.exposure import (
    DEFAULT_MID_GREY,
    ExposureCalibration,
    exposure_calibration,
    tonal_range_at_exposure,
)

__all__ = [
    "OPTICAL_FORMATS",
    "SensorComparison",
    "Comparison",
    "sensor_seed",
    "prob_greater",
    "prob_practically_greater",
    "DEFAULT_PRACTICAL_DIFFERENCE",
    "compare",
    "compare_results",
    "format_compare_text",
]


#: posterior draws kept per sensor for the comparison (thinned evenly)
DEFAULT_N_DRAWS = 4000


def sensor_seed(seed: int, path) -> int:
    """The seed of one sensor's fit: from the run's seed and the file's name, so a sensor's numbers
    do not depend on which other files are compared (``bayescap fit --seed`` with this value and
    the same MTF reproduces them)."""
    return int(
        np.random.SeedSequence([int(seed), zlib.crc32(Path(str(path)).name.encode())]).generate_state(1)[0]
        % (2**31 - 1)
    )


def prob_greater(x, y) -> float:
    """P(X > Y) for independent X, Y given by draws: the mean over all pairs (ties count ½).

    Exact for the empirical distributions, O(n log n); a sample against itself gives 0.5.
    """
    x = np.asarray(x, float).ravel()
    ys = np.sort(np.asarray(y, float).ravel())
    lo = np.searchsorted(ys, x, side="left")
    hi = np.searchsorted(ys, x, side="right")
    return float(np.sum(lo + 0.5 * (hi - lo)) / (x.size * ys.size))


def prob_practically_greater(x, y, delta: float) -> float:
    """P(X > (1+δ)·Y) for independent positive X, Y given by draws (all pairs, ties ½): the
    probability that X exceeds Y by more than the practical difference ``delta``."""
    return prob_greater(x, (1.0 + float(delta)) * np.asarray(y, float))


@dataclass
class SensorComparison:
    """One sensor's numbers for the comparison (draw arrays thinned to a common length)."""

    name: str
    input: str
    result: FitResult
    seed: int
    calibration: ExposureCalibration | None
    crop: AreaCrop | None
    draws: dict = field(default_factory=dict)  # quantity -> (n,) draws used for the pairs
    info: dict = field(default_factory=dict)  # JSON-ready summary
    basis: str = "full_range"  # "tr_at_h0" or "full_range"


@dataclass
class Comparison:
    sensors: list
    pairs: list
    conventions: dict

    def to_dict(self) -> dict:
        from bayescap._version import __version__

        return json_safe(
            {
                "bayescap_version": __version__,
                "command": "compare",
                "conventions": self.conventions,
                "sensors": [s.info for s in self.sensors],
                "pairs": self.pairs,
            }
        )

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, ensure_ascii=False, allow_nan=False) + "\n"

    def format_text(self) -> str:
        return format_compare_text(self.to_dict())

    def probability_matrix(self, quantity: str = "area"):
        """``M[i, j] = P(C_i > C_j)`` (NaN on the diagonal and where undefined)."""
        return self._matrix(f"p_a_greater_{quantity}", lambda v: 1.0 - v)

    def practical_matrix(self, quantity: str = "area"):
        """``M[i, j] = P(C_i > (1+δ)·C_j)``, δ the practical difference (NaN on the diagonal and
        where undefined)."""
        m = self._matrix(f"p_a_practically_greater_{quantity}", None)
        low = self._matrix(f"p_b_practically_greater_{quantity}", None).T
        return np.where(np.isfinite(m), m, low)

    def ratio_matrix(self, quantity: str = "area"):
        """``M[i, j]`` = the median of ``C_i/C_j`` (NaN on the diagonal and where undefined)."""
        n = len(self.sensors)
        m = np.full((n, n), np.nan)
        for pr in self.pairs:
            i, j = pr["index"]
            r = pr.get(f"ratio_{quantity}")
            if r is not None:
                m[i, j], m[j, i] = r["median"], 1.0 / r["median"]
        return m

    def _matrix(self, key, mirror):
        n = len(self.sensors)
        m = np.full((n, n), np.nan)
        for pr in self.pairs:
            i, j = pr["index"]
            if pr.get(key) is not None:
                m[i, j] = pr[key]
                if mirror is not None:
                    m[j, i] = mirror(pr[key])
        return m


def _sensor(name, path, result: FitResult, seed, *, area, h0_lux_s, mid_grey, n_draws) -> SensorComparison:
    md = result.metadata
    idx = result.thin_index(n_draws)
    cal = exposure_calibration(result)
    ds = np.asarray(result.derived["mtf_loss_bits"])[idx]
    w, h = md.get("width_px"), md.get("height_px")
    pitch = md.get("pixel_pitch_um")
    notes = []
    b_full = np.asarray(result.derived["tonal_range_bits"])[idx]
    draws = {"tonal_range_bits_full_range": b_full}
    info = {
        "name": name,
        "input": str(path),
        "sensor": md.get("sensor", ""),
        "manufacturer": md.get("manufacturer"),
        "seed": seed,
        "quality": result.quality,
        "pixel_pitch_um": pitch,
        "width_px": w,
        "height_px": h,
        "converged": bool(result.diag.get("converged")),
        "mtf": result.mtf_info,
        "scene_exposure_time_s": result.scene.exposure_time_s,
        "tonal_range_bits_full_range": summarize(b_full, "bits"),
    }
    if result.diag.get("fast_settings") is not None:
        info["fast_settings"] = dict(result.diag["fast_settings"])  # the fast preset's check
    if md.get("simulated"):
        info["simulated"] = str(md["simulated"])
    if not result.diag.get("converged"):
        failed = "; ".join(result.diag.get("failed_checks", []))
        notes.append(
            f"the sampler did not converge ({failed}): rerun with {rerun_advice(result.quality)} "
            "before trusting the intervals"
        )
    if result.flags.get("capacity_lower_bound"):
        notes.append("no row reaches saturation: TR and capacity are lower bounds")
    basis = "full_range"
    b_use = b_full
    if cal is not None:
        tr, s_max = tonal_range_at_exposure(result, h0_lux_s, calibration=cal, mid_grey=mid_grey, idx=idx)
        b_h0 = tonal_range_bits(tr[:, 0])
        draws["tonal_range_bits_h0"] = b_h0
        info["exposure_calibration"] = {
            "source": cal.source,
            "sensitivity_e_per_lux_s": summarize(np.asarray(cal.sensitivity_e_per_lux_s)[idx], "e-/(lux·s)"),
        }
        info["tonal_range_bits_h0"] = summarize(b_h0, "bits")
        info["s_max_h0_e"] = summarize(s_max[:, 0], "e-")
        clip, _ = result.signal_max_e({k: v[idx] for k, v in result.draws.items()})
        info["analog_gain_h0"] = summarize(clip / s_max[:, 0], "", note="clip / S_max: 1 = base gain")
        basis, b_use = "tr_at_h0", b_h0
    else:
        info["exposure_calibration"] = None
        notes.append(
            "no exposure calibration (exposure_lux_s, photons_per_pixel + pixel_pitch_um, or "
            "sensitivity_e_per_lux_s): TR at H0 unavailable; capacity uses TR over the full range"
        )
    info["capacity_basis"] = basis
    if w and h:
        s_full = float(w) * float(h)
        info["pixels_full"] = int(s_full)
        c_full = information_capacity_bits(s_full, ds, bits_per_pixel=b_use)
        draws["capacity_full_bits"] = c_full
        info["capacity_full_bits"] = summarize(c_full, "bits")
        if basis == "tr_at_h0":
            c_fr = information_capacity_bits(s_full, ds, bits_per_pixel=b_full)
            draws["capacity_full_bits_full_range"] = c_fr
            info["capacity_full_bits_full_range"] = summarize(c_fr, "bits")
    else:
        notes.append("width_px/height_px unknown: no capacity in bits (give '# width_px:' and '# height_px:')")
    crop = None
    if area is not None:
        if w and h and pitch:
            crop = area_crop(int(w), int(h), float(pitch), area)
            info["area"] = crop.to_dict()
            s_a = float(crop.pixels)
            draws["capacity_area_bits"] = information_capacity_bits(s_a, ds, bits_per_pixel=b_use)
            info["capacity_area_bits"] = summarize(draws["capacity_area_bits"], "bits")
            if basis == "tr_at_h0":
                draws["capacity_area_bits_full_range"] = information_capacity_bits(s_a, ds, bits_per_pixel=b_full)
                info["capacity_area_bits_full_range"] = summarize(draws["capacity_area_bits_full_range"], "bits")
            if crop.smaller_than_area:
                notes.append(
                    f"the sensor ({int(w) * float(pitch) / 1000:.2f} × {int(h) * float(pitch) / 1000:.2f} mm) "
                    f"is smaller than the {area.name} area: it keeps its own size "
                    f"({100 * crop.covered_fraction:.0f} % of the area)"
                )
        else:
            info["area"] = None
            notes.append("pixel_pitch_um, width_px or height_px unknown: no capacity at the fixed area")
    info["notes"] = notes
    return SensorComparison(
        name=name,
        input=str(path),
        result=result,
        seed=seed,
        calibration=cal,
        crop=crop,
        draws=draws,
        info=info,
        basis=basis,
    )


def _pair(i, j, A: SensorComparison, B: SensorComparison, rng, delta=DEFAULT_PRACTICAL_DIFFERENCE) -> dict:
    same = A.basis == B.basis
    basis = A.basis if same else "full_range"
    out = {"a": A.name, "b": B.name, "index": [i, j], "basis": basis}
    if not same:
        out["note"] = "one sensor has no exposure calibration: compared on TR over the full range"
    for q in ("full", "area"):
        key = f"capacity_{q}_bits"
        if not same:
            key_a = key + ("_full_range" if A.basis == "tr_at_h0" else "")
            key_b = key + ("_full_range" if B.basis == "tr_at_h0" else "")
        else:
            key_a = key_b = key
        x, y = A.draws.get(key_a), B.draws.get(key_b)
        if x is None or y is None:
            for k in ("p_a_greater", "ratio", "p_a_practically_greater", "p_b_practically_greater", "p_equivalent"):
                out[f"{k}_{q}"] = None
            continue
        out[f"p_a_greater_{q}"] = prob_greater(x, y)
        pa, pb = prob_practically_greater(x, y, delta), prob_practically_greater(y, x, delta)
        out[f"p_a_practically_greater_{q}"] = pa
        out[f"p_b_practically_greater_{q}"] = pb
        out[f"p_equivalent_{q}"] = max(0.0, 1.0 - pa - pb)
        n = min(x.size, y.size)
        ratio = x[rng.permutation(x.size)[:n]] / y[rng.permutation(y.size)[:n]]
        out[f"ratio_{q}"] = summarize(ratio, "")
    return out


def compare_results(
    results,
    *,
    inputs=None,
    names=None,
    seeds=None,
    area=DEFAULT_AREA,
    h0_lux_s: float = DEFAULT_H0_LUX_S,
    mid_grey: float = DEFAULT_MID_GREY,
    seed: int = 0,
    n_draws: int = DEFAULT_N_DRAWS,
    quality: str | None = None,
    practical_difference: float = DEFAULT_PRACTICAL_DIFFERENCE,
) -> Comparison:
    """Compare already-fitted sensors (a list of :class:`FitResult`); ``practical_difference``:
    the δ of ``P(C_A > (1+δ)·C_B)`` (module docstring)."""
    if not (0 <= practical_difference < 1):
        raise CompareInputError(
            f"--practical-difference must be a fraction in [0, 1) (0.01 = 1 %), got {practical_difference}"
        )
    if not (h0_lux_s > 0 and math.isfinite(h0_lux_s)):
        raise CompareInputError(f"--h0 must be a positive exposure in lux·s, got {h0_lux_s}")
    if not (0 < mid_grey <= 1):
        raise CompareInputError(f"--mid-grey must be in (0, 1], got {mid_grey}")
    ar = parse_area(area) if (area is None or isinstance(area, str)) else area
    inputs = inputs or [str(r.model.data.source) for r in results]
    names = names or _names(inputs)
    seeds = seeds or [r.seed for r in results]
    sensors = [
        _sensor(n, p, r, s, area=ar, h0_lux_s=h0_lux_s, mid_grey=mid_grey, n_draws=n_draws)
        for n, p, r, s in zip(names, inputs, results, seeds)
    ]
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
    pairs = [
        _pair(i, j, sensors[i], sensors[j], rng, practical_difference)
        for i in range(len(sensors))
        for j in range(i + 1, len(sensors))
    ]
    conv = {
        "area": ar.to_dict() if ar else None,
        "area_tolerance": AREA_TOLERANCE,
        "h0_lux_s": h0_lux_s,
        "mid_grey_fraction": mid_grey,
        "h0_convention": f"S_max = min(clip, sensitivity·H0/{mid_grey:g}); TR (Eq. 7, {N_GREY_LEVELS}-level "
        "scale) over [sigma(0), S_max]",
        "seed": seed,
        "quality": quality or (results[0].quality if results else None),
        "n_draws_per_sensor": n_draws,
        "probability": "P(C_A > C_B) over all pairs of draws of independent posteriors (ties 1/2)",
        "practical_difference": practical_difference,
        "practical_probability": "P(C_A > (1+δ)·C_B), δ the practical difference; practical equivalence: the "
        "ratio within [1/(1+δ), 1+δ]",
        "intervals": "equal-tailed posterior quantiles: ci68 = 16-84 %, ci95 = 2.5-97.5 %",
    }
    return Comparison(sensors=sensors, pairs=pairs, conventions=conv)


def _names(inputs):
    stems = [Path(str(p)).stem for p in inputs]
    out = []
    for i, s in enumerate(stems):
        out.append(s if stems.count(s) == 1 else f"{s}#{i + 1}")
    return out


def compare(
    paths,
    *,
    area=DEFAULT_AREA,
    h0_lux_s: float = DEFAULT_H0_LUX_S,
    mid_grey: float = DEFAULT_MID_GREY,
    seed: int = 0,
    quality: str = DEFAULT_QUALITY,
    n_draws: int = DEFAULT_N_DRAWS,
    progress: bool = False,
    fit_kwargs: dict | None = None,
    practical_difference: float = DEFAULT_PRACTICAL_DIFFERENCE,
) -> Comparison:
    """Fit each photon-transfer CSV (seeded, :func:`sensor_seed`) and compare them.

    Raises :class:`bayescap.exceptions.PTCInputError` for a bad file and :class:`CompareInputError` for
    a bad option.
    """
    from bayescap.api import fit, load

    if len(paths) < 1:
        raise CompareInputError("give at least one photon-transfer CSV")
    ar = parse_area(area) if (area is None or isinstance(area, str)) else area
    if not (h0_lux_s > 0 and math.isfinite(h0_lux_s)):
        raise CompareInputError(f"--h0 must be a positive exposure in lux·s, got {h0_lux_s}")
    if not (0 <= practical_difference < 1):
        raise CompareInputError(
            f"--practical-difference must be a fraction in [0, 1) (0.01 = 1 %), got {practical_difference}"
        )
    datas = [load(p) for p in paths]  # refuse bad input before any fit runs
    results, seeds = [], []
    with bar(progress, total=len(paths), desc="compare: sensors fitted", unit="sensor") as done:
        for p, d in zip(paths, datas):
            s = sensor_seed(seed, p)
            results.append(fit(d, seed=s, quality=quality, progress=progress, **(fit_kwargs or {})))
            seeds.append(s)
            done.update(1)
    return compare_results(
        results,
        inputs=[str(p) for p in paths],
        seeds=seeds,
        area=ar,
        h0_lux_s=h0_lux_s,
        mid_grey=mid_grey,
        seed=seed,
        n_draws=n_draws,
        quality=quality,
        practical_difference=practical_difference,
    )


def _mbit(x):
    return "—" if x is None else f"{x / 1e6:.4g}"


def _num(x, fmt=".3g"):
    return "—" if x is None else format(x, fmt)


def _iv(s, f):
    if s is None:
        return "—"
    return f"{f(s['median'])} [{f(s['ci95'][0])}, {f(s['ci95'][1])}]"


def format_compare_text(d: dict) -> str:
    """The table printed by ``bayescap compare`` (every number is the JSON's, formatted)."""
    c = d["conventions"]
    ar = c["area"]
    L = []
    L.append(
        f"bayescap {d['bayescap_version']} compare: {len(d['sensors'])} sensors, seed {c['seed']}, "
        f"quality {c['quality']}; medians with 95 % intervals"
    )
    area_txt = f"{ar['name']} = {ar['width_mm']:g} × {ar['height_mm']:g} mm" if ar else "none"
    L.append(
        f"conventions: area {area_txt}; H0 = {c['h0_lux_s']:g} lux·s at mid-grey "
        f"{100 * c['mid_grey_fraction']:g} % ({c['h0_convention']})"
    )
    L.append("")
    an = ar["name"] if ar else "area"
    hdr = (
        f"  {'sensor':<24} {'pitch µm':>8} {'pixels':>10} {'@' + an:>20}  {'TR(H0) bits':<24} "
        f"{'C full (Mbit)':<26} {'C @' + an + ' (Mbit)':<26} basis"
    )
    L.append(hdr)
    for s in d["sensors"]:
        px = f"{s['pixels_full'] / 1e6:.3f} M" if s.get("pixels_full") else "—"
        a = s.get("area")
        apx = f"{a['width_px']}×{a['height_px']}" + ("*" if a["smaller_than_area"] else "") if a else "—"
        L.append(
            f"  {s['name']:<24} {_num(s['pixel_pitch_um'], '.3g'):>8} {px:>10} {apx:>20}  "
            f"{_iv(s.get('tonal_range_bits_h0'), lambda x: f'{x:.3f}'):<24} "
            f"{_iv(s.get('capacity_full_bits'), _mbit):<26} {_iv(s.get('capacity_area_bits'), _mbit):<26} "
            f"{'TR at H0' if s['capacity_basis'] == 'tr_at_h0' else 'TR full range'}"
        )
    if any(s.get("area") and s["area"]["smaller_than_area"] for s in d["sensors"]):
        L.append("  * smaller than the area: keeps its own size")
    if d["pairs"]:
        delta = c.get("practical_difference", DEFAULT_PRACTICAL_DIFFERENCE)
        dp = f"{100 * delta:g}%"
        L.append("")
        L.append(
            f"  pairs: C_A/C_B with its 95 % interval; P(A>B); and with the practical difference δ = {dp} "
            f"(--practical-difference): P(A>B+δ) = P(C_A > (1+δ)·C_B), P(B>A+δ), P(≈) = P(within δ)"
        )
        for q, where in (("full", "full"), ("area", "@" + an)):
            if all(p[f"ratio_{q}"] is None for p in d["pairs"]):
                continue
            L.append(
                f"  {'pair (A vs B), ' + where:<44} {'C_A/C_B':<26} {'P(A>B)':>7} {'P(A>B+' + dp + ')':>12} "
                f"{'P(B>A+' + dp + ')':>12} {'P(≈)':>6}"
            )
            for p in d["pairs"]:
                L.append(
                    f"  {p['a'] + ' vs ' + p['b']:<44} {_iv(p[f'ratio_{q}'], lambda x: f'{x:.4f}'):<26} "
                    f"{_num(p[f'p_a_greater_{q}'], '.3f'):>7} {_num(p.get(f'p_a_practically_greater_{q}'), '.3f'):>12} "
                    f"{_num(p.get(f'p_b_practically_greater_{q}'), '.3f'):>12} {_num(p.get(f'p_equivalent_{q}'), '.3f'):>6}"
                    + ("  (TR full range)" if p["basis"] == "full_range" else "")
                )
    notes = [(s["name"], n) for s in d["sensors"] for n in s.get("notes", [])]
    if notes:
        L.append("")
        for name, n in notes:
            L.append(f"  ! {name}: {n}")
    return "\n".join(L) + "\n"
