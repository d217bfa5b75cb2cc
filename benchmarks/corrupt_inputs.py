"""The bundled Basler CSV corrupted many ways, each run through ``bayescap fit --quality fast``.

    python benchmarks/corrupt_inputs.py [--seed 0] [--cells 60] [--include-slow]

Every variant must either fit (exit 0) or be refused with one line naming the file (exit 2); a
traceback (an exception through ``bayescap.cli.main``), a RuntimeWarning, more than one line of error
or a modified input is listed as a defect, and the script exits 1 if there is one. Variants: ``cells``
random single cells (a bad token, or the value scaled by 10⁻¹²…10¹², negated, ...; ``--seed`` picks
them), each column dropped / zero / empty, structural ones (BOM, CRLF, tabs, rows cut or doubled, ...)
and metadata out of range. ``--include-slow`` adds the two that fit correctly but take ~2 minutes
each (dark variance 0 on every row: the exact rounding terms at read noise 10⁻⁴ e⁻).

In-process (``cli.main``), so a variant costs what its fit costs. Writes
``benchmarks/results/corrupt_inputs.md``: how many variants fitted, how many were refused, and every
defect. ``tests/test_input_corruption.py`` keeps a fixed ~110 variants of this kind."""

import argparse
import contextlib
import io
import random
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "benchmarks" / "results" / "corrupt_inputs.md"

from _machine import describe_machine, emit  # noqa: E402

from bayescap import cli  # noqa: E402

BAD = [
    "abc",
    "",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "1e308",
    "-0",
    "1e-320",
    " 5 ",
    "٣",
    "0x10",
    "1e999",
    "None",
    "true",
    "5e",
    "--3",
    "1_000",
]
SCALES = [1e6, 1e-6, -1, 0.5, 2, 1e12, 1e-12, 1 + 1e-9]
METADATA = [
    "# adc_bits: twelve",
    "# adc_bits: 0",
    "# adc_bits: 64",
    "# adc_bits: 8",
    "# adc_bits: 1.5",
    "# pixel_pitch_um: -3",
    "# pixel_pitch_um: 0",
    "# pixel_pitch_um: nan",
    "# width_px: 1e9",
    "# width_px: 0",
    "# f_number: 0",
    "# f_number: -2",
    "# fill_factor: 2",
    "# fill_factor: 0",
    "# black_level_dn: nan",
    "# black_level_dn: 1e6",
    "# wavelength_nm: 0",
    "# crosstalk_sigma_px: -1",
    "# crosstalk_sigma_px: 1e6",
    "# n_frames: 0",
    "# analog_gain: x",
    "#adc_bits 12",
    "# : 5",
    "# temperature_c: -300",
    "# channel: 7",
]
SLOW = ("column dark_temporal_var_dn2 all '0'", "every dark variance 0")


def variants(text, rng, n_cells):
    """{name: CSV text} of the corruptions."""
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    meta, header = lines[:k], lines[k].split(",")
    rows = [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]

    def build(h, rs, m=meta, sep=",", eol="\n"):
        return eol.join(m + [sep.join(h)] + [sep.join(r) for r in rs]) + eol

    def col(j, value):
        return [r[:j] + [value] + r[j + 1 :] for r in rows]

    out = {}
    for _ in range(n_cells):
        rs = [list(r) for r in rows]
        i, j = rng.randrange(len(rs)), rng.randrange(len(header))
        v = rs[i][j]
        v = rng.choice(BAD) if rng.random() < 0.5 or not v.strip() else repr(float(v) * rng.choice(SCALES))
        rs[i][j] = v
        out[f"row {i + 1} {header[j]}={v!r}"] = build(header, rs)
    for j, c in enumerate(header):
        out[f"column {c} dropped"] = build(header[:j] + header[j + 1 :], [r[:j] + r[j + 1 :] for r in rows])
        out[f"header {c} dropped, not the data"] = build(header[:j] + header[j + 1 :], rows)
        out[f"column {c} all '0'"] = build(header, col(j, "0"))
        out[f"column {c} all empty"] = build(header, col(j, ""))
    out.update(
        {
            "empty file": "",
            "header only": build(header, []),
            "one row": build(header, rows[:1]),
            "two rows": build(header, rows[:2]),
            "BOM": "\ufeff" + build(header, rows),
            "CRLF": build(header, rows, eol="\r\n"),
            "tabs": build(header, rows, sep="\t"),
            "duplicate header column": build(header + ["mean_dn"], [r + ["1"] for r in rows]),
            "extra text column": build(header + ["comment"], [r + ["hello"] for r in rows]),
            "row too long": build(header, rows[:5] + [rows[5] + ["1"]] + rows[6:]),
            "row too short": build(header, rows[:5] + [rows[5][:-3]] + rows[6:]),
            "duplicated rows": build(header, rows + rows),
            "reversed rows": build(header, rows[::-1]),
            "binary": "\x00\x01\x02garbage\xff",
            "header upper case": build([h.upper() for h in header], rows),
            "every dark variance 0": build(header, col(header.index("dark_temporal_var_dn2"), "0")),
            "n_pixels 2 everywhere": build(header, col(header.index("n_pixels"), "2")),
        }
    )
    for m in METADATA:
        out[f"metadata {m!r}"] = build(header, rows, meta + [m])
    return out


def run(path):
    """(exit code or the exception, stderr lines, RuntimeWarnings) of ``bayescap fit PATH --quality fast``."""
    out, err = io.StringIO(), io.StringIO()
    with (
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
        warnings.catch_warnings(record=True) as caught,
    ):
        warnings.simplefilter("always", RuntimeWarning)
        try:
            code = cli.main(["fit", str(path), "--quality", "fast", "--seed", "1"])
        except SystemExit as e:
            code = e.code
        except Exception as e:  # noqa: BLE001 - a traceback is what this looks for
            code = f"{type(e).__name__}: {e}"
    runtime = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    return code, err.getvalue().strip().splitlines(), runtime


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="picks the random cells (default 0)")
    ap.add_argument("--cells", type=int, default=60, help="random single-cell corruptions (default 60)")
    ap.add_argument("--include-slow", action="store_true", help="also the two ~2-minute variants")
    a = ap.parse_args(argv)
    text = (ROOT / "data" / "emva1288_basler_ccd12.csv").read_text(encoding="utf-8")
    cases = variants(text, random.Random(a.seed), a.cells)
    defects, t0, codes, skipped = [], time.perf_counter(), {"fitted (exit 0)": 0, "refused in one line (exit 2)": 0}, 0
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, body) in enumerate(cases.items()):
            if name in SLOW and not a.include_slow:
                skipped += 1
                continue
            p = Path(tmp) / f"v{k}.csv"
            p.write_text(body, encoding="utf-8", errors="surrogateescape")
            before = p.read_bytes()
            t = time.perf_counter()
            code, lines, runtime = run(p)
            ok = code == 0 or (code == 2 and len(lines) == 1 and lines[0].startswith(f"bayescap: error: {p}"))
            bad = not ok or runtime or p.read_bytes() != before
            print(
                f"{time.perf_counter() - t:6.2f} s  exit {code}  {name[:60]:60s} {'DEFECT' if bad else ''}", flush=True
            )
            if bad:
                defects.append((name, code, lines[:2], runtime[:2]))
            elif code == 0:
                codes["fitted (exit 0)"] += 1
            else:
                codes["refused in one line (exit 2)"] += 1
    wall = time.perf_counter() - t0
    cmd = (
        "python benchmarks/corrupt_inputs.py"
        + (f" --seed {a.seed}" if a.seed else "")
        + (f" --cells {a.cells}" if a.cells != 60 else "")
        + (" --include-slow" if a.include_slow else "")
    )
    L = [
        "# The bundled Basler CSV corrupted, through `bayescap fit --quality fast`",
        "",
        f"Generated by `{cmd}` in {wall:.0f} s; machine: {describe_machine()}.",
        "",
        f"{len(cases) - skipped} variants ({a.cells} random single cells, seed {a.seed}; every column dropped, zero "
        "or empty; structural and metadata corruptions"
        + (f"; the {skipped} slow ones skipped: `--include-slow`" if skipped else "")
        + "). A defect is a "
        "traceback, a RuntimeWarning, more than one line of error, or a modified input.",
        "",
        "| outcome | variants |",
        "|---|---|",
    ]
    L += [f"| {k} | {v} |" for k, v in codes.items()] + [f"| **defect** | {len(defects)} |", ""]
    if defects:
        L += ["| variant | exit | stderr | RuntimeWarnings |", "|---|---|---|---|"]
        L += [f"| {n} | {c} | {' / '.join(ln)} | {' / '.join(rt)} |".replace("\n", " ") for n, c, ln, rt in defects]
    emit(L, OUT)
    return 1 if defects else 0


if __name__ == "__main__":
    sys.exit(main())
