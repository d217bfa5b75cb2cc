"""Tests of bayescap.io: frame readers, frame-set descriptions, statistics, CSV output.

Real data: EMVA 1288 Reference Set 001 (Basler AG, Dr. Marco Grimm 2011, CC BY-SA 3.0; see
tests/data/emva1288_basler/README.md).
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

import numpy as np
import pytest
import rawpy
import tifffile
from PIL import Image
from scipy import stats

import bayescap.io as raw
from bayescap.cli import ingest as cli_ingest
from bayescap.exceptions import IngestError

DATA = Path(__file__).parent / "data" / "emva1288_basler"
N_CROP = 128 * 128


# ------------------------------------------------------------------------------------ helpers
def write_png(path: Path, pixels: np.ndarray) -> None:
    """16-bit greyscale PNG (8-bit for uint8 input)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.ascontiguousarray(pixels)).save(path, compress_level=1)


def write_dng(
    path: Path,
    pixels: np.ndarray,
    *,
    pattern: str | None,
    black=0,
    white=4095,
    exposure=(1, 125),
    make="ACME",
    model="Test Cam",
) -> None:
    """A DNG that LibRaw reads: CFA (photometric 32803) or monochrome LinearRaw (34892)."""
    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50717, "H", 1, white, True),  # WhiteLevel
        (33434, "2I", 1, exposure, True),  # ExposureTime
        (271, "s", 0, make, True),
        (272, "s", 0, model, True),
    ]
    if pattern is None:
        tags.append((50714, "H", 1, int(black), True))  # BlackLevel
        tifffile.imwrite(path, pixels, photometric="minisblack", extratags=tags)
        with tifffile.TiffFile(path, mode="r+b") as tif:  # minisblack -> LinearRaw
            tif.pages[0].tags[262].overwrite(34892)
    else:
        code = {"R": 0, "G": 1, "B": 2}
        tags += [
            (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
            (33422, "B", 4, tuple(code[c] for c in pattern), True),  # CFAPattern
            (50713, "H", 2, (2, 2), True),  # BlackLevelRepeatDim
            (50714, "H", 4, tuple(int(b) for b in np.ravel(black)), True),
        ]
        tifffile.imwrite(path, pixels, photometric=32803, extratags=tags)


def read_ptc_csv(path: Path) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    """Metadata lines and columns (float arrays, NaN for empty cells) of a contract CSV."""
    meta, body = {}, []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            key, value = line[1:].split(":", 1)
            meta[key.strip()] = value.strip()
        else:
            body.append(line)
    rows = list(csv.DictReader(io.StringIO("\n".join(body))))
    cols = {k: np.array([float(r[k]) if r[k] != "" else np.nan for r in rows]) for k in rows[0]}
    return meta, cols


def write_manifest(
    path: Path,
    rows: list[tuple],
    *,
    metadata: dict | None = None,
    header=("file", "kind", "exposure_time_s", "photons_per_pixel"),
) -> Path:
    lines = [f"# {k}: {v}" for k, v in (metadata or {}).items()]
    lines.append(",".join(header))
    lines += [",".join("" if v is None else str(v) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def pair_numpy(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """EMVA 1288 pair statistics written out literally, as the contract states them."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    mean = (a.mean() + b.mean()) / 2
    var = (np.mean((a - b) ** 2) - (a.mean() - b.mean()) ** 2) / 2
    return mean, var


def nothing_written(directory: Path, out: Path) -> bool:
    return not out.exists() and not any(p.name.startswith(f".{out.name}") for p in directory.iterdir())


@pytest.fixture(scope="module")
def crops():
    with np.load(DATA / "frames_center_crops.npz") as npz:
        return {k: npz[k] for k in npz.files}


@pytest.fixture(scope="module")
def png_pairs(crops, tmp_path_factory) -> Path:
    """All 50 bright pairs and dark pairs of the crops as PNG files plus a manifest."""
    root = tmp_path_factory.mktemp("png_pairs")
    rows = []
    for step in range(50):
        texp_s = crops["bright_texp_ns"][step] / 1e9
        photons = crops["bright_photons_per_pixel"][step]
        for f in range(2):
            name = f"img/b_{step:03d}_{f}.png"
            write_png(root / name, crops["bright_pairs"][step, f])
            rows.append((name, "bright", repr(float(texp_s)), repr(float(photons))))
        for f in range(2):
            name = f"img/d_{step:03d}_{f}.png"
            write_png(root / name, crops["dark_pairs"][step, f])
            rows.append((name, "dark", repr(float(crops["dark_texp_ns"][step] / 1e9)), ""))
    write_manifest(
        root / "manifest.csv", rows, metadata={"adc_bits": 12, "sensor": "Basler CCD (EMVA 1288 RefSet 001)"}
    )
    return root


@pytest.fixture(scope="module")
def png_csv(png_pairs, tmp_path_factory):
    out = tmp_path_factory.mktemp("png_out") / "ptc.csv"
    paths = raw.ingest(png_pairs / "manifest.csv", out=out, roi="0,0,128,128")
    assert paths == [out]
    return out


@pytest.fixture(scope="module")
def png_result(png_csv):
    return read_ptc_csv(png_csv)


# --------------------------------------------------------------------------- CFA and DNG I/O
#: Positions (row, column) in the 2x2 tile, written out by hand for each Bayer pattern.
EXPECTED_POSITIONS = {
    "RGGB": {"R": (0, 0), "Gr": (0, 1), "Gb": (1, 0), "B": (1, 1)},
    "GRBG": {"R": (0, 1), "Gr": (0, 0), "Gb": (1, 1), "B": (1, 0)},
    "GBRG": {"R": (1, 0), "Gr": (1, 1), "Gb": (0, 0), "B": (0, 1)},
    "BGGR": {"R": (1, 1), "Gr": (1, 0), "Gb": (0, 1), "B": (0, 0)},
}


def coded_mosaic(pattern: str, shape=(64, 96)) -> np.ndarray:
    """A mosaic whose values say which channel each pixel belongs to (R 1xxx, Gr 2xxx, ...)."""
    rng = np.random.default_rng(7)
    mosaic = np.zeros(shape, dtype=np.uint16)
    for k, (_name, (i, j)) in enumerate(EXPECTED_POSITIONS[pattern].items()):
        plane = mosaic[i::2, j::2]
        plane[...] = 1000 * (k + 1) + rng.integers(0, 1000, plane.shape)
    return mosaic


@pytest.mark.parametrize("pattern", ["RGGB", "GRBG", "GBRG", "BGGR"])
def test_split_cfa_selects_the_pattern_positions(pattern):
    mosaic = coded_mosaic(pattern)
    planes = raw.split_cfa(mosaic, pattern)
    for k, name in enumerate(["R", "Gr", "Gb", "B"]):
        assert np.all(planes[name] // 1000 == k + 1), name
        assert planes[name].shape == (32, 48)
    # Gr shares its row with red pixels, Gb with blue pixels
    pos = raw.cfa_positions(pattern)
    assert pos["Gr"][0] == pos["R"][0] and pos["Gb"][0] == pos["B"][0]


@pytest.mark.parametrize("pattern", ["RGGB", "GRBG", "BGGR"])
def test_bayer_dng_roundtrip_is_bit_exact(tmp_path, pattern):
    mosaic = coded_mosaic(pattern)
    black = np.array([[60, 61], [62, 63]])
    path = tmp_path / f"{pattern}.dng"
    write_dng(path, mosaic, pattern=pattern, black=black, white=4095, exposure=(1, 250))
    with rawpy.imread(str(path)) as r:  # LibRaw itself gives the written array back
        assert np.array_equal(r.raw_image_visible, mosaic)
    frame = raw.read_frame(path)
    assert frame.pixels.dtype == np.uint16 and np.array_equal(frame.pixels, mosaic)
    assert frame.cfa_pattern == pattern
    np.testing.assert_array_equal(frame.black_level_dn, black)  # per CFA position
    assert frame.white_level_dn == 4095 and frame.adc_bits == 12
    assert frame.exposure_time_s == 0.004
    assert (frame.make, frame.model) == ("ACME", "Test Cam")
    planes = raw.split_cfa(frame.pixels, frame.cfa_pattern)
    for name, (i, j) in EXPECTED_POSITIONS[pattern].items():
        assert np.array_equal(planes[name], mosaic[i::2, j::2]), name


def test_mono_linear_raw_dng_roundtrip_is_bit_exact(tmp_path):
    rng = np.random.default_rng(3)
    pixels = rng.integers(0, 4096, (48, 80), dtype=np.uint16)
    path = tmp_path / "mono.dng"
    write_dng(path, pixels, pattern=None, black=17, exposure=(3, 1000))
    frame = raw.read_frame(path)
    assert np.array_equal(frame.pixels, pixels)
    assert frame.cfa_pattern is None
    assert frame.black_level_dn == 17 and frame.white_level_dn == 4095
    assert frame.exposure_time_s == 0.003


def test_shared_dng_crops_read_back_as_the_npz_crops(crops):
    frame = raw.read_frame(DATA / "dng_mono_crops" / "bright_step020_b.dng")
    assert np.array_equal(frame.pixels, crops["bright_pairs"][20, 1])
    assert frame.exposure_time_s == crops["bright_texp_ns"][20] / 1e9
    assert frame.make == "Basler"


def test_bayer_dng_set_gives_one_csv_per_channel(tmp_path):
    """Channel means and variances from a BGGR set agree with numpy on the known positions."""
    rng = np.random.default_rng(11)
    pattern, shape = "BGGR", (64, 80)
    black = np.array([[64, 65], [66, 67]])
    level = {"R": 900.0, "Gr": 1500.0, "Gb": 1520.0, "B": 700.0}
    frames = {}
    for kind in ("bright", "dark"):
        for f in range(2):
            mosaic = np.zeros(shape)
            for name, (i, j) in EXPECTED_POSITIONS[pattern].items():
                signal = level[name] if kind == "bright" else 0.0
                plane = mosaic[i::2, j::2]
                plane[...] = black[i, j] + rng.poisson(signal + 20, plane.shape)
            frames[kind, f] = mosaic.astype(np.uint16)
            write_dng(tmp_path / f"{kind}_{f}.dng", frames[kind, f], pattern=pattern, black=black, exposure=(1, 100))
    manifest = write_manifest(
        tmp_path / "manifest.csv", [(f"{k}_{f}.dng", k, "", "") for k in ("bright", "dark") for f in range(2)]
    )
    out = tmp_path / "out" / "ptc.csv"
    paths = raw.ingest(manifest, out=out, channel="all")  # default ROI: centred 50 %
    assert [p.name for p in paths] == ["ptc_R.csv", "ptc_Gr.csv", "ptc_Gb.csv", "ptc_B.csv"]
    roi = (slice(16, 48), slice(20, 60))  # centred half of 64x80, even corners
    for name, path in zip(["R", "Gr", "Gb", "B"], paths):
        i, j = EXPECTED_POSITIONS[pattern][name]
        meta, cols = read_ptc_csv(path)
        sel = [frames[k, f][roi][i::2, j::2] for k in ("bright", "dark") for f in range(2)]
        mean, var = pair_numpy(sel[0], sel[1])
        dmean, dvar = pair_numpy(sel[2], sel[3])
        np.testing.assert_allclose(cols["mean_dn"], [mean], rtol=1e-12)
        np.testing.assert_allclose(cols["temporal_var_dn2"], [var], rtol=1e-10)
        np.testing.assert_allclose(cols["dark_mean_dn"], [dmean], rtol=1e-12)
        np.testing.assert_allclose(cols["dark_temporal_var_dn2"], [dvar], rtol=1e-10)
        assert cols["n_pixels"][0] == 16 * 20
        assert cols["exposure_time_s"][0] == 0.01  # from the files' ExposureTime
        assert meta["channel"] == name and meta["cfa_pattern"] == pattern
        assert float(meta["black_level_dn"]) == black[i, j]
        assert meta["sensor"] == "ACME Test Cam"
        assert (meta["width_px"], meta["height_px"], meta["adc_bits"]) == ("80", "64", "12")
    # G pools the Gr and Gb pixels
    out_g = tmp_path / "out" / "ptc_G.csv"
    raw.ingest(manifest, out=out_g, channel="G")
    _, cols = read_ptc_csv(out_g)
    (gi, gj), (bi, bj) = EXPECTED_POSITIONS[pattern]["Gr"], EXPECTED_POSITIONS[pattern]["Gb"]
    pooled = [
        np.concatenate([frames["bright", f][roi][gi::2, gj::2].ravel(), frames["bright", f][roi][bi::2, bj::2].ravel()])
        for f in range(2)
    ]
    mean, var = pair_numpy(*pooled)
    np.testing.assert_allclose(cols["mean_dn"], [mean], rtol=1e-12)
    np.testing.assert_allclose(cols["temporal_var_dn2"], [var], rtol=1e-10)
    assert cols["n_pixels"][0] == 2 * 16 * 20


# ------------------------------------------------------------------------------ ROI parsing
def test_parse_roi():
    assert raw.parse_roi(None, (128, 128)) == (32, 32, 96, 96)
    assert raw.parse_roi("0.25", (480, 640)) == (240, 180, 400, 300)
    assert raw.parse_roi("10,20,50,60", (480, 640)) == (10, 20, 50, 60)
    assert raw.parse_roi([5, 7, 41, 40], (64, 64), cfa=True) == (4, 6, 40, 40)
    with pytest.raises(IngestError, match="inside"):
        raw.parse_roi("0,0,700,10", (480, 640))
    with pytest.raises(IngestError, match="fraction"):
        raw.parse_roi("1.5", (480, 640))


# ------------------------------------------------------------ real data: PNG + manifest set
def test_png_set_matches_numpy_on_the_crops(png_result, crops):
    meta, cols = png_result
    assert len(cols["mean_dn"]) == 50
    np.testing.assert_allclose(cols["exposure_time_s"], crops["bright_texp_ns"] / 1e9, rtol=1e-15)
    np.testing.assert_array_equal(cols["photons_per_pixel"], crops["bright_photons_per_pixel"])
    for step in range(50):
        mean, var = pair_numpy(*crops["bright_pairs"][step])
        dmean, dvar = pair_numpy(*crops["dark_pairs"][step])
        np.testing.assert_allclose(cols["mean_dn"][step], mean, rtol=1e-13)
        np.testing.assert_allclose(cols["temporal_var_dn2"][step], var, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(cols["dark_mean_dn"][step], dmean, rtol=1e-13)
        np.testing.assert_allclose(cols["dark_temporal_var_dn2"][step], dvar, rtol=1e-9)
        assert cols["frac_saturated"][step] == np.mean(crops["bright_pairs"][step] >= 4095)
    assert np.all(cols["n_pixels"] == N_CROP)
    assert "spatial_var_dn2" not in cols  # pairs only: no stack, no spatial variance
    assert meta["adc_bits"] == "12" and meta["white_level_dn"] == "4095"
    assert meta["channel"] == "mono" and meta["black_level_dn"] == "0"
    assert (meta["width_px"], meta["height_px"]) == ("128", "128")
    assert meta["sensor"] == "Basler CCD (EMVA 1288 RefSet 001)"


def full_frame_table() -> dict[str, np.ndarray]:
    with open(DATA / "ptc_pairs_fullframe.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_crop_variances_agree_with_the_full_frame_table(png_result):
    """Temporal variances of the 128x128 crops vs the same frames' full 640x480 values.

    A variance from N pixels has a relative sd of sqrt(2/(N-1)) (0.0110 for the crop; the
    full-frame value's own error is 4.6x smaller and neglected). Levels where any full-frame
    pixel saturates are left out (clipping makes the variance depend on the region).
    The per-level bound is Bonferroni at 1 % family-wise over all comparisons, and the sum of
    squared z must be compatible with chi-square.
    """
    _, cols = png_result
    full = full_frame_table()
    rel_sd = np.sqrt(2 / (N_CROP - 1))
    unsat = full["frac_saturated"] == 0
    z_bright = (cols["temporal_var_dn2"][unsat] / full["var_temporal_DN2"][unsat] - 1) / rel_sd
    z_dark = (cols["dark_temporal_var_dn2"] / full["dark_var_temporal_DN2"] - 1) / rel_sd
    z = np.concatenate([z_bright, z_dark])
    assert unsat.sum() == 37 and z.size == 87
    limit = stats.norm.isf(0.01 / (2 * z.size))
    assert np.max(np.abs(z)) < limit, (np.max(np.abs(z)), limit)
    assert stats.chi2.sf(np.sum(z**2), z.size) > 1e-3


def test_crop_means_agree_with_the_full_frame_table(png_result, crops):
    """Means of the crop vs the full frames.

    The light is not perfectly uniform: the centre crop receives a fixed fraction r of the
    frame-average signal. So (mean − dark mean) of the crop / (the same of the full frame) must
    be one constant r at every unsaturated level, within the crop's statistical error of the
    mean, and r must lie within EMVA 1288's ±3 % limit for the irradiation non-uniformity.
    The error of a crop mean is estimated from the row means of the pair difference (rows
    taken as independent: this CCD has row-correlated temporal noise).
    """
    _, cols = png_result
    full = full_frame_table()
    unsat = np.flatnonzero(full["frac_saturated"] == 0)

    def mean_error(pair):
        diff = pair[0].astype(float) - pair[1].astype(float)
        # sd of the pair-average mean = sd of (A−B)/2 averaged over rows
        return np.sqrt(np.var(diff.mean(axis=1), ddof=1) / diff.shape[0]) / 2

    signal_crop = cols["mean_dn"][unsat] - cols["dark_mean_dn"][unsat]
    signal_full = full["mean_DN"][unsat] - full["dark_mean_DN"][unsat]
    ratio = signal_crop / signal_full
    err = (
        np.array([np.hypot(mean_error(crops["bright_pairs"][s]), mean_error(crops["dark_pairs"][s])) for s in unsat])
        / signal_full
    )
    r = np.average(ratio, weights=err**-2)
    z = (ratio - r) / err
    assert abs(r - 1) < 0.03
    assert np.max(np.abs(z)) < stats.norm.isf(0.01 / (2 * z.size))
    assert stats.chi2.sf(np.sum(z**2), z.size - 1) > 1e-3
    # the dark means differ by a constant fixed-pattern offset, within the same errors
    dark_err = np.array([mean_error(crops["dark_pairs"][s]) for s in range(50)])
    delta = cols["dark_mean_dn"] - full["dark_mean_DN"]
    offset = np.average(delta, weights=dark_err**-2)
    zd = (delta - offset) / dark_err
    assert np.max(np.abs(zd)) < stats.norm.isf(0.01 / (2 * zd.size))
    # full-frame saturation is reached where the crop saturates too
    sat = full["frac_saturated"] == 1
    assert np.all(cols["frac_saturated"][sat] > 0.99)


def test_spatial_stacks_give_spatial_variance(crops, tmp_path):
    """50-frame stacks plus one pair level: spatial columns on every row, n_frames = L."""
    texp = crops["spatial_bright_texp_ns"] / 1e9
    photons = crops["spatial_bright_photons_per_pixel"]
    rows = []
    for kind, stack in (("bright", crops["spatial_bright_stack"]), ("dark", crops["spatial_dark_stack"])):
        for f, image in enumerate(stack):
            write_png(tmp_path / f"{kind}_{f:02d}.png", image)
            rows.append(
                (f"{kind}_{f:02d}.png", kind, repr(float(texp)), repr(float(photons)) if kind == "bright" else "")
            )
    centre = (slice(32, 96), slice(32, 96))  # a pair level cut to the stacks' 64x64
    pair_texp = repr(float(crops["bright_texp_ns"][10] / 1e9))
    for kind, key in (("bright", "bright_pairs"), ("dark", "dark_pairs")):
        for f in range(2):
            write_png(tmp_path / f"pair_{kind}_{f}.png", crops[key][10, f][centre])
            rows.append(
                (
                    f"pair_{kind}_{f}.png",
                    kind,
                    pair_texp,
                    repr(float(crops["bright_photons_per_pixel"][10])) if kind == "bright" else "",
                )
            )
    write_manifest(tmp_path / "manifest.csv", rows, metadata={"adc_bits": 12})
    out = tmp_path / "stack.csv"
    raw.ingest(tmp_path, out=out, roi=1.0)  # a directory with manifest.csv inside
    meta, cols = read_ptc_csv(out)
    assert meta["roi_px"] == "x0=0 y0=0 x1=64 y1=64"
    # row 1: the stacks (5.16 ms)
    assert cols["n_frames"][1] == 50 and cols["dark_n_frames"][1] == 50
    for kind, col in (("bright", "spatial_var_dn2"), ("dark", "dark_spatial_var_dn2")):
        stack = crops[f"spatial_{kind}_stack"].astype(np.float64)
        expected = np.var(stack.mean(axis=0), ddof=1)
        np.testing.assert_allclose(cols[col][1], expected, rtol=1e-10)
    mean, var = pair_numpy(*crops["spatial_bright_stack"][:2])
    np.testing.assert_allclose(cols["mean_dn"][1], mean, rtol=1e-13)
    np.testing.assert_allclose(cols["temporal_var_dn2"][1], var, rtol=1e-10)
    # PRNU sanity: the stack average still holds temporal_var/50; what is left is positive
    assert cols["spatial_var_dn2"][1] > cols["temporal_var_dn2"][1] / 50
    # row 0: the pair (2.9 ms) carries the spatial variance of its two-frame average
    assert cols["n_frames"][0] == 2 and cols["dark_n_frames"][0] == 2
    pair = crops["bright_pairs"][10][:, centre[0], centre[1]].astype(np.float64)
    np.testing.assert_allclose(cols["spatial_var_dn2"][0], np.var(pair.mean(axis=0), ddof=1), rtol=1e-10)
    # the project's own contract reader takes the table as it is
    from bayescap.io.ptc_csv import read_ptc_csv as contract_reader

    data = contract_reader(out)
    assert data.n_levels == 2 and data.metadata["adc_bits"] == 12


def test_dng_crops_through_a_manifest(crops, tmp_path):
    """The shared mono DNG crops (exposure time from the files) plus PNG darks."""
    dng = DATA / "dng_mono_crops"
    rows = []
    for step in (0, 5, 10, 20, 30, 36):
        photons = crops["bright_photons_per_pixel"][step]
        rows += [(str(dng / f"bright_step{step:03d}_{f}.dng"), "bright", "", repr(float(photons))) for f in "ab"]
        if step == 0:
            rows += [(str(dng / f"dark_step000_{f}.dng"), "dark", "", "") for f in "ab"]
        else:
            for f in range(2):
                write_png(tmp_path / f"d_{step}_{f}.png", crops["dark_pairs"][step, f])
                rows.append((f"d_{step}_{f}.png", "dark", repr(float(crops["dark_texp_ns"][step] / 1e9)), ""))
    manifest = write_manifest(tmp_path / "dng.csv", rows)
    out = tmp_path / "dng_ptc.csv"
    raw.ingest(manifest, out=out, roi="0,0,128,128", channel="all")  # mono: channel ignored
    meta, cols = read_ptc_csv(out)
    assert meta["sensor"] == "Basler EMVA1288-RefSet001-CCD12" and meta["adc_bits"] == "12"
    assert meta["channel"] == "mono"
    for k, step in enumerate((0, 5, 10, 20, 30, 36)):
        assert cols["exposure_time_s"][k] == crops["bright_texp_ns"][step] / 1e9
        mean, var = pair_numpy(*crops["bright_pairs"][step])
        dmean, dvar = pair_numpy(*crops["dark_pairs"][step])
        np.testing.assert_allclose(cols["mean_dn"][k], mean, rtol=1e-13)
        np.testing.assert_allclose(cols["temporal_var_dn2"][k], var, rtol=1e-10)
        np.testing.assert_allclose(cols["dark_mean_dn"][k], dmean, rtol=1e-13)
        np.testing.assert_allclose(cols["dark_temporal_var_dn2"][k], dvar, rtol=1e-10)


# ------------------------------------------------------------------------- EMVA descriptors
def test_emva_descriptor_with_png_frames(crops, tmp_path):
    steps = (3, 17, 33)
    lines = ["# test descriptor in the EMVA 1288 reference-set layout", "v 3.0", "n 12 128 128"]
    for step in steps:
        lines.append(f"b {crops['bright_texp_ns'][step]:.1f} {crops['bright_photons_per_pixel'][step]:.1f}")
        for f in range(2):
            write_png(tmp_path / "images" / f"b_{step:03d}_snap_{f}.png", crops["bright_pairs"][step, f])
            lines.append(f"i images\\b_{step:03d}_snap_{f}.png")
    for step in steps:
        lines.append(f"d {crops['dark_texp_ns'][step]:.1f}")
        for f in range(2):
            write_png(tmp_path / "images" / f"d_{step:03d}_snap_{f}.png", crops["dark_pairs"][step, f])
            lines.append(f"i images\\d_{step:03d}_snap_{f}.png")
    (tmp_path / "EMVA1288_Data.txt").write_bytes("\r\n".join(lines).encode() + b"\r\n")
    out = tmp_path / "out.csv"
    raw.ingest(tmp_path, out=out, roi="0,0,128,128")  # directory -> the *.txt descriptor
    meta, cols = read_ptc_csv(out)
    assert meta["adc_bits"] == "12" and meta["emva1288_descriptor_version"] == "3.0"
    np.testing.assert_allclose(cols["photons_per_pixel"], crops["bright_photons_per_pixel"][list(steps)])
    for k, step in enumerate(steps):
        mean, var = pair_numpy(*crops["bright_pairs"][step])
        np.testing.assert_allclose(cols["mean_dn"][k], mean, rtol=1e-13)
        np.testing.assert_allclose(cols["temporal_var_dn2"][k], var, rtol=1e-10)
        assert cols["exposure_time_s"][k] == crops["bright_texp_ns"][step] / 1e9


def test_real_descriptor_is_understood():
    frameset = raw.read_emva_descriptor(DATA / "EMVA1288_Data.txt")
    assert frameset.frame_shape_hw == (480, 640) and frameset.metadata["adc_bits"] == "12"
    assert len(frameset.entries) == 300
    assert frameset.entries[0].path == DATA / "images" / "b_000_snap_001.png"
    assert frameset.entries[0].exposure_time_s == 4e-5
    assert frameset.entries[0].photons_per_pixel == 120.0
    levels = raw.group_levels(frameset)
    assert len(levels) == 51
    stack = [lv for lv in levels if len(lv.bright) > 2]
    assert len(stack) == 1 and len(stack[0].bright) == 50 and len(stack[0].dark) == 50
    assert stack[0].exposure_time_s == 0.00516 and stack[0].photons_per_pixel == 15508.0
    assert all(len(lv.dark) == 2 for lv in levels if lv is not stack[0])


# ------------------------------------------------------------------------------------ errors
def small_png_set(root: Path, crops, *, steps=(0, 1)) -> list[tuple]:
    rows = []
    for step in steps:
        for kind, key in (("bright", "bright_pairs"), ("dark", "dark_pairs")):
            for f in range(2):
                name = f"{kind[0]}_{step}_{f}.png"
                write_png(root / name, crops[key][step, f])
                rows.append([name, kind, repr(float(crops["bright_texp_ns"][step] / 1e9)), ""])
    return rows


def case_mismatched_size(root, crops, rows):
    write_png(root / "b_1_1.png", crops["bright_pairs"][1, 1][:64, :])
    return rows, "b_1_1.png"


def case_missing_partner(root, crops, rows):
    return [r for r in rows if r[0] != "b_1_1.png"], "b_1_0.png"


def case_truncated(root, crops, rows):
    data = (root / "d_0_1.png").read_bytes()
    (root / "d_0_1.png").write_bytes(data[: len(data) // 2])
    return rows, "d_0_1.png"


def case_text_exposure(root, crops, rows):
    rows[5][2] = "fast"
    return rows, "manifest.csv, row 7, column 'exposure_time_s'"


def case_missing_dark(root, crops, rows):
    return [r for r in rows if not r[0].startswith("d_1_")], "b_1_0.png"


def case_photons_on_some_levels(root, crops, rows):
    for row in rows:
        if row[0].startswith("b_0_"):
            row[3] = "120.0"
    return rows, "row 6, column 'photons_per_pixel': photons_per_pixel is empty for bright frame b_1_0.png"


@pytest.mark.parametrize(
    "case",
    [
        case_mismatched_size,
        case_missing_partner,
        case_truncated,
        case_text_exposure,
        case_missing_dark,
        case_photons_on_some_levels,
    ],
)
def test_bad_input_is_refused_naming_the_file(crops, tmp_path, case):
    rows = small_png_set(tmp_path, crops)
    rows, expected = case(tmp_path, crops, rows)
    manifest = write_manifest(tmp_path / "manifest.csv", rows)
    out = tmp_path / "ptc.csv"
    with pytest.raises(IngestError) as info:
        raw.ingest(manifest, out=out, roi=1.0)
    message = str(info.value)
    assert expected in message and "\n" not in message, message
    assert nothing_written(tmp_path, out)


def test_cli_exit_status_and_one_line_error(crops, tmp_path, capsys):
    rows = small_png_set(tmp_path, crops)
    rows[0][1] = "brite"
    write_manifest(tmp_path / "manifest.csv", rows)
    parser = cli_ingest.add_ingest_arguments(argparse.ArgumentParser(prog="bayescap ingest"))
    out = tmp_path / "ptc.csv"
    args = parser.parse_args([str(tmp_path / "manifest.csv"), "-o", str(out)])
    assert cli_ingest.run_ingest(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "row 2, column 'kind'" in err
    assert nothing_written(tmp_path, out)
    rows[0][1] = "bright"
    write_manifest(tmp_path / "manifest.csv", rows)
    assert cli_ingest.run_ingest(args) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert out.exists()


def test_output_never_overwrites_an_input(crops, tmp_path):
    rows = small_png_set(tmp_path, crops)
    manifest = write_manifest(tmp_path / "manifest.csv", rows)
    before = manifest.read_bytes()
    with pytest.raises(IngestError, match="overwrite an input"):
        raw.ingest(manifest, out=manifest)
    assert manifest.read_bytes() == before


def test_tiff_npy_and_8bit_png_readers(tmp_path):
    rng = np.random.default_rng(5)
    pixels = rng.integers(0, 65536, (40, 50), dtype=np.uint16)
    tifffile.imwrite(tmp_path / "f.tif", pixels, extratags=[(33434, "2I", 1, (1, 50), True)])
    np.save(tmp_path / "f.npy", pixels)
    small = rng.integers(0, 256, (40, 50), dtype=np.uint8)
    write_png(tmp_path / "f8.png", small)
    tif = raw.read_frame(tmp_path / "f.tif")
    assert np.array_equal(tif.pixels, pixels) and tif.exposure_time_s == 0.02
    assert tif.white_level_dn == 65535 and tif.cfa_pattern is None
    assert np.array_equal(raw.read_frame(tmp_path / "f.npy").pixels, pixels)
    png8 = raw.read_frame(tmp_path / "f8.png")
    assert np.array_equal(png8.pixels, small) and png8.white_level_dn == 255


def test_truncated_dng_and_tiff_are_refused(tmp_path):
    data = (DATA / "dng_mono_crops" / "bright_step005_a.dng").read_bytes()
    (tmp_path / "half.dng").write_bytes(data[: len(data) // 2])
    with pytest.raises(IngestError, match="half.dng"):
        raw.read_frame(tmp_path / "half.dng")
    tifffile.imwrite(tmp_path / "full.tif", np.ones((64, 64), dtype=np.uint16))
    data = (tmp_path / "full.tif").read_bytes()
    (tmp_path / "half.tif").write_bytes(data[: len(data) // 2])
    with pytest.raises(IngestError, match="half.tif.*truncated"):
        raw.read_frame(tmp_path / "half.tif")


def test_ingested_crops_fit_to_the_full_frame_gain(png_csv, basler_standard_fit):
    """Frames -> CSV -> fit gives the conversion gain of the full-frame table's fit.

    The crop's statistical error: each pair variance over 128x128 pixels has a relative sd of
    sqrt(2/16383) = 1.1 %, against 0.26 % for the full 640x480 frame; the posterior sd of K from
    each fit (which also carries the fitted systematic scatter) is that error propagated through
    the ~37 unsaturated rows. The two K must agree within 3 combined sd (99.7 %).
    """
    import bayescap

    crop = bayescap.fit(png_csv, seed=2)
    full = basler_standard_fit  # the full table's standard fit (seed 1), shared with other tests
    kc, kf = crop.draws["conversion_gain_e_per_dn"], full.draws["conversion_gain_e_per_dn"]
    sd = np.hypot(kc.std(), kf.std())
    diff = np.median(kc) - np.median(kf)
    assert crop.diag["converged"] and full.diag["converged"]
    assert abs(diff) < 3 * sd, (
        f"K crop {np.median(kc):.4f} ± {kc.std():.4f}, full {np.median(kf):.4f} ± "
        f"{kf.std():.4f} e-/DN: difference {diff:.4f} vs 3 sd {3 * sd:.4f}"
    )
    # the crop's error is the larger one, as its pixel count says
    assert kc.std() > kf.std()


def test_broken_tiff_frame_is_one_line_of_error(tmp_path):
    """tifffile logs what it finds wrong in a file ("invalid offset to first page") to standard error
    before raising; that line must not come out above bayescap's own: only the IngestError, naming the file."""
    import subprocess
    import sys

    rng = np.random.default_rng(0)
    rows = ["file,kind,exposure_time_s"]
    for i, t in enumerate((0.001, 0.002, 0.004)):
        for kind, level in (("bright", 200.0 * (i + 1)), ("dark", 10.0)):
            for ab in "ab":
                name = f"{kind}_{i}_{ab}.npy"
                np.save(tmp_path / name, rng.poisson(level, (32, 32)).astype(np.uint16))
                rows.append(f"{name},{kind},{t}")
    (tmp_path / "broken.tif").write_bytes(b"II*\x00garbage")
    rows[1] = "broken.tif," + rows[1].split(",", 1)[1]
    (tmp_path / "manifest.csv").write_text("# adc_bits: 12\n" + "\n".join(rows) + "\n")
    out = tmp_path / "ptc.csv"
    r = subprocess.run(
        [sys.executable, "-m", "bayescap.cli", "ingest", str(tmp_path / "manifest.csv"), "-o", str(out)],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and not out.exists()
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bayescap ingest: error:") and "broken.tif" in lines[0], r.stderr


def test_raw_file_without_rawpy_is_one_line_naming_the_extra(tmp_path, monkeypatch):
    """rawpy is the optional 'raw' extra: without it a RAW file is refused in one line that says
    what to install, not an ImportError traceback."""
    import sys

    monkeypatch.setitem(sys.modules, "rawpy", None)  # import rawpy now raises ImportError
    f = tmp_path / "a.dng"
    f.write_bytes(b"not read")
    with pytest.raises(
        IngestError, match=r"a\.dng: reading a RAW or DNG file needs rawpy: pip install 'bayescap\[raw\]'"
    ):
        raw.read_frame(f)
