"""Detector MTF as system MTF ÷ lens MTF (the paper's method, Section 4 and Fig. 7).

The paper mounted every sensor behind identical lenses whose MTF was measured (TRIOPTICS) and
found "the detector MTF by dividing the overall MTF of the resultant imaging system by the lens
MTF". Here the system MTF is a slanted-edge measurement (:func:`bayescap.measure.measure_sfr`,
with bootstrap draws) and the lens MTF a table read by :func:`read_lens_mtf_table`.

Lens table (CSV, one header line, ``#`` comments allowed): a frequency column whose name gives
its unit, ``frequency_lp_per_mm`` (line pairs = cycles per mm in the image plane) or
``frequency_cy_per_px``, and a column ``mtf`` (0..1). lp/mm is converted to cycles per pixel
with the pixel pitch: ``f_cy_per_px = f_lp_per_mm · pitch_um / 1000``.

The quotient is reported where the lens MTF is at least ``min_lens_mtf`` (default 0.05) and
inside the table: there the division amplifies the measurement noise by at most 1/min_lens_mtf;
outside it the detector MTF is NaN and the result says so. The interval is the bootstrap
interval of the system MTF divided by the lens MTF: the lens table is taken as exact (its own
uncertainty, when known, is not in the interval). Frequencies are given in cycles per pixel,
in lp/mm (``f_cy_per_px / pitch_mm``) and in cycles per image height (``f_cy_per_px ·
height_px``, the paper's "cpi" of Fig. 7, right), where Nyquist is ``height_px / 2``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bayescap.exceptions import MTFInputError
from bayescap.measure.result import SFRResult

__all__ = ["LensMTF", "DetectorMTF", "read_lens_mtf_table", "detector_mtf", "detector_table_text"]

FREQ_COLUMNS = {
    "frequency_lp_per_mm": "lp/mm",
    "frequency_cy_per_px": "cy/px",
    # the names of the system MTF table (``freq_cy_per_px``, measure.table): one convention, both read
    "freq_lp_per_mm": "lp/mm",
    "freq_cy_per_px": "cy/px",
}


@dataclass(frozen=True)
class LensMTF:
    """A lens MTF table: frequencies in ``unit`` ("lp/mm" or "cy/px") and MTF values."""

    freq: np.ndarray
    mtf: np.ndarray
    unit: str
    source: str = ""

    def freq_cy_per_px(self, pixel_pitch_um: float | None) -> np.ndarray:
        if self.unit == "cy/px":
            return self.freq
        if pixel_pitch_um is None or not pixel_pitch_um > 0:
            raise MTFInputError(f"{self.source}: the lens table is in lp/mm: give the pixel pitch (µm) to convert it")
        return self.freq * pixel_pitch_um / 1000.0


def read_lens_mtf_table(path: str | Path) -> LensMTF:
    """Read a lens MTF table (see the module docstring); errors name the file, row and column."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise MTFInputError(f"{path}: cannot read the lens MTF table ({e})") from None
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise MTFInputError(f"{path}: empty lens MTF table")
    header_line, header = lines[0][0], [h.strip() for h in next(csv.reader([lines[0][1]]))]
    fcols = [c for c in header if c in FREQ_COLUMNS]
    if len(fcols) != 1 or "mtf" not in header:
        raise MTFInputError(
            f"{path}, line {header_line}: expected a header with one frequency column "
            f"({' or '.join(FREQ_COLUMNS)}) and 'mtf', got {header}"
        )
    fi, mi = header.index(fcols[0]), header.index("mtf")
    freq, mtf = [], []
    for lineno, ln in lines[1:]:
        cells = next(csv.reader([ln]))
        for col, idx, out in ((fcols[0], fi, freq), ("mtf", mi, mtf)):
            try:
                v = float(cells[idx])
            except (IndexError, ValueError):
                v = math.nan
            if not math.isfinite(v) or v < 0:
                got = cells[idx] if idx < len(cells) else "nothing"
                raise MTFInputError(f"{path}, line {lineno}, column {col}: expected a finite number >= 0, got {got!r}")
            out.append(v)
    freq, mtf = np.asarray(freq), np.asarray(mtf)
    if freq.size < 2 or np.any(np.diff(freq) <= 0):
        raise MTFInputError(f"{path}, column {fcols[0]}: need at least two strictly increasing frequencies")
    if np.any(mtf > 1.5):
        raise MTFInputError(f"{path}, column mtf: MTF values above 1.5; give the MTF as a fraction (0..1)")
    return LensMTF(freq=freq, mtf=mtf, unit=FREQ_COLUMNS[fcols[0]], source=str(path))


@dataclass(frozen=True)
class DetectorMTF:
    """System ÷ lens MTF, with the 95 % bootstrap interval, on the system MTF's frequencies."""

    freq_cy_per_px: np.ndarray
    mtf: np.ndarray
    ci95: tuple[np.ndarray, np.ndarray]
    lens_mtf: np.ndarray
    valid: np.ndarray
    pixel_pitch_um: float | None
    height_px: int | None
    min_lens_mtf: float
    notes: list[str] = field(default_factory=list)

    @property
    def freq_lp_per_mm(self) -> np.ndarray | None:
        return None if self.pixel_pitch_um is None else self.freq_cy_per_px / (self.pixel_pitch_um / 1000.0)

    @property
    def freq_cy_per_image_height(self) -> np.ndarray | None:
        return None if self.height_px is None else self.freq_cy_per_px * self.height_px

    def at(self, f_cy_per_px) -> np.ndarray:
        """Detector MTF at ``f_cy_per_px`` (linear interpolation; NaN where not valid)."""
        return np.interp(f_cy_per_px, self.freq_cy_per_px, np.where(self.valid, self.mtf, np.nan))

    def to_dict(self) -> dict:
        def lst(x):
            return None if x is None else [None if not np.isfinite(v) else float(v) for v in x]

        return {
            "freq_cy_per_px": lst(self.freq_cy_per_px),
            "freq_lp_per_mm": lst(self.freq_lp_per_mm),
            "freq_cy_per_image_height": lst(self.freq_cy_per_image_height),
            "detector_mtf": lst(np.where(self.valid, self.mtf, np.nan)),
            "detector_mtf_ci95_low": lst(np.where(self.valid, self.ci95[0], np.nan)),
            "detector_mtf_ci95_high": lst(np.where(self.valid, self.ci95[1], np.nan)),
            "lens_mtf": lst(self.lens_mtf),
            "pixel_pitch_um": self.pixel_pitch_um,
            "height_px": self.height_px,
            "min_lens_mtf": self.min_lens_mtf,
            "interval": "bootstrap 95 % interval of the system MTF divided by the lens MTF (lens taken as exact)",
            "notes": list(self.notes),
        }


def detector_mtf(
    system: SFRResult,
    lens: LensMTF,
    *,
    pixel_pitch_um: float | None = None,
    height_px: int | None = None,
    min_lens_mtf: float = 0.05,
) -> DetectorMTF:
    """Detector MTF = system MTF / lens MTF with its bootstrap interval (see the module docstring)."""
    f = np.asarray(system.freq_cy_per_px, float)
    lf = lens.freq_cy_per_px(pixel_pitch_um)
    inside = (f >= lf[0]) & (f <= lf[-1])
    lm = np.interp(f, lf, lens.mtf)
    valid = inside & (lm >= min_lens_mtf)
    safe = np.where(valid, lm, 1.0)
    det = np.asarray(system.mtf, float) / safe
    notes = []
    if system.mtf_samples.shape[0]:
        lo, hi = np.quantile(system.mtf_samples / safe, [0.025, 0.975], axis=0)
    else:
        lo = hi = np.full_like(det, np.nan)
        notes.append("the system MTF has no bootstrap draws: no interval")
    if not np.all(valid):
        top = f[valid].max() if valid.any() else float("nan")
        notes.append(
            f"detector MTF reported up to {top:.3f} cy/px only: beyond it the lens MTF is below "
            f"{min_lens_mtf} or outside its table"
        )
    return DetectorMTF(
        freq_cy_per_px=f,
        mtf=det,
        ci95=(lo, hi),
        lens_mtf=lm,
        valid=valid,
        pixel_pitch_um=pixel_pitch_um,
        height_px=height_px,
        min_lens_mtf=min_lens_mtf,
        notes=notes,
    )


def detector_table_text(det: DetectorMTF) -> str:
    """CSV: frequency in cy/px, lp/mm and cycles per image height (empty when unknown), the
    detector MTF and its 95 % interval (empty where not reported), and the lens MTF used."""
    d = det.to_dict()
    cols = [
        "freq_cy_per_px",
        "freq_lp_per_mm",
        "freq_cy_per_image_height",
        "detector_mtf",
        "detector_mtf_ci95_low",
        "detector_mtf_ci95_high",
        "lens_mtf",
    ]
    rows = [",".join(cols)]
    for i in range(det.freq_cy_per_px.size):
        rows.append(",".join("" if d[c] is None or d[c][i] is None else f"{d[c][i]:.6g}" for c in cols))
    return "\n".join(rows) + "\n"
