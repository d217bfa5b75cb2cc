"""The bundled Basler CSV corrupted one value (or one structural feature) at a time: `bayescap fit`
either fits (exit 0) or refuses with one line naming the file (exit 2). Never an exception through
main (a traceback), never a RuntimeWarning on the way, never a modified input.

The corruptions are a fixed part of the sweep ``benchmarks/corrupt_inputs.py`` runs; the defects it
found are named in tests/test_ptc.py and tests/test_model.py."""

import contextlib
import io
import warnings
from pathlib import Path

import pytest

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


#: a bundled sensor with the Basler table's columns and size whose fast fit takes its fast path
#: (the Basler set's response terms send every fit of its ~40 fitting variants to MCMC: minutes);
#: benchmarks/corrupt_inputs.py corrupts the Basler set itself
BASE = Path(__file__).resolve().parents[1] / "data" / "simulated" / "sim_industrial_3p45um_12bit.csv"


#: the sweep in two halves (even and odd positions), so that under ``pytest -n 2`` both workers share it
PARTS = ("even", "odd")


def _part(variants, part):
    return {n: variants[n] for n in list(variants)[PARTS.index(part) :: 2]}


def test_the_parts_are_the_whole_sweep():
    variants = _variants(BASE.read_text())
    assert len(variants) > 100
    names = [n for part in PARTS for n in _part(variants, part)]
    assert sorted(names) == sorted(variants)


@pytest.mark.slow
@pytest.mark.parametrize("part", PARTS)
def test_every_corruption_fits_or_is_refused_in_one_line(part, tmp_path):
    variants = _variants(BASE.read_text())
    failures = []
    for i, (name, text) in enumerate(_part(variants, part).items()):
        p = tmp_path / f"v{i}.csv"
        p.write_text(text)
        code, lines, runtime = _run_fit(p)
        ok = code == 0 or (code == 2 and len(lines) == 1 and lines[0].startswith(f"bayescap: error: {p}"))
        if not ok or runtime or p.read_text() != text:
            failures.append((name, code, lines[:2], runtime[:2]))
    assert not failures, failures


def _table(basler_csv):
    lines = basler_csv.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    return lines[:k], lines[k].split(","), [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]


def hostile_variants(text):
    """{name: (CSV text, what the one-line error must hold)} of issue 48's hostile inputs: each
    refused in one line naming the file (and its row and column where there is one)."""
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    meta, header = lines[:k], lines[k].split(",")
    rows = [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]
    t = header.index("exposure_time_s")

    def build(rs, m=meta):
        return "\n".join(m + [",".join(header)] + [",".join(r) for r in rs]) + "\n"

    def scaled(f):
        return [r[:t] + [repr(float(r[t]) * f)] + r[t + 1 :] for r in rows]

    big = [list(r) for r in rows]
    big[3][1] = "1" * 10_000_000  # a 10 MB cell
    return {
        "subnormal exposure times": (build(scaled(1e-310)), ("row 1", "exposure_time_s", "subnormal")),
        "exposure times of 1e-300 s": (build(scaled(1e-300)), ("row 1", "exposure_time_s", "implausibly short")),
        "a 10 MB cell": (build(big), ("cannot read the table",)),
        "adc_bits 10 then 16": (build(rows, meta + ["# adc_bits: 10", "# adc_bits: 16"]), ("given twice", "line")),
        "width_px 1e30": (
            build(rows, [m for m in meta if not m.startswith("# width_px")] + ["# width_px: 1e30"]),
            ("width_px", "implausible"),
        ),
        "one row repeated 300 times": (build(rows + [rows[5]] * 300), ("repeats row 6", "301 copies")),
        "the table repeated 10 times": (build(rows * 10), ("repeats row 1", "10 copies")),
    }


def test_hostile_tables_are_refused_in_one_line(tmp_path, basler_csv, capfd):
    """Was: LAPACK's DLASCL text on stdout and a LinAlgError traceback (subnormal times); a
    ``_csv.Error`` traceback (10 MB cell); the last of two adc_bits taken silently; a capacity of
    5e33 bits (width 1e30); repeated rows taken as independent (K's interval ~3x too narrow)."""
    failures = []
    for i, (name, (text, needles)) in enumerate(hostile_variants(basler_csv.read_text()).items()):
        p = tmp_path / f"h{i}.csv"
        p.write_text(text)
        capfd.readouterr()
        code, lines, runtime = _run_fit(p)
        ok = code == 2 and len(lines) == 1 and lines[0].startswith(f"bayescap: error: {p}")
        # nothing on the process's standard output (LAPACK writes to file descriptor 1 directly)
        ok = ok and all(n in lines[0] for n in needles) and not runtime and capfd.readouterr().out == ""
        if not ok:
            failures.append((name, code, [ln[:200] for ln in lines[:2]]))
    assert not failures, failures


def test_an_absurd_scene_temperature_is_refused_before_fitting(basler_csv, monkeypatch, capsys):
    """Was: OverflowError (2^(ΔT/6)) after the whole fit."""
    import bayescap.api

    monkeypatch.setattr(bayescap.api, "fit", lambda *a, **k: pytest.fail("fitted"))
    p = basler_csv
    code = cli.main(["fit", str(p), "--temperature-c", "1e6", "--seed", "1"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "implausible" in err[0]
