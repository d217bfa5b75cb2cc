"""Table 1 of Tisse, Guichard & Cao (SPIE 2008) as data, and the dark-current temperature law.

The table lives in ``data/paper_table1_pixel_parameters.csv`` (read ``data/PAPER_TABLE1.md`` for
how the printed cells were read: the extracted text puts the 25 °C dark current in the same cell
as an unassigned number). :func:`load_table1` returns one :class:`PixelSpec` per row, with units
in the attribute names (electrons, e⁻/(lux·s), e⁻/s, fractions).

Section 2.2: dark current "is roughly doubling every 6 °C" (measured by Rhodes et al. for a
3.2 µm 2.5-T pixel); :func:`dark_current_at` implements that law.

Example
-------
>>> from bayescap.physics.table1 import load_table1
>>> [p.pitch_um for p in load_table1()]
[5.2, 3.2, 2.9, 2.2, 1.75, 1.45]
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "PixelSpec",
    "TABLE1_PATH",
    "DARK_CURRENT_DOUBLING_C",
    "load_table1",
    "table1_arrays",
    "dark_current_at",
]

#: repository copy of Table 1 (the package is installed editable from the repository)
TABLE1_PATH = Path(__file__).resolve().parents[2] / "data" / "paper_table1_pixel_parameters.csv"
#: Section 2.2: dark current doubles about every 6 °C
DARK_CURRENT_DOUBLING_C = 6.0

# Embedded copy, used only when the repository's data/ folder is not next to the package
# (a wheel install); tests check that it equals the CSV.
_EMBEDDED_CSV = """\
pitch_um,architecture,full_well_min_ke,full_well_max_ke,full_well_as_printed,sensitivity_ke_per_lux_s,sensitivity_as_printed,dark_current_25c_e_per_s,dark_current_60c_e_per_s,dark_current_cells_as_printed,dark_current_unassigned_as_printed,prnu_max_percent,prnu_as_printed,source_full_well,source_sensitivity,source_dark_current,source_prnu
5.2,4T,28,38,28 – 38 *,57,57 *,22,2000,250 – 22 * | 2000 *,250,1.05,<1.05 *,Rhodes,Rhodes,Rhodes,Rhodes
3.2,2.5T,22,33,22 – 33 *,22,22 *,12,360,65 – 12 * | 360 *,65,1.05,<1.05 *,Rhodes,Rhodes,Rhodes,Rhodes
2.90,2.5T,19,25,19 – 25 *,16,16 *,10,300,30 – 10 * | 300 *,30,1.05,<1.05 *,Rhodes,Rhodes,Rhodes,Rhodes
2.20,2.5T,12,21,12 – 21 *,9.3,9.3 *,9,270,25 – 9 * | 270 *,25,1.5,<1.5,Rhodes,Rhodes,Rhodes,unmarked
1.75,1.75T,8,9,9 – 8 **,5,5 **,,25,20 | 25 **,20,1.5,<1.5 **,Cohen,Cohen,Cohen,Cohen
1.45,1.5T,4,7,7 – 4 **,3,3 (italic),,15,18 | 15 **,18,2.0,<2.0,Cohen,model,Cohen,unmarked
"""


@dataclass(frozen=True)
class PixelSpec:
    """One row of Table 1 (units in the names; ranges kept as min/max).

    ``dark_current_25c_e_per_s`` is NaN where the table prints no 25 °C value (the Cohen et al.
    pixels); :meth:`dark_current_e_per_s` then scales the 60 °C value with the 6 °C law.
    ``prnu_max_frac`` is the printed upper bound ("<1.05 %") as a fraction.
    """

    pitch_um: float
    architecture: str
    full_well_min_e: float
    full_well_max_e: float
    sensitivity_e_per_lux_s: float
    dark_current_25c_e_per_s: float
    dark_current_60c_e_per_s: float
    prnu_max_frac: float
    sources: dict
    as_printed: dict

    @property
    def full_well_mid_e(self) -> float:
        return 0.5 * (self.full_well_min_e + self.full_well_max_e)

    def dark_current_e_per_s(
        self, temperature_c: float = 25.0, *, doubling_c: float = DARK_CURRENT_DOUBLING_C
    ) -> float:
        """Dark current (e⁻/s) at ``temperature_c`` from the nearest printed reference (25 or
        60 °C), doubling every ``doubling_c`` °C (Section 2.2)."""
        refs = [
            (t, v)
            for t, v in ((25.0, self.dark_current_25c_e_per_s), (60.0, self.dark_current_60c_e_per_s))
            if np.isfinite(v)
        ]
        if not refs:
            raise ValueError(f"pixel {self.pitch_um} µm has no dark-current value")
        t_ref, v_ref = min(refs, key=lambda tv: abs(tv[0] - temperature_c))
        return float(
            dark_current_at(
                temperature_c, reference_e_per_s=v_ref, reference_temperature_c=t_ref, doubling_c=doubling_c
            )
        )


def dark_current_at(
    temperature_c, *, reference_e_per_s, reference_temperature_c, doubling_c: float = DARK_CURRENT_DOUBLING_C
):
    """Dark current (e⁻/s) at ``temperature_c`` (°C), doubling every ``doubling_c`` °C.

    ``D(T) = D_ref · 2^((T − T_ref)/doubling_c)`` (Section 2.2, after Rhodes et al. 2004).
    Vectorised over ``temperature_c`` and ``reference_e_per_s``.

    >>> float(dark_current_at(31.0, reference_e_per_s=10.0, reference_temperature_c=25.0))
    20.0
    """
    if not (np.isfinite(doubling_c) and doubling_c > 0):
        raise ValueError(f"doubling_c must be positive, got {doubling_c}")
    t = np.asarray(temperature_c, float)
    return np.asarray(reference_e_per_s, float) * np.exp2((t - reference_temperature_c) / doubling_c)


def _f(x: str) -> float:
    x = x.strip()
    return float(x) if x else float("nan")


def load_table1(path: str | Path | None = None) -> list[PixelSpec]:
    """Read Table 1 (pixel parameters of the SNR and capacity simulations).

    ``path`` defaults to the repository's ``data/paper_table1_pixel_parameters.csv`` (or an
    embedded copy of it when the package is installed without the repository). Rows are in the
    paper's order (5.2 µm first).
    """
    if path is None:
        text = TABLE1_PATH.read_text(encoding="utf-8") if TABLE1_PATH.exists() else _EMBEDDED_CSV
    else:
        text = Path(path).read_text(encoding="utf-8")
    rows = []
    for i, r in enumerate(csv.DictReader(io.StringIO(text)), start=2):
        try:
            fw_lo, fw_hi = sorted((_f(r["full_well_min_ke"]), _f(r["full_well_max_ke"])))
            rows.append(
                PixelSpec(
                    pitch_um=_f(r["pitch_um"]),
                    architecture=r["architecture"].strip(),
                    full_well_min_e=1e3 * fw_lo,
                    full_well_max_e=1e3 * fw_hi,
                    sensitivity_e_per_lux_s=1e3 * _f(r["sensitivity_ke_per_lux_s"]),
                    dark_current_25c_e_per_s=_f(r["dark_current_25c_e_per_s"]),
                    dark_current_60c_e_per_s=_f(r["dark_current_60c_e_per_s"]),
                    prnu_max_frac=_f(r["prnu_max_percent"]) / 100.0,
                    sources={k[len("source_") :]: v for k, v in r.items() if k.startswith("source_")},
                    as_printed={k: v for k, v in r.items() if k.endswith("_as_printed")},
                )
            )
        except (KeyError, ValueError) as exc:
            raise ValueError(
                f"Table 1 file {path or TABLE1_PATH}, line {i}: {exc!r}; "
                "expected the columns of data/paper_table1_pixel_parameters.csv"
            ) from exc
    return rows


def table1_arrays(specs: list[PixelSpec] | None = None, *, temperature_c: float = 25.0) -> dict:
    """Table 1 as arrays (one entry per pixel), dark current taken at ``temperature_c``."""
    specs = load_table1() if specs is None else specs
    return {
        "pitch_um": np.array([s.pitch_um for s in specs]),
        "full_well_min_e": np.array([s.full_well_min_e for s in specs]),
        "full_well_max_e": np.array([s.full_well_max_e for s in specs]),
        "sensitivity_e_per_lux_s": np.array([s.sensitivity_e_per_lux_s for s in specs]),
        "dark_current_e_per_s": np.array([s.dark_current_e_per_s(temperature_c) for s in specs]),
        "prnu_max_frac": np.array([s.prnu_max_frac for s in specs]),
    }
