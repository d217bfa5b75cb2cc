"""Output paths and faults of the commands: outputs never over an input, checked before any
fitting, written as a whole set or not at all; names with ``$`` in plots; exit statuses."""

import json
from pathlib import Path

import pytest

from bayescap.cli import main


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    from bayescap.simulate import SensorTruth, simulate_ptc

    p = tmp_path_factory.mktemp("csv") / "cam_$5_vs_$10.csv"
    simulate_ptc(
        SensorTruth(conversion_gain_e_per_dn=2.0, read_noise_e=3.0, full_well_e=8000.0),
        seed=3,
        shape=(50, 50),
        n_levels=20,
        path=p,
        metadata={"pixel_pitch_um": 2.2},
    )
    return p


@pytest.fixture(scope="module")
def out_set(small_csv, tmp_path_factory):
    """``bayescap fit small_csv --quality fast --seed 1 --out DIR``: the folder, for the tests that
    read a first set (one fit and one set of plots and posterior for the module)."""
    out = tmp_path_factory.mktemp("out_set") / "o"
    assert main(["fit", str(small_csv), "--quality", "fast", "--seed", "1", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_dollar_in_file_name_does_not_reach_math_text(small_csv, out_set, tmp_path, capsys):
    assert (out_set / "ptc.png").stat().st_size > 0
    rep = tmp_path / "r.html"
    assert main(["report", str(small_csv), "-o", str(rep), "--quality", "fast", "--seed", "1"]) == 0
    assert "cam_$5_vs_$10" in rep.read_text()


EDGE = Path(__file__).parent / "data" / "slanted_edge" / "sfrmat3_v_edge_mono.tif"


def _no_fit(monkeypatch):
    """Make any fit an error: the checks below must come before fitting."""
    import bayescap.api
    import bayescap.studies.compare

    def boom(*a, **k):
        raise AssertionError("fitted before checking the output")

    monkeypatch.setattr(bayescap.api, "fit", boom)
    monkeypatch.setattr(bayescap.studies.compare, "compare", boom)  # what report and compare import when they run


def _one_line_exit(code, argv, capsys, *fragments):
    assert main(argv) == code
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    for f in fragments:
        assert f in err, (f, err)


def test_an_output_that_is_an_input_is_refused_before_any_work(small_csv, tmp_path, capsys, monkeypatch):
    _no_fit(monkeypatch)
    csv_copy = tmp_path / "in.csv"
    csv_copy.write_bytes(small_csv.read_bytes())
    before = csv_copy.read_bytes()
    edge = tmp_path / "e.tif"
    edge.write_bytes(EDGE.read_bytes())
    for argv in (
        ["mtf", str(edge), "--out", str(edge)],
        ["report", str(csv_copy), "-o", str(csv_copy)],
        ["report", str(csv_copy), "-o", str(tmp_path / "." / "in.csv")],
        ["fit", str(csv_copy), "--out", str(csv_copy)],
        ["fit", str(csv_copy), "--out", str(tmp_path)],  # the directory holding the input is replaced
        ["compare", str(csv_copy), "--out", str(csv_copy)],
    ):
        _one_line_exit(2, argv, capsys, "in" if "mtf" not in argv else "e.tif")
    assert csv_copy.read_bytes() == before and edge.read_bytes() == EDGE.read_bytes()


def test_an_output_place_that_cannot_be_written_is_refused_before_fitting(small_csv, tmp_path, capsys, monkeypatch):
    _no_fit(monkeypatch)
    a_file = tmp_path / "f.txt"
    a_file.write_text("x")
    _one_line_exit(2, ["fit", str(small_csv), "--out", str(a_file)], capsys, "is a file")
    _one_line_exit(2, ["fit", str(small_csv), "--out", str(a_file / "sub")], capsys, "not a directory")
    _one_line_exit(2, ["report", str(small_csv), "-o", str(tmp_path)], capsys, "is a directory")
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.md").write_text("mine")
    _one_line_exit(2, ["fit", str(small_csv), "--out", str(other)], capsys, "notes.md")
    assert (other / "notes.md").read_text() == "mine"
    import os

    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            _one_line_exit(2, ["fit", str(small_csv), "--out", str(ro / "out")], capsys, "not writable")
        finally:
            ro.chmod(0o700)


def _leftovers(folder):
    return sorted(p.name for p in Path(folder).iterdir() if p.name.startswith("."))


def test_disk_full_while_writing_the_set_prints_the_result_and_leaves_nothing(small_csv, tmp_path, capsys, monkeypatch):
    import errno

    import bayescap.report.text as text

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(text, "plot_corner", full)
    out = tmp_path / "out"
    assert main(["fit", str(small_csv), "--quality", "fast", "--seed", "1", "--json", "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert json.loads(cap.out)["diagnostics"]["seed"] == 1  # the result is not lost
    err = cap.err.strip()
    assert err.count("\n") == 0 and "No space left on device" in err and "Traceback" not in err
    assert not out.exists() and _leftovers(tmp_path) == []
    # a NetCDF file that cannot fit is refused before h5py starts (h5py crashes on ENOSPC)
    monkeypatch.undo()
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9, 1000))
    assert main(["fit", str(small_csv), "--quality", "fast", "--seed", "1", "--out", str(out)]) == 1
    assert "No space left" in capsys.readouterr().err
    assert not out.exists() and _leftovers(tmp_path) == []


@pytest.mark.slow
def test_the_out_set_is_replaced_as_a_whole(small_csv, out_set, tmp_path, capsys, monkeypatch):
    """A second run into the same folder replaces the first run's set as a whole; a failed run
    leaves the previous set as it was and no temporary files."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(out_set, out)  # the first run's set
    first = (out / "result.json").read_text()
    (out / "corner.png").unlink()  # a set that lost a file: replaced whole, not topped up
    assert main(["fit", str(small_csv), "--quality", "fast", "--seed", "2", "--out", str(out)]) == 0
    second = (out / "result.json").read_text()
    assert second != first and (out / "corner.png").exists()
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["result.json", "report.txt", "posterior.nc", "ptc.png", "corner.png"]
    )
    import bayescap.report.text as text

    def killed(*a, **k):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(text, "to_inference_data", killed)  # after result.json and report.txt are in the new set
    assert main(["fit", str(small_csv), "--quality", "fast", "--seed", "3", "--out", str(out)]) == 1
    assert (out / "result.json").read_text() == second and _leftovers(tmp_path) == []
    capsys.readouterr()


def _bomb_tiff(path, shape=(40000, 40000)):
    """A small TIFF that declares ``shape`` pixels (one compressed strip of zeros)."""
    import numpy as np
    import tifffile

    with tifffile.TiffWriter(path) as tw:
        tw.write(np.zeros((16, 16), np.uint16), compression="zlib")
    # rewrite ImageWidth/ImageLength (SHORT or LONG) in place: the declared size, not the data
    b = bytearray(path.read_bytes())
    with tifffile.TiffFile(path) as tif:
        for tag in (256, 257):
            t = tif.pages[0].tags[tag]
            fmt = {3: "<H", 4: "<I"}[t.dtype]
            import struct

            struct.pack_into(fmt, b, t.valueoffset, shape[1] if tag == 256 else shape[0])
    path.write_bytes(bytes(b))


def _bomb_png(path, width, height):
    """A small PNG whose header declares ``width`` x ``height`` pixels."""
    import struct
    import zlib

    from PIL import Image

    Image.new("L", (16, 16)).save(path)
    b = bytearray(path.read_bytes())
    struct.pack_into(">II", b, 16, width, height)  # IHDR data start at byte 16
    struct.pack_into(">I", b, 29, zlib.crc32(bytes(b[12:29])))
    path.write_bytes(bytes(b))
    return path


def test_images_declaring_too_many_pixels_are_refused_before_decoding(tmp_path, capsys, monkeypatch):
    from bayescap.exceptions import IngestError, MTFInputError
    from bayescap.io.frames import read_frame
    from bayescap.measure import read_image

    tif = tmp_path / "bomb.tif"
    _bomb_tiff(tif)
    with pytest.raises(IngestError, match="40000 x 40000"):
        read_frame(tif)
    png = _bomb_png(tmp_path / "bomb.png", 40000, 40000)  # past Pillow's own limit
    with pytest.raises(MTFInputError, match="exceeds limit"):
        read_image(png)
    _one_line_exit(2, ["mtf", str(png)], capsys, "bomb.png")
    png = _bomb_png(tmp_path / "big.png", 12000, 12000)
    monkeypatch.setenv("BAYESCAP_MAX_IMAGE_PIXELS", str(10**8))
    _one_line_exit(2, ["mtf", str(png)], capsys, "12000 x 12000", "BAYESCAP_MAX_IMAGE_PIXELS")
    with pytest.raises(IngestError, match="12000 x 12000"):
        read_frame(png)
    monkeypatch.setenv("BAYESCAP_MAX_IMAGE_PIXELS", "100")
    with pytest.raises(MTFInputError, match="limit of 100"):
        read_image(EDGE)


def test_strict_exit_status_and_drawn_seed(small_csv, tmp_path, capsys, monkeypatch):
    """Without --seed a seed is drawn, used and recorded ('seed N (drawn)'); the same seed gives the
    same numbers. --strict: exit 3 when a result is not converged."""
    argv = ["fit", str(small_csv), "--quality", "fast", "--json"]
    assert main(argv) == 0
    d = json.loads(capsys.readouterr().out)
    seed = d["diagnostics"]["seed"]
    assert isinstance(seed, int) and d["diagnostics"]["seed_drawn"] is True
    assert main(argv + ["--seed", str(seed)]) == 0
    d2 = json.loads(capsys.readouterr().out)
    assert d2["parameters"] == d["parameters"] and "seed_drawn" not in d2["diagnostics"]
    assert main(argv[:-1]) == 0
    assert " (drawn)" in capsys.readouterr().out
    import bayescap.api

    real = bayescap.api.fit

    def unconverged(*a, **k):
        r = real(*a, **k)
        r.diag["converged"] = False
        return r

    monkeypatch.setattr(bayescap.api, "fit", unconverged)
    assert main(argv + ["--seed", "1"]) == 0  # reported in the output, not in the status
    assert main(argv + ["--seed", "1", "--strict"]) == 3
    assert "NOT CONVERGED" in capsys.readouterr().err


def test_help_documents_exit_statuses(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    out = capsys.readouterr().out
    for code in ("0 ", "1 ", "2 ", "3 "):
        assert "\n  " + code in out


def test_closed_pipe_is_no_traceback():
    import subprocess
    import sys

    p = subprocess.Popen(
        [sys.executable, "-m", "bayescap", "sweep", "pixel-size", "--format", "1/4in", "--json", "--draws", "300"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    p.stdout.readline()
    p.stdout.close()  # as `| head -1` does
    err = p.stderr.read().decode()
    p.wait()
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert p.returncode in (0, 141)
