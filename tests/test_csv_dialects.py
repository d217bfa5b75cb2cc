"""Spreadsheet exports of the photon-transfer CSV: ';' with decimal commas, Excel's 'sep=' line,
trailing empty columns; control characters in metadata."""

import numpy as np
import pytest

from bayescap.io.ptc_csv import REQUIRED_COLUMNS, read_ptc_csv


def _split(basler_csv):
    lines = basler_csv.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    return lines[:k], lines[k:]


def _same(a, b):
    for c in REQUIRED_COLUMNS:
        np.testing.assert_array_equal(getattr(a, c), getattr(b, c))
    assert a.metadata == b.metadata


def test_semicolon_decimal_comma_sep_line_and_padding(basler_csv, tmp_path):
    ref = read_ptc_csv(basler_csv)
    meta, table = _split(basler_csv)
    euro = [ln.replace(",", ";").replace(".", ",") for ln in table]  # 4e-05, 30,9658, ...
    p = tmp_path / "euro.csv"
    p.write_text("sep=;\n" + "\n".join(m + ";;;" for m in meta) + "\n" + "\n".join(r + ";;" for r in euro) + "\n")
    got = read_ptc_csv(p)
    _same(got, ref)
    p2 = tmp_path / "euro_nosep.csv"
    p2.write_text("\n".join(meta) + "\n" + "\n".join(euro) + "\n")
    _same(read_ptc_csv(p2), ref)


def test_excel_sep_line_and_trailing_empty_columns(basler_csv, tmp_path):
    ref = read_ptc_csv(basler_csv)
    meta, table = _split(basler_csv)
    p = tmp_path / "excel.csv"
    p.write_text('"sep=,"\n' + "\n".join(meta) + "\n" + "\n".join(r + ",," for r in table) + "\n,,,\n")
    _same(read_ptc_csv(p), ref)


def test_control_characters_in_metadata_do_not_reach_the_terminal(basler_csv, tmp_path):
    meta, table = _split(basler_csv)
    p = tmp_path / "ansi.csv"
    p.write_text("# sensor: \x1b[31mred\x1b[0m cam\x07\n" + "\n".join(meta[1:] + table) + "\n")
    md = read_ptc_csv(p).metadata
    assert md["sensor"] == "red cam" and "\x1b" not in md["sensor"]


def test_a_real_error_in_a_semicolon_table_still_names_row_and_column(basler_csv, tmp_path):
    from bayescap.exceptions import PTCInputError

    meta, table = _split(basler_csv)
    rows = [ln.replace(",", ";") for ln in table]
    rows[3] = rows[3].replace(";", ";abc;", 1)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(meta + rows) + "\n")
    with pytest.raises(PTCInputError, match="row 3"):
        read_ptc_csv(p)


@pytest.mark.parametrize(
    "kw, fragment",
    [
        ({"quality": None}, "quality must be one of"),
        ({"quality": "best"}, "quality must be one of"),
        ({"seed": -1}, "seed must be a whole number"),
        ({"seed": 1.5}, "seed must be a whole number"),
        ({"seed": True}, "seed must be a whole number"),
        ({"prior": {"read_log_bounds": (20, 1)}}, "lo < hi"),
        ({"prior": {"read_log_bounds": (0, 1)}}, "> 0"),
        ({"prior": {"qe_bounds": (0.5, 2)}}, "(0, 1]"),
        ({"prior": {"read_scale_e": -3}}, "> 0"),
        ({"prior": {"no_such": 1}}, "unknown prior key"),
        ({"prior": [1, 2]}, "must be a dict"),
        ({"fallback_quality": "x"}, "fallback_quality"),
    ],
)
def test_api_fit_refuses_bad_arguments_with_input_errors(basler_csv, kw, fragment):
    import bayescap
    from bayescap.exceptions import InputError

    data = bayescap.load(basler_csv)
    with pytest.raises(InputError, match=fragment.replace("(", r"\(").replace(")", r"\)").replace("]", r"\]")):
        bayescap.fit(data, **kw)


def test_metadata_overrides_are_typed(basler_csv):
    import bayescap
    from bayescap.exceptions import InputError

    for kw in ({"adc_bits": 12.5}, {"adc_bits": "12"}, {"pixel_pitch_um": float("nan")}, {"width_px": True}):
        with pytest.raises(InputError, match="metadata override"):
            bayescap.load(basler_csv, **kw)
        with pytest.raises(InputError, match="metadata override"):
            bayescap.load(basler_csv).with_metadata(**kw)
    assert bayescap.load(basler_csv, adc_bits=12.0).metadata["adc_bits"] == 12
    with pytest.raises(InputError, match="between 1 and 32"):
        bayescap.load(basler_csv).with_metadata(adc_bits=40)
