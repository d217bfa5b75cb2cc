"""Reading photon-transfer CSVs: the contract, and clear refusals (file, row, column; exit 2)."""

import subprocess
import sys

import numpy as np
import pytest

from bayescap.exceptions import PTCInputError
from bayescap.io.ptc_csv import read_ptc_csv, write_ptc_csv

HEADER = "exposure_time_s,mean_dn,temporal_var_dn2,dark_mean_dn,dark_temporal_var_dn2,n_pixels"
GOOD_ROWS = ["0.001,100,30,10,5,10000", "0.002,200,55,10,5,10000", "0.003,300,80,10,5,10000"]


def _cli(argv, capsys, fresh_process=False):
    """``bayescap ARGV``: (exit status, stdout, stderr), in a fresh ``python -m bayescap.cli``
    process or through the CLI's main in this one (where an uncaught exception fails the test)."""
    if fresh_process:
        r = subprocess.run([sys.executable, "-m", "bayescap.cli", *argv], capture_output=True, text=True)
        return r.returncode, r.stdout, r.stderr
    from bayescap.cli import main

    capsys.readouterr()
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _write(tmp_path, text, name="s.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_reads_metadata_rows_and_sorts(tmp_path):
    p = _write(
        tmp_path,
        "# sensor: demo\n# adc_bits: 12\n# pixel_pitch_um: 1.75\n# custom: kept\n"
        + HEADER
        + "\n"
        + "\n".join(reversed(GOOD_ROWS))
        + "\n",
    )
    d = read_ptc_csv(p)
    assert d.metadata == {"sensor": "demo", "adc_bits": 12, "pixel_pitch_um": 1.75, "custom": "kept"}
    assert list(d.mean_dn) == [100, 200, 300]
    assert list(d.row_numbers) == [3, 2, 1]  # row labels follow the file, not the sorted order
    with pytest.raises(ValueError):
        d.mean_dn[0] = 5  # immutable
    assert d.adc_max_dn == 4095


def test_overrides_replace_metadata(tmp_path):
    p = _write(tmp_path, "# f_number: 2.8\n" + HEADER + "\n" + "\n".join(GOOD_ROWS))
    d = read_ptc_csv(p, overrides={"f_number": 4.0, "width_px": 100})
    assert d.metadata["f_number"] == 4.0 and d.metadata["width_px"] == 100


def test_round_trip_with_sparse_spatial_columns(tmp_path):
    cols = {
        "exposure_time_s": [0.1, 0.2],
        "mean_dn": [100.0, 200.0],
        "temporal_var_dn2": [30.0, 55.0],
        "dark_mean_dn": [10.0, 10.0],
        "dark_temporal_var_dn2": [5.0, 5.0],
        "n_pixels": [100, 100],
        "spatial_var_dn2": [np.nan, 12.5],
        "n_frames": [np.nan, 16],
    }
    write_ptc_csv({k: np.asarray(v, float) for k, v in cols.items()}, tmp_path / "x.csv", metadata={"sensor": "a"})
    d = read_ptc_csv(tmp_path / "x.csv")
    assert np.isnan(d.spatial_var_dn2[0]) and d.spatial_var_dn2[1] == 12.5 and d.n_frames[1] == 16


BAD = {
    "missing column": (
        HEADER.replace(",n_pixels", "") + "\n0.001,100,30,10,5\n0.002,200,55,10,5\n",
        ["missing required column", "n_pixels"],
    ),
    "text in a number": (
        HEADER + "\n0.001,100,abc,10,5,10000\n" + GOOD_ROWS[1] + "\n",
        ["row 1", "temporal_var_dn2", "expected a number", "'abc'"],
    ),
    "NaN": (HEADER + "\n" + GOOD_ROWS[0] + "\n0.002,nan,55,10,5,10000\n", ["row 2", "mean_dn", "finite"]),
    "negative variance": (
        HEADER + "\n" + GOOD_ROWS[0] + "\n0.002,200,-55,10,5,10000\n",
        ["row 2", "temporal_var_dn2", "negative variance"],
    ),
    "one row": (HEADER + "\n" + GOOD_ROWS[0] + "\n", ["at least 2 data rows"]),
    "empty file": ("", ["empty file"]),
    "negative exposure": (
        HEADER + "\n-0.001,100,30,10,5,10000\n" + GOOD_ROWS[1] + "\n",
        ["row 1", "exposure_time_s", "negative"],
    ),
    "n_pixels < 2": (HEADER + "\n0.001,100,30,10,5,1\n" + GOOD_ROWS[1] + "\n", ["row 1", "n_pixels"]),
    "short row": (HEADER + "\n0.001,100,30\n" + GOOD_ROWS[1] + "\n", ["row 1", "fields"]),
    "bad metadata": ("# adc_bits: twelve\n" + HEADER + "\n" + "\n".join(GOOD_ROWS), ["adc_bits", "metadata line 1"]),
    "negative crosstalk": (
        "# crosstalk_sigma_px: -0.3\n" + HEADER + "\n" + "\n".join(GOOD_ROWS),
        ["crosstalk_sigma_px", ">= 0"],
    ),
    "mean above ADC max": (
        "# adc_bits: 8\n" + HEADER + "\n" + GOOD_ROWS[0] + "\n0.002,300,55,10,5,10000\n",
        ["row 2", "mean_dn", "ADC maximum"],
    ),
    # found by corrupting the Basler CSV value by value: these reached the optimiser,
    # whose overflow ended in a traceback
    "implausibly large value": (
        HEADER + "\n" + GOOD_ROWS[0] + "\n1e308,200,55,10,5,10000\n",
        ["row 2", "exposure_time_s", "implausibly large"],
    ),
    "variance beyond the ADC's range": (
        "# adc_bits: 8\n" + HEADER + "\n" + GOOD_ROWS[0] + "\n0.002,200,70000,10,5,10000\n",
        ["row 2", "temporal_var_dn2", "square of the ADC maximum"],
    ),
    "temperature below absolute zero": (
        "# temperature_c: -300\n" + HEADER + "\n" + "\n".join(GOOD_ROWS),
        ["temperature_c", "absolute zero"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_csv_refused_with_location(tmp_path, case):
    text, fragments = BAD[case]
    p = _write(tmp_path, text)
    with pytest.raises(PTCInputError) as e:
        read_ptc_csv(p)
    msg = str(e.value)
    assert str(p) in msg
    for frag in fragments:
        assert frag in msg, (frag, msg)


@pytest.mark.parametrize(
    "case", ["missing column", "text in a number", "NaN", "negative variance", "one row", "empty file"]
)
def test_cli_refuses_bad_csv_exit_2_one_line_no_traceback(tmp_path, case, capsys):
    """The first case in a fresh process (the exit status and stderr a shell sees), the others through
    the CLI's main in this process."""
    text, fragments = BAD[case]
    p = _write(tmp_path, text)
    out = tmp_path / "out"
    code, stdout, stderr = _cli(["fit", str(p), "--out", str(out)], capsys, fresh_process=case == "missing column")
    assert code == 2
    assert stdout == ""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bayescap: error:"), stderr
    assert "Traceback" not in stderr
    assert not out.exists()  # nothing half-written


def test_cli_missing_file(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "bayescap.cli", "fit", str(tmp_path / "nope.csv")], capture_output=True, text=True
    )
    assert r.returncode == 2 and "file not found" in r.stderr and "Traceback" not in r.stderr


def test_input_never_modified(tmp_path, basler_csv):
    before = basler_csv.read_bytes()
    read_ptc_csv(basler_csv)
    assert basler_csv.read_bytes() == before


def _basler_variant(basler_csv, tmp_path, edit, meta=""):
    """The bundled Basler CSV with ``edit(header, rows)`` applied to its data rows (lists of
    strings) and ``meta`` lines added: the path, and the file row label of each data row."""
    lines = basler_csv.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    header, rows = lines[k].split(","), [ln.split(",") for ln in lines[k + 1 :] if ln.strip()]
    edit(header, rows)
    p = tmp_path / "variant.csv"
    p.write_text(
        "\n".join(lines[:k] + ([meta] if meta else []) + [",".join(header)] + [",".join(r) for r in rows]) + "\n"
    )
    return p


def _cli_fit_refuses(p, tmp_path, fragments, capsys, fresh_process=False):
    out = tmp_path / "out"
    argv = ["fit", str(p), "--quality", "fast", "--seed", "1", "--out", str(out)]
    code, stdout, stderr = _cli(argv, capsys, fresh_process)
    assert code == 2, stderr
    assert stdout == "" and "Traceback" not in stderr and not out.exists()
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bayescap: error:"), stderr
    for frag in fragments:
        assert frag in lines[0], (frag, lines[0])


def test_value_no_parameter_can_explain_is_refused_with_its_row(tmp_path, basler_csv, capsys):
    """A spatial variance of 0 on an unsaturated row (the reader accepts it: a dark one can be 0)
    has no finite likelihood anywhere; the optimiser had stopped with a RuntimeError and a
    traceback. Now: exit 2, the file, the row and the column (inference.starts._no_finite_start)."""

    def zero_spatial(header, rows):
        rows[17][header.index("spatial_var_dn2")] = "0"  # file row 18

    p = _basler_variant(basler_csv, tmp_path, zero_spatial)
    _cli_fit_refuses(
        p, tmp_path, [str(p), "row 18", "column 'spatial_var_dn2'", "no finite likelihood"], capsys, fresh_process=True
    )


def test_mtf_zero_at_every_frequency_is_refused_before_fitting(tmp_path, basler_csv, capsys):
    """A crosstalk σ of 10⁶ px makes the MTF zero across the band: Δs = −∞; a ValueError with a
    traceback before, after the fit. Now refused up front with where the MTF came from."""
    p = _basler_variant(basler_csv, tmp_path, lambda h, r: None, meta="# crosstalk_sigma_px: 1e6")
    _cli_fit_refuses(p, tmp_path, [str(p), "MTF is zero at every frequency", "crosstalk_sigma_px"], capsys)


def test_batch_names_an_input_error_once(tmp_path, basler_csv):
    """``bayescap fit A.csv B.csv``: a sensor whose value no parameter can explain is reported as the
    input error it is (file, row, column), once per line, and the batch exits 1."""

    def zero_spatial(header, rows):
        rows[17][header.index("spatial_var_dn2")] = "0"

    p = _basler_variant(basler_csv, tmp_path, zero_spatial)
    r = subprocess.run(
        [sys.executable, "-m", "bayescap.cli", "fit", str(p), str(p), "--quality", "fast"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 1 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 2
    for ln in lines:
        assert ln.startswith(f"bayescap: error: {p}, row 18, column 'spatial_var_dn2'"), ln
        assert ln.count(str(p)) == 1


def test_mtf_above_one_is_flagged_and_an_all_zero_table_refused(tmp_path, basler_csv, capsys):
    """A sharpened MTF (above 1 over the band) gives Δs > 0, which Eq. 9 does not allow for: the
    result carries the flag and a note (the fit's JSON, through the CLI's main in this process). An
    all-zero MTF table without a 0 cy/px row is refused before fitting, naming the table (a fresh
    process)."""
    import json

    sharp = tmp_path / "sharp.csv"
    sharp.write_text("freq_cy_per_px,mtf\n0.05,1.6\n0.5,1.4\n")
    code, stdout, stderr = _cli(
        ["fit", str(basler_csv), "--quality", "fast", "--seed", "1", "--mtf", str(sharp), "--json"], capsys
    )
    assert code == 0, stderr
    d = json.loads(stdout)
    assert d["flags"].get("mtf_above_one") is True
    assert any(n.startswith("the MTF exceeds 1") for n in d["notes"])
    zeros = tmp_path / "zeros.csv"
    zeros.write_text("freq_cy_per_px,mtf\n0.05,0\n0.5,0\n")
    r = subprocess.run(
        [sys.executable, "-m", "bayescap.cli", "fit", str(basler_csv), "--quality", "fast", "--mtf", str(zeros)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "MTF is zero at every frequency" in lines[0] and "zeros.csv" in lines[0]


def test_a_lit_mean_far_below_its_dark_mean_is_refused_with_its_row(tmp_path, basler_csv):
    """A flat's mean 0 DN under a dark mean of 64 DN sent the fit to a sampler that could not
    converge (a minute, R-hat 1.8); 4 pixel σ below the dark mean is now an input error naming the
    row, 2 σ below (a black-level drift's size, far beyond the means' own scatter) still reads."""
    from dataclasses import replace

    from bayescap.io.ptc_csv import check_table
    from bayescap.io.table_checks import DARKER_THAN_DARK_SIGMA

    def lit_below_dark(n_sigma):
        def edit(header, rows):
            r = rows[4]  # file row 5
            var = float(r[header.index("temporal_var_dn2")]) + float(r[header.index("dark_temporal_var_dn2")])
            r[header.index("mean_dn")] = repr(float(r[header.index("dark_mean_dn")]) - n_sigma * (var + 1 / 12) ** 0.5)

        return edit

    assert DARKER_THAN_DARK_SIGMA == 3.0
    ok = read_ptc_csv(_basler_variant(basler_csv, tmp_path, lit_below_dark(2.0)))
    assert np.sum(ok.signal_dn < 0) == 1
    with pytest.raises(PTCInputError, match=r"row 5, column 'mean_dn': the lit mean .* DN below the row's dark mean"):
        read_ptc_csv(_basler_variant(basler_csv, tmp_path, lit_below_dark(4.0)))
    # the same check on a table built in memory (the API path)
    i = int(np.argmin(ok.signal_dn))
    mean = np.array(ok.mean_dn)
    mean[i] -= 2.0 * np.sqrt(ok.temporal_var_dn2[i] + ok.dark_temporal_var_dn2[i] + 1 / 12)
    with pytest.raises(PTCInputError, match="row 5"):
        check_table(replace(ok, mean_dn=mean))
