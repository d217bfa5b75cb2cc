"""Ingest of an EMVA 1288 descriptor with spatial stacks (issue 49): the real Basler reference
set's frames (centre crops, tests/data/emva1288_basler) listed in a descriptor as the original lists
them, 50 pair blocks, a 50-frame bright stack and a 50-frame dark stack. The stack is the spatial
row of the EMVA 1288 view (not a 2-frame pair) and no row of its photon-transfer sweep; and one
frame given to ``ingest`` says that a measurement needs pairs."""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import numpy as np
import pytest

import bayescap
from bayescap.cli import main
from bayescap.exceptions import IngestError
from bayescap.io.ingest import ingest
from bayescap.posterior.emva import emva1288_view

DATA = Path(__file__).resolve().parent / "data" / "emva1288_basler"


def _descriptor(folder: Path) -> Path:
    """The descriptor and its frames: the 64×64 pixels both the pairs' and the stacks' crops hold."""
    z = np.load(DATA / "frames_center_crops.npz")
    c = slice(32, 96)  # the pair crops start 32 pixels before the stack crops (crop origins)
    assert np.array_equal(z["crop_spatial_origin_yx"] - z["crop_temporal_origin_yx"], [32, 32])
    (folder / "images").mkdir(parents=True)
    lines = ["v 3.0", "n 12 64 64"]

    def put(name, a):
        np.save(folder / "images" / name, np.ascontiguousarray(a))
        return f"i images/{name}"

    for i in range(50):
        lines.append(f"b {z['bright_texp_ns'][i]} {z['bright_photons_per_pixel'][i]}")
        lines += [put(f"b_{i:03d}_{j}.npy", z["bright_pairs"][i, j][c, c]) for j in range(2)]
    lines.append(f"b {float(z['spatial_bright_texp_ns'])} {float(z['spatial_bright_photons_per_pixel'])}")
    lines += [put(f"b_s_{j:03d}.npy", f) for j, f in enumerate(z["spatial_bright_stack"])]
    for i in range(50):
        lines.append(f"d {z['dark_texp_ns'][i]}")
        lines += [put(f"d_{i:03d}_{j}.npy", z["dark_pairs"][i, j][c, c]) for j in range(2)]
    lines.append(f"d {float(z['spatial_dark_texp_ns'])}")
    lines += [put(f"d_s_{j:03d}.npy", f) for j, f in enumerate(z["spatial_dark_stack"])]
    path = folder / "EMVA1288_Data.txt"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def ingested(tmp_path_factory):
    folder = tmp_path_factory.mktemp("emva")
    out = folder / "ptc.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ingest(_descriptor(folder), out=out, roi="0,0,64,64")
        r = bayescap.fit(out, seed=1, quality="fast")
    return out, r, emva1288_view(r)


def test_the_stack_is_the_spatial_row_not_a_sweep_row(ingested):
    out, r, view = ingested
    rows = list(csv.DictReader(line for line in out.read_text().splitlines() if not line.startswith("#")))
    stack = [row for row in rows if row["n_frames"] == "50"]
    assert len(rows) == 51 and len(stack) == 1
    z = np.load(DATA / "frames_center_crops.npz")
    sp = view["spatial_row"]
    assert sp["n_frames"] == 50  # the stack, not a 2-frame pair
    # its signal: the stacks' means, independently of ingest
    want = z["spatial_bright_stack"].mean() - z["spatial_dark_stack"].mean()
    assert sp["signal_dn"] == pytest.approx(want, rel=1e-3)
    assert view["saturation"]["sweep_rows"] == 50  # the 50 pair blocks


def test_linearity_error_is_the_pairs(ingested):
    """LE from the 50 pair rows: emva1288 gives −0.62 / +0.48 % on the full frames; these 4096
    pixels are a crop of them, so the extremes agree to within a few tenths of a percent, not 1066 %."""
    _, _, view = ingested
    q = view["quantities"]
    assert -1.0 < q["LE_min"]["median"] < 0 < q["LE_max"]["median"] < 1.0


def test_dsnu_recipe_comes_from_the_stack(ingested):
    """The standard's recipe on the stack row: spatial variance of the 50-frame average minus the
    temporal part over 50, here computed from the frames directly."""
    _, r, view = ingested
    z = np.load(DATA / "frames_center_crops.npz")
    dark = z["spatial_dark_stack"].astype(float)
    s2 = dark.mean(axis=0).var(ddof=1)  # spatial variance of the 50-frame average
    diff = dark[0] - dark[1]
    tvar = 0.5 * np.mean((diff - diff.mean()) ** 2)  # temporal variance of the first pair
    sp = view["spatial_row"]
    assert sp["s2_y_dark"] == pytest.approx(s2 - tvar / 50, abs=1e-9)
    # a 2-frame pair would leave its temporal part at tvar/2, far above this crop's pattern
    assert abs(sp["s2_y_dark"]) < 0.05 < tvar / 2


@pytest.mark.parametrize("name", ["bright_step000_a.dng", "frame.bin"])
def test_one_frame_says_a_measurement_needs_pairs(name, tmp_path, capsys):
    src = DATA / "dng_mono_crops" / "bright_step000_a.dng"
    path = tmp_path / name
    path.write_bytes(src.read_bytes())
    with pytest.raises(IngestError, match="pairs of bright frames") as e:
        ingest(path, out=tmp_path / "ptc.csv")
    assert "UTF-8" not in str(e.value)
    assert main(["ingest", str(path), "-o", str(tmp_path / "ptc.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pairs" in err and "UTF-8" not in err
    assert not (tmp_path / "ptc.csv").exists()
