"""Hostile options and files of the smaller commands (issue 48): each refused in one line (exit 2,
nothing written) or read as documented; never an input overwritten, never a file's bytes or its
control characters echoed."""

import math
from pathlib import Path

import numpy as np
import pytest

from bayescap.cli import main

EDGE = Path(__file__).parent / "data" / "slanted_edge" / "sfrmat3_v_edge_mono.tif"


def _lens(path, col="frequency_cy_per_px"):
    f = np.linspace(0, 1.0, 41)
    rows = "\n".join(f"{a:.6g},{math.exp(-3 * a * a):.6g}" for a in f)
    path.write_text(f"{col},mtf\n{rows}\n")
    return path


def _one_line_error(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_mtf_out_over_the_lens_table_is_refused(tmp_path, capsys):
    """Was: ``mtf --lens-mtf L.csv --out L.csv`` overwrote the lens table."""
    lens = _lens(tmp_path / "L.csv")
    before = lens.read_bytes()
    assert main(["mtf", str(EDGE), "--lens-mtf", str(lens), "--out", str(lens), "--n-boot", "20"]) == 2
    assert "would overwrite an input" in _one_line_error(capsys)
    assert lens.read_bytes() == before


@pytest.mark.parametrize(
    "opts, needle",
    [
        (["--n-boot", "0"], "--n-boot"),  # was [nan, nan], exit 0
        (["--n-boot", "10000000"], "--n-boot"),  # was MemoryError
        (["--pixel-pitch-um", "0"], "--pixel-pitch-um"),  # was "inf lp/mm"
        (["--height-px", "-3"], "--height-px"),  # was accepted
    ],
)
def test_mtf_numbers_out_of_range_are_refused_before_any_work(opts, needle, tmp_path, capsys):
    out = tmp_path / "m.csv"
    assert main(["mtf", str(EDGE), "--out", str(out), *opts]) == 2
    assert needle in _one_line_error(capsys)
    assert not out.exists()


def test_mtf_edge_errors_name_the_file(tmp_path, capsys):
    """Was: six messages of the edge analysis without the file name (a constant image, a bad ROI...)."""
    flat = tmp_path / "flat.npy"
    np.save(flat, np.full((60, 60), 0.5))
    for opts in ([], ["--roi", "0,0,5,5"], ["--channel", "Q"]):
        assert main(["mtf", str(flat), *opts, "--n-boot", "20"]) == 2
        assert _one_line_error(capsys).startswith(f"bayescap: error: {flat}")


def test_lens_and_system_tables_read_both_frequency_names(tmp_path):
    """Was: ``fit --mtf`` wanted ``freq_cy_per_px``, ``mtf --lens-mtf`` ``frequency_cy_per_px``."""
    from bayescap.measure import read_mtf_table
    from bayescap.measure.detector import read_lens_mtf_table

    for col in ("freq_cy_per_px", "frequency_cy_per_px"):
        p = _lens(tmp_path / f"{col}.csv", col)
        assert read_lens_mtf_table(p).unit == "cy/px"
        assert read_mtf_table(p).freq_cy_per_px.size == 41


def test_datasheet_outputs_on_one_file_are_refused(tmp_path, capsys, basler_csv):
    """Was: ``datasheet -o X --json X``: one output replaced the other."""
    x = tmp_path / "x.html"
    assert main(["datasheet", str(basler_csv), "-o", str(x), "--json", str(x)]) == 2
    assert "--json" in _one_line_error(capsys) and not x.exists()


def test_a_manifest_never_echoes_a_files_bytes(tmp_path, capsys):
    """Was: a manifest path to /etc/shadow got the file's first bytes in the error (``header=b'root'``)."""
    secret = b"SECRETPASSWORD:x:1:2\n"
    for n in ("a.tif", "b.tif"):
        (tmp_path / n).write_bytes(secret)
    for n in ("d1.npy", "d2.npy"):
        np.save(tmp_path / n, np.full((64, 64), 10, np.uint16))
    m = tmp_path / "m.csv"
    m.write_text(
        "file,kind,exposure_time_s\na.tif,bright,0.001\nb.tif,bright,0.001\nd1.npy,dark,0.001\nd2.npy,dark,0.001\n"
    )
    assert main(["ingest", str(m), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "a.tif" in err and "SECR" not in err and len(err.strip().splitlines()) == 1


def test_control_characters_of_a_tiff_tag_are_not_echoed():
    from bayescap.io.frames import _tag_text

    assert _tag_text(b"Cam\x00\x1b[2J\x1b]0;pwn\x07Era\x00") == "Cam]0;pwnEra"
    assert _tag_text("\x00\x00") is None


def test_no_image_limit_means_none(tmp_path, monkeypatch):
    """``BAYESCAP_MAX_IMAGE_PIXELS=0`` (no limit) held over Pillow's own decompression-bomb limit.
    Was: Pillow refused the image at its own limit anyway."""
    from PIL import Image

    from bayescap.measure import read_image

    p = tmp_path / "big.png"
    Image.new("L", (400, 300), 7).save(p)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # Pillow's limit far below the image
    monkeypatch.setenv("BAYESCAP_MAX_IMAGE_PIXELS", "0")
    assert read_image(p).shape == (300, 400)
    assert Image.MAX_IMAGE_PIXELS == 1000  # restored
    monkeypatch.setenv("BAYESCAP_MAX_IMAGE_PIXELS", "100000")
    from bayescap.exceptions import MTFInputError

    with pytest.raises(MTFInputError, match="limit"):
        read_image(p)
