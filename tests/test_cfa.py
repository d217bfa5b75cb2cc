"""The four CFA channels as one sensor: RAW/DNG ingest in one pass, the colour matrix and white
balance from the RAW metadata, the joint fit and its K check, and `bayescap colour`.

The frames are written here, pixel by pixel (Poisson electrons, Gaussian read noise, a well, a
black level, rounding), by tifffile as DNGs that LibRaw reads (../shared/NOTES.md, "Writing test
RAW files"): independent of the model that is fitted to them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tifffile
from conftest import python_stdout

from bayescap.cli import main
from bayescap.colour.raw_metadata import ccm_from_cam_xyz, parse_ccm, read_raw_colour
from bayescap.exceptions import IngestError, InputError
from bayescap.io.cfa import ingest_cfa, read_cfa_tables

#: the Nikon D850's ColorMatrix1 (Adobe DNG Converter), XYZ -> camera
CM1_D850 = np.array([10405, -3755, -1270, -5461, 13787, 1793, -1040, 2015, 6785]).reshape(3, 3) / 1e4
#: what LibRaw 0.22 returns as color_matrix (camera -> sRGB) for a DNG with that ColorMatrix1 and
#: CalibrationIlluminant1 = 21 (D65): the golden rows
GOLDEN_CCM = np.array([[1.4009, -0.3130, -0.0879], [-0.1249, 1.4125, -0.2876], [0.0080, -0.4077, 1.3997]])
AS_SHOT_NEUTRAL = (0.45, 1.0, 0.80)
#: LibRaw's daylight balance for that matrix, R/G and B/G
GOLDEN_DAYLIGHT = (2.2199, 1.2537)
TRUTH = dict(k=2.0, read=3.0, well=6000.0, qe=(0.35, 0.55, 0.55, 0.30), black=64)
POS = {"R": (0, 0), "Gr": (0, 1), "Gb": (1, 0), "B": (1, 1)}


def write_dng(path: Path, pixels, *, pattern="RGGB", black=64, cm=CM1_D850, neutral=AS_SHOT_NEUTRAL, exposure=(1, 100)):
    def rationals(values, signed=False):
        return tuple(v for x in np.ravel(values) for v in (int(round(x * 10000)), 10000))

    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50717, "H", 1, 4095, True),  # WhiteLevel
        (33434, "2I", 1, exposure, True),  # ExposureTime
        (271, "s", 0, "ACME", True),
        (272, "s", 0, "Colour Cam", True),
        (50721, "2i", 9, rationals(cm), True),  # ColorMatrix1 (SRATIONAL)
        (50778, "H", 1, 21, True),  # CalibrationIlluminant1 = D65
        (50728, "2I", 3, rationals(neutral), True),  # AsShotNeutral
    ]
    if pattern is None:
        tags.append((50714, "H", 1, int(black), True))
        tifffile.imwrite(path, pixels, photometric="minisblack", extratags=tags)
        with tifffile.TiffFile(path, mode="r+b") as tif:  # minisblack -> LinearRaw
            tif.pages[0].tags[262].overwrite(34892)
        return
    code = {"R": 0, "G": 1, "B": 2}
    tags += [
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, tuple(code[c] for c in pattern), True),  # CFAPattern
        (50713, "H", 2, (2, 2), True),  # BlackLevelRepeatDim
        (50714, "H", 4, (int(black),) * 4, True),
    ]
    tifffile.imwrite(path, pixels, photometric=32803, extratags=tags)


def make_frame_set(root: Path, *, levels=8, shape=(48, 48), seed=0, mono=False) -> Path:
    """An RGGB flat/dark DNG set of a known sensor: 2 flats and 2 darks per exposure level."""
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    k, read, well, qe, black = (TRUTH[n] for n in ("k", "read", "well", "qe", "black"))
    photons = np.linspace(0.03, 1.25, levels) * well / max(qe)
    rows = ["file,kind,exposure_time_s"]
    for i, ph in enumerate(photons):
        for kind in ("bright", "dark"):
            for f in range(2):
                mosaic = np.zeros(shape)
                for j, (a, b) in enumerate(POS.values()):
                    plane = mosaic[a::2, b::2]
                    lam = (qe[j] if not mono else qe[1]) * ph if kind == "bright" else 0.0
                    e = np.minimum(rng.poisson(lam, plane.shape), well) + read * rng.standard_normal(plane.shape)
                    plane[...] = np.clip(np.floor(black + e / k + 0.5), 0, 4095)
                name = f"{kind}_{i:02d}_{f}.dng"
                write_dng(
                    root / name, mosaic.astype(np.uint16), pattern=None if mono else "RGGB", exposure=(i + 1, 1000)
                )
                rows.append(f"{name},{kind},{(i + 1) / 1000}")
    (root / "manifest.csv").write_text("\n".join(rows) + "\n")
    return root / "manifest.csv"


@pytest.fixture(scope="module")
def frame_set(tmp_path_factory) -> Path:
    return make_frame_set(tmp_path_factory.mktemp("cfa_set"))


# ------------------------------------------------------------------------------ RAW metadata
def test_dng_colour_matrix_and_white_balance_read_back_to_golden_rows(tmp_path):
    path = tmp_path / "one.dng"
    write_dng(path, np.full((32, 32), 500, np.uint16))
    rc = read_raw_colour(path)
    np.testing.assert_allclose(rc.ccm, GOLDEN_CCM, atol=1e-4)
    # independently: dcraw's recipe on the matrix written (rows normalised, inverted), to LibRaw's float32
    np.testing.assert_allclose(rc.ccm, ccm_from_cam_xyz(CM1_D850), atol=1e-4)
    np.testing.assert_allclose(rc.wb_gains, [1 / 0.45, 1.0, 1 / 0.80], atol=1e-4)  # as shot = 1 / AsShotNeutral
    np.testing.assert_allclose(rc.daylight_wb_gains[[0, 2]], GOLDEN_DAYLIGHT, atol=1e-4)
    assert "color_matrix" in rc.ccm_source and "as shot" in rc.wb_source


def test_user_ccm_inline_file_and_refusals(tmp_path):
    m, source, rc = parse_ccm("1.5,-0.4,-0.1, -0.2,1.4,-0.2, 0,-0.5,1.5")
    np.testing.assert_array_equal(m, [[1.5, -0.4, -0.1], [-0.2, 1.4, -0.2], [0, -0.5, 1.5]])
    assert rc is None and "inline" in source
    f = tmp_path / "ccm.txt"
    f.write_text("# camera -> sRGB\n1.5 -0.4 -0.1\n-0.2 1.4 -0.2\n0 -0.5 1.5\n")
    np.testing.assert_array_equal(parse_ccm(str(f))[0], m)
    with pytest.raises(InputError, match="singular"):
        parse_ccm("1,2,3, 2,4,6, 0,0,1")
    with pytest.raises(InputError, match="8 numbers"):
        parse_ccm("1,0,0,0,1,0,0,0")
    f.write_text("1 0 0\n0 1 x\n0 0 1\n")
    with pytest.raises(InputError, match="'x' is not a number"):
        parse_ccm(str(f))


# ------------------------------------------------------------------------------------ ingest
def test_four_channels_in_one_pass(frame_set):
    cfa = ingest_cfa(frame_set, roi=1.0)
    assert list(cfa.tables) == ["R", "Gr", "Gb", "B"] and cfa.cfa_pattern == "RGGB"
    assert cfa.first_frame.name == "bright_00_0.dng"
    n = [t.n_pixels[0] for t in cfa.tables.values()]
    assert n == [24 * 24] * 4
    # the channels' signals stand in the ratio of their QE: on rows below the well the mean signal's
    # relative sd is ≤ 1/sqrt(576·(signal in e-)) < 0.3 %; 1.5 % is 5 sd
    sig = {c: t.signal_dn for c, t in cfa.tables.items()}
    ok = sig["Gr"] < 0.8 * TRUTH["well"] / TRUTH["k"]
    ratio = sig["R"][ok].sum() / sig["Gr"][ok].sum()
    assert ratio == pytest.approx(0.35 / 0.55, rel=0.015)


def test_channel_csvs_of_different_sizes_are_refused(frame_set, tmp_path):
    from bayescap.io import ingest

    paths = ingest(frame_set, out=tmp_path / "ptc.csv", channel="all", roi=1.0)
    assert read_cfa_tables(paths).n_pixels == 576
    text = paths[3].read_text().replace(",576,", ",500,")
    paths[3].write_text(text)
    with pytest.raises(IngestError, match="channels of different sizes") as e:
        read_cfa_tables(paths)
    assert e.value.path == paths[3]


# --------------------------------------------------------------------------------------- fit
def _tables(seed, k_r=2.5):
    from bayescap.simulate import SensorTruth, exposure_series, simulate_ptc

    qe = {"R": 0.35, "Gr": 0.55, "Gb": 0.55, "B": 0.30}
    prnu = {"R": 0.008, "Gr": 0.006, "Gb": 0.0065, "B": 0.01}
    base = SensorTruth(conversion_gain_e_per_dn=2.5, read_noise_e=3.0, full_well_e=9000, quantum_efficiency=0.55)
    ph, t = exposure_series(base, 24, max_fraction=1.1)
    out = {}
    for i, c in enumerate(qe):
        k = k_r if c == "R" else 2.5
        tr = SensorTruth(
            conversion_gain_e_per_dn=k,
            read_noise_e=3.0,
            full_well_e=9000,
            quantum_efficiency=qe[c],
            prnu_frac=prnu[c],
        )
        out[c] = simulate_ptc(
            tr,
            photons_per_pixel=ph,
            exposure_time_s=t,
            shape=(50, 50),
            seed=seed * 10 + i,
            spatial_frames=2,
            spatial_every=3,
            include_photons=False,
            metadata={"channel": c},
        )
    return out


@pytest.fixture(scope="module")
def joint_fit():
    from bayescap.colour.cfa_fit import fit_cfa

    return fit_cfa(_tables(3), seed=5)


def test_joint_fit_holds_the_truth_and_narrows_k(joint_fit):
    f = joint_fit
    d = f.to_dict()
    assert f.converged and d["k_check"]["passed"]
    assert "conversion_gain_e_per_dn" in d["shared"] and "read_noise_e" in d["shared"]
    k = d["shared"]["conversion_gain_e_per_dn"]
    assert k["ci95"][0] < 2.5 < k["ci95"][1]
    width = k["ci95"][1] - k["ci95"][0]
    for c in f.channels:
        s = d["separate"][c]["conversion_gain_e_per_dn"]["ci95"]
        # four channels' worth of data: the joint interval is about half as wide (1/sqrt(4))
        assert width < 0.75 * (s[1] - s[0])
        p = d["joint"][c]["prnu_percent"]["ci95"]
        assert p[0] < 100 * {"R": 0.008, "Gr": 0.006, "Gb": 0.0065, "B": 0.01}[c] < p[1]
    coeffs = f.var_coeffs_dn2(0.01)
    assert coeffs.shape == (f.n_draws, 4, 3)
    np.testing.assert_allclose(np.median(coeffs[:, :, 1], axis=0), 1 / 2.5, rtol=0.01)


def test_joint_noise_coefficients_are_the_monochrome_ones(joint_fit):
    """The joint draws' σ²(S) in DN is Eq. 1 as the monochrome fit computes it
    (``NoiseCoefficients.from_parameters``: dark noise, DSNU and rounding in a; PRNU² in c), over K²."""
    from bayescap.physics.noise import NoiseCoefficients

    f = joint_fit
    t = 0.01
    got = f.var_coeffs_dn2(t)
    for j, c in enumerate(f.channels):
        d = f.draws[c]
        assert "dsnu_e" in d
        k = d["conversion_gain_e_per_dn"]
        nc = NoiseCoefficients.from_parameters(
            read_noise_e=d["read_noise_e"],
            dark_current_e_per_s=d.get("dark_current_e_per_s", 0.0),
            exposure_time_s=t,
            dsnu_e=d["dsnu_e"],
            prnu_frac=d["prnu_percent"] / 100.0,
            conversion_gain_e_per_dn=k,
        )
        np.testing.assert_allclose(got[:, j, 0], nc.a / k**2, rtol=1e-12)
        np.testing.assert_allclose(got[:, j, 1], nc.b / k, rtol=1e-12)
        np.testing.assert_allclose(got[:, j, 2], nc.c, rtol=1e-12)


def test_consensus_agrees_with_the_mode_of_the_exact_joint_density(joint_fit):
    """The four models' densities with K and read noise tied (JointCFAModel), maximised from the
    channels' medians: its shared coordinates land within half a consensus sd of the consensus."""
    from scipy.optimize import minimize

    from bayescap.colour.cfa_fit import JointCFAModel

    f = joint_fit
    models = [f.results[c].model for c in f.channels]
    jm = JointCFAModel(models)
    x0 = np.empty(jm.ndim)
    for i, c in enumerate(f.channels):
        x0[jm.columns(i)] = np.median(f.results[c].chains.chain.reshape(-1, models[i].ndim), axis=0)
    consensus = {
        "log_k": np.log(f.draws["R"]["conversion_gain_e_per_dn"]),
        "log_read": np.log(f.draws["R"]["read_noise_e"]),
    }
    for j, name in enumerate(jm.shared):
        if name in consensus:
            x0[j] = np.median(consensus[name])
    jm.ref_shared = x0[: len(jm.shared)].copy()
    h = np.eye(jm.ndim) * 1e-5

    def neg(z):
        return -float(jm.log_prob(x0 + 0.01 * z)[0])

    def grad(z):
        lp = jm.log_prob(x0 + 0.01 * np.concatenate([z + h, z - h]))
        return np.where(np.isfinite(lp[: jm.ndim] - lp[jm.ndim :]), -(lp[: jm.ndim] - lp[jm.ndim :]) / 2e-5, 0.0)

    res = minimize(neg, np.zeros(jm.ndim), jac=grad, method="BFGS", options={"maxiter": 300, "gtol": 1e-3})
    x_map = x0 + 0.01 * res.x
    for name, draws in consensus.items():
        z = (x_map[jm.shared.index(name)] - np.median(draws)) / np.std(draws)
        assert abs(z) < 0.5, (name, z)


def test_channel_fits_do_not_depend_on_the_process_count(joint_fit):
    """The four channel fits in worker processes give bit for bit what one process gives (the
    default at fast), and each channel's is ``bayescap.fit``'s with the channel's child seed and the
    channel fits' fast settings (the gate on the reported parameters)."""
    import bayescap
    from bayescap.batch import sensor_seeds
    from bayescap.colour.cfa_fit import channel_fast_settings, fit_cfa

    one = fit_cfa(_tables(3), seed=5, n_jobs=1)
    two = fit_cfa(_tables(3), seed=5, n_jobs=2)
    for c in one.channels:
        np.testing.assert_array_equal(one.results[c].chains.chain, two.results[c].chains.chain)
        for name, v in one.draws[c].items():
            np.testing.assert_array_equal(v, two.draws[c][name])
            np.testing.assert_array_equal(v, joint_fit.draws[c][name])
    alone = bayescap.fit(
        _tables(3)["B"], seed=sensor_seeds(5, 4)[3], quality="fast", fast_settings=channel_fast_settings()
    )
    np.testing.assert_array_equal(alone.chains.chain, one.results["B"].chains.chain)
    assert one.to_dict()["k_check"] == two.to_dict()["k_check"]
    # each channel's parameter summary, computed once where its fit ran, is the result's own
    for c in one.channels:
        assert two.summaries[c] == two.results[c].parameter_summary() == one.summaries[c]
    assert one.to_dict()["separate"] == two.to_dict()["separate"]


def test_channel_fits_gate_the_reported_parameters_and_still_check_the_rest(joint_fit):
    """At fast each channel fit's top-up and gate judge the parameters the colour result reports
    (their interval ends' predicted Monte Carlo error within the gate), not the monochrome derived
    quantities; the result still computes those (capacity, TR) and checks them against the same
    gate (a failure would send the channel to MCMC)."""
    from bayescap.colour.cfa_fit import REPORTED_PARAMETERS

    for c, r in joint_fit.results.items():
        d = r.diag
        assert d["method"] == "laplace-is" and d["converged"], c
        assert tuple(d["fast_settings"]["end_parameters"]) == REPORTED_PARAMETERS
        gated = set(r.chains.extra["end_mcse"])
        assert gated and gated <= set(REPORTED_PARAMETERS), (c, gated)
        gate = d["fast_settings"]["end_mcse_max"]
        end = d["interval_end_mcse"]
        assert {"capacity_bits", "tonal_range_bits"} <= set(end), c
        assert all(end[n] <= gate for n in gated | {"capacity_bits", "tonal_range_bits"}), c


def test_channel_fits_run_in_one_process_unless_asked(monkeypatch):
    """The channel fits' process count: one by default (a worker costs CPU time, the target's
    measure), ``BAYESCAP_JOBS`` or ``n_jobs`` for more, never more than the channels."""
    from bayescap.colour.cfa_fit import _channel_jobs

    monkeypatch.delenv("BAYESCAP_JOBS", raising=False)
    assert _channel_jobs(None, 4) == 1
    assert _channel_jobs(2, 4) == 2 and _channel_jobs(8, 4) == 4
    monkeypatch.setenv("BAYESCAP_JOBS", "3")
    assert _channel_jobs(None, 4) == 3 and _channel_jobs(1, 4) == 1


@pytest.mark.parametrize("bad", ["R", "Gr"])  # R is fitted in this process, Gr in a worker
def test_a_channel_fit_refusing_its_input_raises_here(bad, tmp_path):
    """An input error inside a worker process comes back as the same error, naming the file."""
    from bayescap.colour.cfa_fit import fit_cfa

    tables = dict(_tables(3))
    tables[bad] = tmp_path / "missing.csv"
    with pytest.raises(InputError, match="missing.csv"):
        fit_cfa(tables, seed=5, n_jobs=2)


def test_k_check_catches_a_digitally_scaled_channel():
    from bayescap.colour.cfa_fit import fit_cfa

    f = fit_cfa(_tables(3, k_r=2.5 / 1.08), seed=5)  # R scaled by 1.08 inside the "RAW"
    kc = f.k_check
    assert not kc["passed"] and kc["max_ratio"] == pytest.approx(1.08, rel=0.02)
    assert any("conversion gains disagree" in n for n in f.notes)


def test_chi2_check_without_scipy_stats():
    """The K check's p-value is the χ² survival function (for 3 degrees of freedom, in closed form
    erfc(√(x/2)) + √(2x/π)·e^(−x/2)), and the colour command's modules leave scipy.stats unimported
    (its import cost ~0.7 CPU s at the command's start, more than a fast channel fit)."""

    code = (
        "import sys, math\n"
        "import bayescap.api, bayescap.cli.colour, bayescap.colour.ccm, bayescap.colour.raw_metadata\n"
        "import bayescap.colour.scores, bayescap.colour.sensitivity, bayescap.io.cfa, bayescap.report.colour_section\n"
        "from bayescap.colour.agreement import chi2_check\n"
        "import numpy as np\n"
        "chi2, dof, p = chi2_check(np.array([0.0, 1.0, 2.0, 3.0]), np.ones(4))\n"
        "x = 5.0  # the values' squared distances from their mean 1.5, in sd: 2.25 + 0.25 + 0.25 + 2.25\n"
        "exact = math.erfc(math.sqrt(x / 2)) + math.sqrt(2 * x / math.pi) * math.exp(-x / 2)\n"
        "print(chi2 == x, dof, abs(p - exact) < 1e-12, 'scipy.stats' in sys.modules)\n"
    )
    stdout = python_stdout(code)
    assert stdout.split() == ["True", "3", "True", "False"]


# ----------------------------------------------------------------------------------- the CLI
@pytest.fixture(scope="module")
def colour_json(frame_set, tmp_path_factory):
    out = tmp_path_factory.mktemp("colour_out") / "res"
    status = main(["colour", str(frame_set), "--roi", "1.0", "--json", "--out", str(out), "--seed", "3"])
    assert status == 0
    return out


def test_colour_command_json_and_files(colour_json):
    doc = json.loads((colour_json / "colour.json").read_text())
    c = doc["colour"]
    for key in ("median", "ci68", "ci95", "unit"):
        assert key in c["cs_bits"]
    lo, hi = c["cs_bits"]["ci95"]
    assert 0 < hi - lo and lo < c["cs_bits"]["median"] < hi <= 24  # at most 3 x 8 bits with the floor
    assert set(c["scores"]) >= {"colour_depth_bits", "colour_depth_print_bits", "dynamic_range_ev_Gr", "snr_18_db_B"}
    assert set(c["capacity"]) == {"superpixel", "per_channel", "cs_luminance_mtf"}
    assert c["capacity"]["superpixel"]["median"] == pytest.approx(c["cs_bits"]["median"] * 48 * 48 / 4, rel=1e-3)
    # the matrix rows and the white balance read back from the DNGs, to 1e-4
    np.testing.assert_allclose(c["ccm"]["matrix"], GOLDEN_CCM, atol=1e-4)
    np.testing.assert_allclose(c["white_balance"]["gains"], [1 / 0.45, 1.0, 1 / 0.80], atol=1e-4)
    assert len(c["ccm"]["noise_gain"]) == 3 and c["ccm"]["condition_number"] > 1
    f = c["cfa_fit"]
    assert f["k_check"]["passed"] and set(f["separate"]) == {"R", "Gr", "Gb", "B"}
    k = f["shared"]["conversion_gain_e_per_dn"]["ci95"]
    assert k[0] < TRUTH["k"] < k[1]
    text = (colour_json / "colour.txt").read_text()
    for needle in ("Colour sensitivity CS", "K check", "Definitions:", "noise gain"):
        assert needle in text
    # each channel fit's own caveats reach the JSON, and the text once per caveat with its channels
    # (those the colour result already says, once)
    assert set(f["separate_notes"]) == set(f["separate_flags"]) == {"R", "Gr", "Gb", "B"}
    shown = [ln for ln in text.splitlines() if ln.startswith("  note (")]
    every = {n for notes in f["separate_notes"].values() for n in notes} - set(f["notes"] + c["notes"])
    assert every and len(shown) == len(every)
    assert all(any(ln.endswith(": " + n) for ln in shown) for n in every)


def _one_line_error(capsys, argv, *, must=()):
    status = main(argv)
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    for m in must:
        assert m in err
    return err


def test_raw_without_cfa_is_refused_naming_the_file(tmp_path, capsys):
    manifest = make_frame_set(tmp_path / "mono", levels=2, shape=(32, 32), mono=True)
    out = tmp_path / "out"
    _one_line_error(
        capsys, ["colour", str(manifest), "--out", str(out)], must=("bright_00_0.dng", "no colour filter array")
    )
    assert not out.exists()


def test_singular_ccm_is_refused_and_nothing_written(frame_set, tmp_path, capsys):
    out = tmp_path / "out"
    _one_line_error(
        capsys, ["colour", str(frame_set), "--ccm", "1,2,3,2,4,6,0,0,1", "--out", str(out)], must=("singular",)
    )
    assert not out.exists()


def test_channel_csvs_of_different_sizes_cli(frame_set, tmp_path, capsys):
    from bayescap.io import ingest

    paths = ingest(frame_set, out=tmp_path / "ptc.csv", channel="all", roi=1.0)
    paths[2].write_text(paths[2].read_text().replace(",576,", ",300,"))
    out = tmp_path / "out"
    _one_line_error(
        capsys,
        ["colour", *map(str, paths), "--ccm", "1,0,0,0,1,0,0,0,1", "--out", str(out)],
        must=(paths[2].name, "different sizes"),
    )
    assert not out.exists()


def test_colour_over_a_reflectance_set(frame_set, colour_json, capsys):
    """--domain reflectances: the same fit (same seed) over the chart's cone, a part of the cube:
    fewer colours, and the domain and the clipping stated."""
    argv = ["colour", str(frame_set), "--roi", "1.0", "--json", "--seed", "3", "--domain", "reflectances"]
    assert main(argv + ["--sensitivities", "Nikon 5100 (NPL)", "--illuminant", "D50"]) == 0
    c = json.loads(capsys.readouterr().out)["colour"]
    cube = json.loads((colour_json / "colour.json").read_text())["colour"]
    assert "ColorChecker N Ohta under D50" in c["choices"]["domain"] and "Nikon 5100" in c["choices"]["domain"]
    assert cube["choices"]["domain"].startswith("the full raw cube")
    assert c["choices"]["clip_output"] is True and cube["choices"]["clip_output"] is True
    assert c["cs_bits"]["ci95"][1] < cube["cs_bits"]["median"]


@pytest.mark.parametrize(
    "extra, must",
    [
        ([], ("--domain reflectances needs --sensitivities",)),
        (["--sensitivities", "Nikon 5100 (NPL)", "--illuminant", "D66"], ("unknown illuminant 'D66'",)),
        (["--sensitivities", "nosuch.csv"], ("nosuch.csv", "not a file")),
    ],
)
def test_reflectance_domain_refusals(frame_set, tmp_path, capsys, extra, must):
    out = tmp_path / "out"
    _one_line_error(
        capsys, ["colour", str(frame_set), "--domain", "reflectances", "--out", str(out), *extra], must=must
    )
    assert not out.exists()


# ---------------------------------------------------------------- report and datasheet sections
def test_colour_section_html_from_the_colour_json(colour_json):
    from bayescap.report.colour_section import colour_section_html, load_colour_result

    doc = load_colour_result(colour_json / "colour.json")
    page = colour_section_html(doc)
    cs = doc["colour"]["cs_bits"]
    assert page.startswith('<section id="colour">') and f"{cs['median']:.4g}" in page
    for needle in ("Colour-correction matrix", "noise gain", "K check", "superpixel", "(lower bound)"):
        assert needle in page


def test_datasheet_gains_a_colour_section(frame_set, colour_json, tmp_path, capsys):
    from bayescap.io import ingest

    (csv,) = ingest(frame_set, out=tmp_path / "ptc.csv", channel="Gr", roi=1.0)
    out = tmp_path / "ds.html"
    argv = ["datasheet", str(csv), "--colour", str(colour_json / "colour.json"), "-o", str(out), "--quality", "fast"]
    assert main(argv + ["--seed", "1"]) == 0
    page = out.read_text()
    assert page.count('<section id="colour">') == 1 and "Colour (beyond EMVA 1288)" in page


@pytest.mark.slow
def test_pdf_datasheet_gains_a_colour_page(frame_set, colour_json, tmp_path):
    """The PDF datasheet: one page, and a second with the colour section when --colour is given
    (its table rows are those of the HTML section's quantities)."""
    import re

    from bayescap.io import ingest
    from bayescap.report.colour_pdf import colour_rows

    (csv,) = ingest(frame_set, out=tmp_path / "ptc.csv", channel="Gr", roi=1.0)
    argv = ["datasheet", str(csv), "--quality", "fast", "--seed", "1"]
    assert main(argv + ["-o", str(tmp_path / "plain.pdf")]) == 0
    assert main(argv + ["-o", str(tmp_path / "colour.pdf"), "--colour", str(colour_json / "colour.json")]) == 0

    def pages(p):
        return len(re.findall(rb"/Type\s*/Page(?!s)", p.read_bytes()))

    assert pages(tmp_path / "plain.pdf") == 1 and pages(tmp_path / "colour.pdf") == 2
    doc = json.loads((colour_json / "colour.json").read_text())
    rows = colour_rows(doc["colour"])
    cs = doc["colour"]["cs_bits"]
    assert rows[0] == [
        "colour sensitivity CS",
        f"{cs['median']:.4g} bits",
        f"{cs['ci95'][0]:.4g} – {cs['ci95'][1]:.4g}",
    ]
    labels = [r[0] for r in rows]
    assert "colour capacity, superpixel" in labels and "dynamic range ev (B)" in labels


def test_report_refuses_a_colour_file_that_is_not_one(frame_set, tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"colour": {}}')
    out = tmp_path / "rep.html"
    _one_line_error(
        capsys, ["report", str(frame_set), "--colour", str(bad), "-o", str(out)], must=("bad.json", "bayescap colour")
    )
    assert not out.exists()


def test_cs_without_floor_closed_form_matches_the_general_integral():
    from bayescap.colour.cfa_fit import cs_without_floor
    from bayescap.colour.sensitivity import colour_sensitivity

    rng = np.random.default_rng(4)
    n = 6
    k = rng.uniform(0.5, 4.0, n)
    coeffs = np.stack(
        [np.stack([rng.uniform(1, 20, n) / k**2 + 1 / 12, 1 / k, rng.uniform(0, 1e-4, n)], axis=1)] * 4, axis=1
    )
    clip = rng.uniform(1000, 4000, (n, 4))
    ccm = [[1.6, -0.5, -0.1], [-0.2, 1.5, -0.3], [0.0, -0.6, 1.6]]
    general = colour_sensitivity(coeffs, clip, ccm, [2.0, 1.0, 1.5], floor=False).bits
    np.testing.assert_allclose(cs_without_floor(coeffs, clip), general, atol=1e-6)


def test_channel_csvs_without_a_ccm_or_with_a_bad_wb_are_refused(frame_set, tmp_path, capsys):
    from bayescap.io import ingest

    paths = [str(p) for p in ingest(frame_set, out=tmp_path / "ptc.csv", channel="all", roi=1.0)]
    _one_line_error(capsys, ["colour", *paths], must=("ptc_R.csv", "no colour-correction matrix", "--ccm"))
    _one_line_error(capsys, ["colour", *paths, "--ccm", "1,0,0,0,1,0,0,0,1", "--wb", "1,2"], must=("--wb",))
    _one_line_error(capsys, ["colour", *paths[:3], "--ccm", "1,0,0,0,1,0,0,0,1"], must=("four Bayer channels",))
