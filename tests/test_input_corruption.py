"""The bundled Basler CSV corrupted one value (or one structural feature) at a time: `bayescap fit`
either fits (exit 0) or refuses with one line naming the file (exit 2). Never an exception through
main (a traceback), never a RuntimeWarning on the way, never a modified input.

The corruptions are a fixed part of the sweep ``benchmarks/corrupt_inputs.py`` runs; the defects it
found are named in tests/test_ptc.py and tests/test_model.py."""

import contextlib
import io
import warnings

from bayescap import cli


def _run_fit(path):
    """(exit code or the exception, stderr lines, RuntimeWarnings) of ``bayescap fit PATH --quality fast``
    in-process (as ``benchmarks/corrupt_inputs.py`` runs each variant)."""
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


TOKENS = ["abc", "", "nan", "inf", "-1", "0", "1e308", "1e-320"]


def _variants(text):
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    meta, header = lines[:k], lines[k].split(",")
    rows = [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]

    def build(h, rs, m=meta):
        return "\n".join(m + [",".join(h)] + [",".join(r) for r in rs]) + "\n"

    out = {}
    for j, col in enumerate(header):
        for tok in TOKENS:
            rs = [list(r) for r in rows]
            rs[9][j] = tok  # file row 10, on the slope of the curve
            out[f"row 10 {col}={tok!r}"] = build(header, rs)
        out[f"no {col}"] = build(header[:j] + header[j + 1 :], [r[:j] + r[j + 1 :] for r in rows])
    out["header only"] = build(header, [])
    out["two rows"] = build(header, rows[:2])
    out["row too long"] = build(header, rows[:5] + [rows[5] + ["1"]] + rows[6:])
    out["duplicated rows"] = build(header, rows + rows)
    out["semicolons"] = "\n".join(meta + [";".join(header)] + [";".join(r) for r in rows]) + "\n"
    for m in (
        "# adc_bits: 1.5",
        "# pixel_pitch_um: nan",
        "# crosstalk_sigma_px: 1e6",
        "# temperature_c: -300",
        "# fill_factor: 0",
    ):
        out[f"metadata {m!r}"] = build(header, rows, meta + [m])
    return out


def test_every_corruption_fits_or_is_refused_in_one_line(tmp_path, basler_csv):
    variants = _variants(basler_csv.read_text())
    failures = []
    for i, (name, text) in enumerate(variants.items()):
        p = tmp_path / f"v{i}.csv"
        p.write_text(text)
        code, lines, runtime = _run_fit(p)
        ok = code == 0 or (code == 2 and len(lines) == 1 and lines[0].startswith(f"bayescap: error: {p}"))
        if not ok or runtime or p.read_text() != text:
            failures.append((name, code, lines[:2], runtime[:2]))
    assert not failures, failures
    assert len(variants) > 100
