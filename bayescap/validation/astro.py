"""Astronomy photon-transfer tables from the frame simulator: one row per flat pair, the mean with
the bias removed and the pair-difference variance, as LSST cp_pipe, eotest or PypeIt keep them (no
dark rows, no exposure times; CONTRACT.md section 1b).

Each amplifier is a :class:`~bayescap.validation.framesim.FrameSensor` with brighter-fatter
(Astier's a₀₀, :mod:`.responses`), PRNU, a per-pixel well with a spread (so the PTC turns over
smoothly), an 18-bit ADC and a bias level; every level's two flats are simulated pixel by pixel by
:mod:`.framesim` (all levels of a table at once). The bias is removed as a pipeline does it: each
frame's mean of an overscan region (read noise only, the same ADC) is subtracted from its mean. The
variance is the contract's pair formula, (mean((A−B)²) − (mean A − mean B)²)/2, which neither the
bias nor the PRNU enters.

Nothing here imports :mod:`bayescap.model`: the truths are the simulator's inputs.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from bayescap.validation.framesim import FrameSensor, _pair_stats, _Pixels

__all__ = ["AmpTruth", "draw_amplifier", "astronomy_table", "write_astro_csv", "focal_plane", "ASTRO_COLUMNS"]

ASTRO_COLUMNS = ("mean_dn", "temporal_var_dn2", "n_pixels")


@dataclass(frozen=True)
class AmpTruth:
    """One amplifier: gain (e⁻/ADU, the small-signal conversion gain K), read noise (e⁻), Astier's
    a₀₀ (per e⁻, negative), the mean pixel well (e⁻) and its spread, PRNU, bias (ADU), the table's
    number of flat pairs and the ROI side (pixels)."""

    gain_e_per_adu: float
    read_noise_e: float
    a00_per_e: float
    full_well_e: float
    n_points: int
    bias_adu: float = 1000.0
    well_spread_frac: float = 0.02
    prnu_frac: float = 0.005
    roi_px: int = 32
    overscan_px: int = 512
    adc_bits: int = 18
    bf_steps: int = 4
    top_frac: float = 1.25

    def sensor(self) -> FrameSensor:
        return FrameSensor(
            k_e_per_dn=self.gain_e_per_adu,
            read_noise_e=self.read_noise_e,
            full_well_e=self.full_well_e,
            quantum_efficiency=1.0,
            prnu_frac=self.prnu_frac,
            well_spread_frac=self.well_spread_frac,
            adc_bits=self.adc_bits,
            black_level_dn=self.bias_adu,
            width_px=self.roi_px,
            height_px=self.roi_px,
            bf_a00_per_e=self.a00_per_e,
            bf_steps=self.bf_steps,
        )

    def charges_e(self) -> np.ndarray:
        """Mean charge per pixel of each flat pair: half the pairs geometric from 50 e⁻ to 30 % of
        the top, half evenly spaced from there to ``top_frac`` of the well (the low rows fix the read
        noise; the top rows pass the PTC turnoff, as a PTC run that goes to saturation has them)."""
        top = self.top_frac * self.full_well_e
        n_geo = self.n_points // 2
        geo = np.geomspace(50.0, 0.3 * top, n_geo, endpoint=False)
        return np.concatenate([geo, np.linspace(0.3 * top, top, self.n_points - n_geo)])


def draw_amplifier(rng: np.random.Generator, *, strong_bf: bool = True) -> AmpTruth:
    """An amplifier from the ranges of astronomy CCDs: gain 0.6–1.8 e⁻/ADU, read noise 3–10 e⁻,
    a₀₀ −(1–3)·10⁻⁶ per e⁻ (``strong_bf``; else −(0.2–1)·10⁻⁶), well 80 000–150 000 e⁻, 40–400
    flat pairs (log-uniform), bias 500–5 000 ADU."""
    lo, hi = (1e-6, 3e-6) if strong_bf else (2e-7, 1e-6)
    return AmpTruth(
        gain_e_per_adu=float(rng.uniform(0.6, 1.8)),
        read_noise_e=float(rng.uniform(3.0, 10.0)),
        a00_per_e=-float(rng.uniform(lo, hi)),
        full_well_e=float(rng.uniform(80_000, 150_000)),
        n_points=int(round(math.exp(rng.uniform(math.log(40), math.log(400))))),
        bias_adu=float(rng.uniform(500, 5_000)),
    )


def _overscan_mean(rng, truth: AmpTruth, n_frames: int) -> np.ndarray:
    """Per frame, the mean of an overscan region: bias + read noise, through the same ADC."""
    x = truth.bias_adu + truth.read_noise_e / truth.gain_e_per_adu * rng.standard_normal((n_frames, truth.overscan_px))
    x = np.clip(np.rint(x), 0, 2**truth.adc_bits - 1)
    return x.mean(axis=1)


def astronomy_table(truth: AmpTruth, seed: int, *, n_pixels: bool = True) -> list[dict]:
    """The table's rows (dicts with ``mean_dn``, ``temporal_var_dn2`` and, with ``n_pixels``,
    ``n_pixels``), in order of increasing flux."""
    s = truth.sensor()
    ss = np.random.SeedSequence(seed)
    map_seq, frame_seq, os_seq = ss.spawn(3)
    pix = _Pixels(s, np.random.default_rng(map_seq))
    rng = np.random.default_rng(frame_seq)
    electrons = truth.charges_e()  # QE 1: photons are electrons
    a = pix.frame(rng, electrons, 0.0)
    b = pix.frame(rng, electrons, 0.0)
    os_a = _overscan_mean(np.random.default_rng(os_seq), truth, 2 * truth.n_points).reshape(2, -1)
    n = truth.roi_px**2
    rows = []
    for i in range(truth.n_points):
        m, v = _pair_stats(a[i] - os_a[0, i], b[i] - os_a[1, i])
        row = {"mean_dn": m, "temporal_var_dn2": v}
        if n_pixels:
            row["n_pixels"] = n
        rows.append(row)
    return rows


def write_astro_csv(path, rows: list[dict], metadata: dict | None = None) -> None:
    """``# key: value`` lines, then ``mean_dn,temporal_var_dn2[,n_pixels]``; written to a temporary
    file and renamed."""
    from pathlib import Path

    path = Path(path)
    cols = [c for c in ASTRO_COLUMNS if c in rows[0]]
    lines = [f"# {k}: {v}" for k, v in (metadata or {}).items()]
    lines.append(",".join(cols))
    for r in rows:
        lines.append(",".join(str(int(r[c])) if c == "n_pixels" else repr(float(r[c])) for c in cols))
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tmp.replace(path)


def ensure_astro_csv(folder, name: str, truth: AmpTruth, seed: int, *, n_pixels: bool = True):
    """The table's CSV in ``folder``, simulated once: the file name carries a hash of the definition
    (truth, seed, columns), so a changed definition is simulated again."""
    import hashlib
    import json
    from pathlib import Path

    blob = json.dumps([asdict(truth), seed, n_pixels], sort_keys=True)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}-{hashlib.sha1(blob.encode()).hexdigest()[:10]}.csv"
    if not path.exists():
        rows = astronomy_table(truth, seed, n_pixels=n_pixels)
        write_astro_csv(path, rows, {"sensor": f"simulated astronomy amplifier {name}"})
    return path


def focal_plane(n_ccds: int = 189, n_amps: int = 16, seed: int = 46) -> list[tuple[str, AmpTruth, int]]:
    """(name, truth, seed) for every amplifier of a focal plane (LSST: 189 science CCDs × 16
    amplifiers = 3 024), drawn with :func:`draw_amplifier` (strong brighter-fatter)."""
    rng = np.random.default_rng(seed)
    out = []
    for c in range(n_ccds):
        for a in range(n_amps):
            out.append((f"ccd{c:03d}_amp{a:02d}", draw_amplifier(rng), int(seed * 100_000 + c * 100 + a)))
    return out


def truth_dict(truth: AmpTruth) -> dict:
    """The truth as plain numbers (for a results log)."""
    return asdict(truth)


__all__ += ["truth_dict", "ensure_astro_csv"]


def noise_parameter(result: dict) -> str | None:
    """The fit's read-noise entry: ``read_noise_e``, or ``dark_noise_e`` where the table cannot
    separate read noise from dark current (no exposure times: the same thing for a bias-dominated
    astronomy CCD)."""
    pars = result.get("parameters", {})
    for name in ("read_noise_e", "dark_noise_e"):
        if (pars.get(name) or {}).get("median") is not None:
            return name
    return None


def score_astro(truth: AmpTruth, result: dict) -> dict:
    """A fit (``FitResult.to_dict()``) against the amplifier's truth: K inside its 95 % interval
    (and by how many half-widths it misses), the read noise's relative error and whether its 95 %
    interval holds it."""
    out = {"k_truth": truth.gain_e_per_adu, "read_truth": truth.read_noise_e}
    k = result.get("parameters", {}).get("conversion_gain_e_per_dn") or {}
    lo, hi = (k.get("ci95") or [None, None])[:2]
    out["k_median"] = k.get("median")
    if lo is None or hi is None:
        out["k_inside"], out["k_miss_half_widths"] = False, float("nan")
    else:
        t = truth.gain_e_per_adu
        out["k_inside"] = bool(lo <= t <= hi)
        dist = 0.0 if out["k_inside"] else min(abs(t - lo), abs(t - hi))
        out["k_miss_half_widths"] = dist / ((hi - lo) / 2) if hi > lo else float("inf")
    name = noise_parameter(result)
    if name is None:
        out["read_rel_err"], out["read_inside"], out["read_name"] = float("nan"), False, None
    else:
        p = result["parameters"][name]
        out["read_name"] = name
        out["read_rel_err"] = p["median"] / truth.read_noise_e - 1.0
        rlo, rhi = p.get("ci95") or [None, None]
        out["read_inside"] = bool(rlo is not None and rhi is not None and rlo <= truth.read_noise_e <= rhi)
    turn = (result.get("derived", {}) or {}).get("ptc_turnoff_dn") or {}
    out["ptc_turnoff_dn"] = turn.get("median") if isinstance(turn, dict) else turn
    return out


def refuses_mean_variance_tables(message: str) -> bool:
    """Whether an input error says the table lacks the columns a mean/variance-only table omits
    (bayescap before CONTRACT.md section 1b was implemented)."""
    m = message.lower()
    return "missing required column" in m and ("exposure_time_s" in m or "dark_mean_dn" in m)


__all__ += ["noise_parameter", "score_astro", "refuses_mean_variance_tables"]
