"""Mean/variance-only photon-transfer tables (CONTRACT 1b; docs/astronomy.md): the astronomy PTC
table of LSST cp_pipe or eotest, one row per flat pair, bias-subtracted means and pair-difference
variances / 2, no dark pairs, no exposure times, ``n_pixels`` optional.

The tables are simulated here frame by frame, independently of the model: Poisson charges, a
per-pixel full well, Gaussian read noise, rounding to integer ADU on a bias, and the statistics of
each flat pair as cp_pipe takes them.
"""

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

import bayescap
from bayescap.cli import main


def simulate_flat_pairs(
    seed,
    *,
    gain_e_per_adu=1.2,
    read_e=6.0,
    n_levels=40,
    n_px=10000,
    low_e=50.0,
    top_e=8e4,
    full_well_e=None,
    well_spread_e=0.0,
    bf_top=0.0,
    bias_adu=1000.0,
    subtract_bias=True,
):
    """(mean_adu, var_adu2) of ``n_levels`` flat pairs from ``low_e`` to ``top_e`` electrons per pixel
    (geometric steps) on a 100 × (n_px/100) pixel amplifier. ``full_well_e``: each pixel's charge clips
    at its own well (normal spread ``well_spread_e``). ``bf_top``: a brighter-fatter-like charge
    sharing, each pixel passing a fraction b = bf_top/8 · μ/top_e of its charge to each of its four
    neighbours (the mean stays, the variance falls by ≈ bf_top at the top). Means are pair averages
    less the bias; variances var(A − B)/2."""
    rng = np.random.default_rng(seed)
    shape = (100, n_px // 100)
    fw = None if full_well_e is None else full_well_e + well_spread_e * rng.standard_normal(shape)
    means, variances = [], []
    for mu in np.geomspace(low_e, top_e, n_levels):
        frames = []
        for _ in range(2):
            q = rng.poisson(mu, shape).astype(float)
            if bf_top:
                b = bf_top / 8.0 * mu / top_e
                nb = np.roll(q, 1, 0) + np.roll(q, -1, 0) + np.roll(q, 1, 1) + np.roll(q, -1, 1)
                q = (1.0 - 4.0 * b) * q + b * nb
            if fw is not None:
                q = np.minimum(q, fw)
            adu = np.round(q / gain_e_per_adu + (read_e / gain_e_per_adu) * rng.standard_normal(shape) + bias_adu)
            frames.append(adu)
        a, bb = frames
        means.append(0.5 * (a.mean() + bb.mean()) - (bias_adu if subtract_bias else 0.0))
        variances.append(0.5 * np.var(a - bb, ddof=1))
    return np.array(means), np.array(variances)


def write_table(path, mean, var, *, n_pixels=None, header_lines=()):
    cols = "mean_dn,temporal_var_dn2" + (",n_pixels" if n_pixels else "")
    rows = [f"{float(m)!r},{float(v)!r}" + (f",{n_pixels}" if n_pixels else "") for m, v in zip(mean, var)]
    Path(path).write_text("".join(f"{h}\n" for h in header_lines) + cols + "\n" + "\n".join(rows) + "\n")
    return path


def run_cli(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(args) + ["--no-progress"])
    return status, out.getvalue(), err.getvalue()


def _inside(s, truth):
    lo, hi = s["ci95"]
    return lo <= truth <= hi


# (seed, gain e-/ADU, read noise e-): gains across 0.6–1.8 e-/ADU
CASES = [(11, 0.65, 4.5), (12, 1.2, 6.0), (13, 1.75, 8.0)]


@pytest.mark.parametrize("with_n_pixels", [False, True], ids=["scatter_fitted", "n_pixels"])
@pytest.mark.parametrize("seed,gain,read", CASES)
def test_a_frame_simulated_table_fits(tmp_path, seed, gain, read, with_n_pixels):
    """K inside its 95 % interval, read noise (the PTC intercept) within 10 %, reported as
    read_noise_e; without n_pixels the scatter is the fitted discrepancy."""
    m, v = simulate_flat_pairs(seed, gain_e_per_adu=gain, read_e=read)
    p = write_table(tmp_path / "amp.csv", m, v, n_pixels=10000 if with_n_pixels else None)
    data = bayescap.load(p)
    assert not data.has_dark_rows and data.n_pixels_known == with_n_pixels
    d = bayescap.fit(data, seed=1, quality="fast").to_dict()
    assert d["diagnostics"]["converged"]
    par = d["parameters"]
    assert _inside(par["conversion_gain_e_per_dn"], gain), par["conversion_gain_e_per_dn"]
    assert par["read_noise_e"]["constrained"] and abs(par["read_noise_e"]["median"] / read - 1) < 0.10
    assert "dark_noise_e" not in par and "dark_current_e_per_s" not in par
    assert {"dark_current", "prnu", "dsnu", "quantum_efficiency"} <= set(d["terms_left_out"])
    assert ("variance_discrepancy" in d["term_notes"]) == (not with_n_pixels)
    if with_n_pixels:
        # pure Poisson + Gaussian frames: nothing beyond the 1.4 % sampling error of 10⁴ pixels
        assert par["variance_discrepancy"]["median"] < 0.01


def test_black_level_says_the_means_still_hold_the_offset(tmp_path):
    """Means with the bias left in and ``# black_level_dn:`` fit as the bias-subtracted table does."""
    m, v = simulate_flat_pairs(21, gain_e_per_adu=0.9, read_e=5.0, subtract_bias=False, bias_adu=1000.0)
    p = write_table(tmp_path / "raw.csv", m, v, header_lines=["# black_level_dn: 1000"])
    q = write_table(tmp_path / "sub.csv", m - 1000.0, v)
    a = bayescap.fit(p, seed=3, quality="fast").to_dict()["parameters"]
    b = bayescap.fit(q, seed=3, quality="fast").to_dict()["parameters"]
    for name in ("conversion_gain_e_per_dn", "read_noise_e"):
        assert a[name]["median"] == pytest.approx(b[name]["median"], rel=1e-6)
    assert _inside(a["conversion_gain_e_per_dn"], 0.9) and abs(a["read_noise_e"]["median"] / 5.0 - 1) < 0.10


def test_a_saturating_table_reports_its_ptc_turnoff(tmp_path):
    """ptc_turnoff_dn in the JSON and the text: the last row before the variance falls (here the
    variance peak), bracketed by the next row; the rows past it are named and inform the full well."""
    m, v = simulate_flat_pairs(31, gain_e_per_adu=1.2, top_e=1.3e5, full_well_e=9e4, well_spread_e=1500.0)
    p = write_table(tmp_path / "sat.csv", m, v)
    status, out, _ = run_cli(["fit", str(p), "--seed", "1", "--quality", "fast", "--json"])
    assert status == 0
    d = json.loads(out)
    t = d["derived"]["ptc_turnoff_dn"]
    i = int(np.argmax(v))
    order = np.sort(m)
    assert t["median"] == pytest.approx(m[i]) and t["ci95"][1] == pytest.approx(order[np.searchsorted(order, m[i]) + 1])
    past = [k + 1 for k in range(m.size) if m[k] > m[i]]  # data rows (1-based) above the turnoff
    assert t["rows_past"] == past and "full_well" in t["rows_past_use"]
    # the turnoff sits below the well (the variance falls as the first pixels clip)
    assert t["median"] * 1.2 < 9e4 and _inside(d["parameters"]["full_well_e"], 9e4)
    status, text, _ = run_cli(["fit", str(p), "--seed", "1", "--quality", "fast"])
    assert "ptc_turnoff_dn" in text and "rows past the PTC turnoff" in text


def test_without_a_turnoff_it_is_a_lower_limit(tmp_path):
    m, v = simulate_flat_pairs(32)
    d = bayescap.fit(write_table(tmp_path / "lin.csv", m, v), seed=1, quality="fast").to_dict()
    t = d["derived"]["ptc_turnoff_dn"]
    assert t["median"] is None and t["limit"]["kind"] == "lower" and t["limit"]["value"] == pytest.approx(m.max())


def test_the_text_names_what_was_left_out_and_why(tmp_path):
    m, v = simulate_flat_pairs(41)
    status, text, _ = run_cli(["fit", str(write_table(tmp_path / "a.csv", m, v)), "--seed", "1", "--quality", "fast"])
    assert status == 0
    assert "read_noise_e" in text and "dark_noise_e" not in text
    for term in ("dark_current", "prnu", "dsnu", "quantum_efficiency"):
        assert f"left out: {term}: " in text
    assert "mean/variance table (no dark pairs)" in text and "intercept" in text


def test_a_nan_cell_is_refused_with_file_row_and_column(tmp_path):
    m, v = simulate_flat_pairs(51, n_levels=8)
    lines = ["mean_dn,temporal_var_dn2"] + [f"{float(a)!r},{float(b)!r}" for a, b in zip(m, v)]
    lines[3] = lines[3].split(",")[0] + ",nan"  # data row 3 (after the header)
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    status, stdout, err = run_cli(["fit", str(p), "--seed", "1", "--quality", "fast", "--out", str(out)])
    assert status == 2 and stdout == ""
    msg = err.strip().splitlines()
    assert len(msg) == 1 and "bad.csv" in msg[0] and "row 3" in msg[0] and "temporal_var_dn2" in msg[0]
    assert not out.exists()


def test_a_table_with_dark_columns_still_needs_all_of_them(tmp_path):
    """A dark column makes it the full contract table: a missing n_pixels is still an error."""
    p = tmp_path / "x.csv"
    p.write_text(
        "exposure_time_s,mean_dn,temporal_var_dn2,dark_mean_dn,dark_temporal_var_dn2\n0.1,100,30,10,5\n0.2,200,55,10,5\n"
    )
    with pytest.raises(bayescap.exceptions.PTCInputError, match="missing required column.*n_pixels"):
        bayescap.load(p)


def test_cp_pipe_column_names(tmp_path):
    m, v = simulate_flat_pairs(61, n_levels=10)
    p = tmp_path / "cp.csv"
    p.write_text("rawMeans,rawVars\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(m, v)))
    d = bayescap.load(p)
    np.testing.assert_array_equal(np.sort(d.mean_dn), np.sort(m))
    p.write_text("rawMeans,rawVars\n1,2\n3,inf\n")
    with pytest.raises(
        bayescap.exceptions.PTCInputError, match=r"row 2, column 'rawVars \(read as temporal_var_dn2\)'"
    ):
        bayescap.load(p)


def test_modest_variance_curvature(tmp_path):
    """A brighter-fatter-like charge sharing (the variance 8 % short at the top, the means linear):
    K (the small-signal gain) inside its interval and the read noise within 10 %, the bend fitted by
    the brighter-fatter term (a mean/variance table's bend always is: model/terms.py)."""
    m, v = simulate_flat_pairs(71, gain_e_per_adu=1.5, read_e=7.0, n_levels=60, top_e=1e5, bf_top=0.08)
    d = bayescap.fit(write_table(tmp_path / "bf.csv", m, v), seed=1, quality="fast").to_dict()
    par = d["parameters"]
    assert "brighter_fatter" in d["model_terms"] and "response_nonlinearity" not in d["model_terms"]
    assert par["brighter_fatter_a00_per_e"]["ci95"][1] < 0  # a variance loss
    assert _inside(par["conversion_gain_e_per_dn"], 1.5), par["conversion_gain_e_per_dn"]
    assert abs(par["read_noise_e"]["median"] / 7.0 - 1) < 0.10


def test_a_folder_of_tables_gives_the_same_numbers_on_the_pool_and_on_dask(tmp_path):
    """A focal plane's amplifiers as one batch: ``bayescap fit DIR --out OUT --jobs 2`` (the local
    pool) and the same batch on a Dask cluster (in-process workers, the runner ``--dask`` uses) write
    the same results, bit for bit."""
    import distributed  # (the test extra installs it, as for tests/test_batch_dask.py)

    from bayescap.batch import fit_many

    folder = tmp_path / "amps"
    folder.mkdir()
    for i, (g, r) in enumerate([(0.7, 5.0), (1.0, 6.0), (1.3, 7.0), (1.7, 9.0)]):
        m, v = simulate_flat_pairs(80 + i, gain_e_per_adu=g, read_e=r, n_levels=40 + 20 * i)
        write_table(folder / f"amp{i:02d}.csv", m, v)
    status, _, err = run_cli(
        ["fit", str(folder), "--seed", "9", "--quality", "fast", "--out", str(tmp_path / "pool"), "--jobs", "2"]
    )
    assert status == 0, err
    paths = sorted(str(p) for p in folder.glob("*.csv"))
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as c,
        distributed.Client(c) as client,
    ):
        fit_many(paths, seed=9, out=tmp_path / "dask", client=client, chunk_size=1)
    docs = {
        how: {
            p.parent.name: _numbers(json.loads(p.read_text())) for p in sorted((tmp_path / how).glob("*/result.json"))
        }
        for how in ("pool", "dask")
    }
    assert len(docs["pool"]) == 4 and docs["pool"] == docs["dask"]
    for d in docs["pool"].values():
        assert "ptc_turnoff_dn" in d["derived"] and "read_noise_e" in d["parameters"]


def _numbers(doc):
    doc["diagnostics"] = {k: v for k, v in doc["diagnostics"].items() if not k.endswith("wall_s")}
    return doc


def test_rows_past_the_turnoff_are_not_outliers_a_corrupted_row_is(tmp_path):
    """Without a frac_saturated column the rows past the PTC's turnoff are the rows at the clip: those
    the mixture down-weights there (an amplifier simulated frame by frame, whose wells spread: the clip
    model is an approximation) are flagged rows_in_the_clip_misfit, not outliers; a corrupted row
    below the turnoff is still an outlier."""
    from bayescap.validation.astro import ensure_astro_csv, focal_plane

    name, truth, seed = focal_plane()[2]  # 47 flat pairs, 32 × 32 pixels
    path = ensure_astro_csv(tmp_path, name, truth, seed, n_pixels=True)
    d = bayescap.fit(str(path), seed=1, quality="fast").to_dict()
    past = set(d["derived"]["ptc_turnoff_dn"]["rows_past"])
    clip = set(d["flags"].get("rows_in_the_clip_misfit", []))
    assert clip and clip <= past and not {o["row"] for o in d["outliers"]} & past
    assert "lie past the PTC's turnoff" in " ".join(d["notes"])
    # the same table with one row's variance 50 % high, well below the turnoff
    lines = path.read_text().splitlines()
    head = [i for i, line in enumerate(lines) if not line.startswith("#")][0]
    cols = lines[head].split(",")
    j = cols.index("temporal_var_dn2")
    row = head + 10  # data row 10
    cells = lines[row].split(",")
    cells[j] = repr(1.5 * float(cells[j]))
    lines[row] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    d = bayescap.fit(str(bad), seed=1, quality="fast").to_dict()
    assert 10 in {o["row"] for o in d["outliers"]} and 10 not in d["flags"].get("rows_in_the_clip_misfit", [])
