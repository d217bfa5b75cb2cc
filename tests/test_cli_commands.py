"""The other subcommands: mtf, fit --mtf, sweep, ingest registration."""

import contextlib
import io
import json
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

EDGE = Path(__file__).parent / "data" / "slanted_edge" / "sfrmat3_v_edge_mono.tif"


def _run(*args):
    return subprocess.run([sys.executable, "-m", "bayescap.cli", *map(str, args)], capture_output=True, text=True)


def _main(*args):
    """``bayescap ARGS`` in this process (what :func:`_run` gives, without a fresh interpreter's
    imports): its exit status, standard output and standard error."""
    from bayescap.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in args])
        except SystemExit as e:  # argparse's usage errors
            code = e.code
    return types.SimpleNamespace(returncode=0 if code is None else code, stdout=out.getvalue(), stderr=err.getvalue())


def test_mtf_command_json_and_table(tmp_path):
    out = tmp_path / "mtf.csv"
    r = _run("mtf", EDGE, "--npol", "1", "--json", "--out", out, "--n-boot", "50")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert abs(d["mtf50_cy_per_px"] - 0.1980) < 0.02 * 0.1980  # sfrmat5 reference SFR50 (npol 1)
    lo, hi = d["mtf50_ci95_cy_per_px"]
    assert lo < d["mtf50_cy_per_px"] < hi
    assert out.read_text().splitlines()[0].startswith("freq_cy_per_px,mtf")


def test_mtf_command_bad_input_exit_2(tmp_path):
    flat = tmp_path / "flat.npy"
    np.save(flat, np.full((60, 60), 0.5))
    # the missing file in a fresh process, the others through main in this process (same checks)
    for args, run in (
        (("mtf", tmp_path / "missing.tif"), _run),
        (("mtf", flat), _main),
        (("mtf", EDGE, "--roi", "1,2,3"), _main),
    ):
        r = run(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


@pytest.mark.slow
def test_fit_with_measured_edge_carries_sharpness_uncertainty(tmp_path):
    from bayescap.simulate import SensorTruth, simulate_ptc

    csv = tmp_path / "s.csv"
    simulate_ptc(
        SensorTruth(conversion_gain_e_per_dn=2.0, read_noise_e=3.0, full_well_e=8000.0),
        seed=3,
        shape=(50, 50),
        n_levels=20,
        path=csv,
        metadata={"pixel_pitch_um": 2.2},
    )
    r = _run("fit", csv, "--json", "--seed", "1", "--quality", "fast", "--mtf", EDGE)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    ds = d["derived"]["mtf_loss_bits"]
    assert ds["ci95"][0] < ds["median"] < ds["ci95"][1]  # a measured MTF has draws: Δs has an interval
    assert d["mtf"]["model"]["name"].startswith("measured:")
    r2 = _run("fit", csv, "--mtf", tmp_path / "none.csv")
    assert r2.returncode == 2 and "Traceback" not in r2.stderr


def test_sweep_command_gives_optimal_pitch_with_interval():
    r = _run("sweep", "pixel-size", "--format", "1/4in", "--f-number", "2.8", "--json", "--draws", "300")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    text = json.dumps(d)
    assert "optimal" in text and "ci95" in text


def test_help_lists_every_command():
    r = _run("--help")
    for cmd in ("fit", "ingest", "mtf", "sweep", "compare", "report"):
        assert cmd in r.stdout


@pytest.mark.slow
def test_fit_many_csvs_as_a_batch(tmp_path):
    """``bayescap fit a.csv b.csv ... --quality fast``: one fit JSON per CSV (each the same as that
    CSV fitted alone, by the batch's child seed), outputs in DIR/<name>/; a bad CSV among them
    stops the run with exit 2 before anything is written."""
    from bayescap.batch import gpixel_sensors
    from bayescap.io.ptc_csv import write_ptc_csv

    datas, _ = gpixel_sensors(n_max=3, seed=6)
    paths = [tmp_path / f"roi{i}.csv" for i in range(3)]
    for d, p in zip(datas, paths):
        write_ptc_csv(d, p)
    out = tmp_path / "out"
    r = _run("fit", *paths, "--quality", "fast", "--seed", "3", "--json", "--out", out)
    assert r.returncode == 0, r.stderr
    docs = json.loads(r.stdout)
    assert [Path(d["input"]).name for d in docs] == [p.name for p in paths]
    assert sorted(x.name for x in out.iterdir() if x.is_dir()) == ["roi0", "roi1", "roi2"]
    assert {x.name for x in out.iterdir() if x.is_file()} <= {"summary.csv", "summary.parquet"}
    assert json.loads((out / "roi1" / "result.json").read_text()) == docs[1]
    # a missing file: exit 2, one line naming it, nothing written
    out2 = tmp_path / "out2"
    r = _run("fit", paths[0], tmp_path / "missing.csv", "--quality", "fast", "--out", out2)
    assert r.returncode == 2 and "missing.csv" in r.stderr and "Traceback" not in r.stderr
    assert not out2.exists()
    r = _main("fit", paths[0], paths[1], "--select-model")  # (a refusal in a fresh process: the one above)
    assert r.returncode == 2 and "one CSV at a time" in r.stderr


@pytest.mark.slow
def test_fast_tolerance_and_confidence_flags(tmp_path):
    """``--fast-tolerance``/``--fast-confidence`` set the fast path's check (FastSettings), are recorded
    in the result JSON, make it stop drawing no later than the default does (the same seed draws the
    same first proposals; a looser target is met no later), reach the batch too, and are refused
    with exit 2 outside ``--quality fast`` or out of range. The default run is a true subprocess,
    the others run in this process."""
    # a linear sensor: the fast path's check accepts it (the Basler set's response terms send it to MCMC)
    sensor = Path(__file__).resolve().parents[1] / "data" / "simulated" / "sim_industrial_3p45um_12bit.csv"
    runs = {}
    for name, extra, run in (("default", (), _run), ("loose", ("--fast-tolerance", "0.1"), _main)):
        r = run("fit", sensor, "--quality", "fast", "--seed", "1", "--json", *extra)
        assert r.returncode == 0, r.stderr
        runs[name] = json.loads(r.stdout)["diagnostics"]
    d, lo = runs["default"], runs["loose"]
    assert d["fast_settings"]["end_tolerance"] == 0.05 and d["fast_settings"]["end_mcse_max"] == 0.035
    assert lo["fast_settings"]["end_tolerance"] == 0.1
    assert abs(lo["fast_settings"]["end_mcse_max"] - 0.07) < 1e-12
    assert d["fast_path_accepted"] and lo["fast_path_accepted"]
    assert lo["n_proposals"] <= d["n_proposals"]
    assert "within 0.1 of its width" in lo["fast_path"]

    from bayescap.batch import gpixel_sensors
    from bayescap.io.ptc_csv import write_ptc_csv

    datas, _ = gpixel_sensors(n_max=2, seed=6)
    paths = [tmp_path / f"roi{i}.csv" for i in range(2)]
    for dd, p in zip(datas, paths):
        write_ptc_csv(dd, p)
    r = _main("fit", *paths, "--quality", "fast", "--seed", "3", "--json", "--fast-confidence", "none")
    assert r.returncode == 0, r.stderr
    assert all(doc["diagnostics"]["fast_settings"]["end_confidence"] is None for doc in json.loads(r.stdout))

    # compare and report (fast by default) take them too
    bench = sorted((Path(__file__).resolve().parents[1] / "data" / "benchmark").glob("*.csv"))[:2]
    r = _main("compare", *bench, "--fast-tolerance", "0.1", "--json")
    assert r.returncode == 0, r.stderr
    assert [s["fast_settings"]["end_tolerance"] for s in json.loads(r.stdout)["sensors"]] == [0.1, 0.1]
    r = _main("report", *bench, "--fast-confidence", "7", "-o", tmp_path / "r.html")
    assert r.returncode == 2 and "--fast-confidence must be" in r.stderr and not (tmp_path / "r.html").exists()

    for bad, msg in (
        (("--fast-tolerance", "0.1"), "apply to --quality fast only"),
        (("--quality", "fast", "--fast-tolerance", "1.5"), "--fast-tolerance must be"),
        (("--quality", "fast", "--fast-confidence", "high"), "--fast-confidence must be"),
    ):
        r = _main("fit", sensor, *bad)
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--f-number", "0"], "--f-number must be"),
        (["--f-number", "nan"], "--f-number must be"),
        (["--draws", "0"], "--draws must be at least 1"),
        (["--wavelength-nm", "-5"], "--wavelength-nm"),
        (["--f-number", "1e308"], "capacity is zero at every pitch"),
    ],
)
def test_sweep_bad_numbers_exit_2_one_line(args, fragment):
    """A zero or NaN f-number, --draws 0, or an f/1e308 lens (whose capacities are all zero, so no
    optimal pitch) is a usage error: exit 2 and one line, no traceback."""
    # the first case in a fresh process, the others through main in this process (same checks)
    run = _run if args == ["--f-number", "0"] else _main
    r = run("sweep", "pixel-size", "--draws", "50", *args)
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bayescap: error:") and fragment in lines[0], r.stderr


BASLER = Path(__file__).parents[1] / "data" / "emva1288_basler_ccd12.csv"


@pytest.mark.parametrize(
    "cmd", [["fit", BASLER], ["compare", BASLER, BASLER], ["report", BASLER], ["sweep", "pixel-size"], ["mtf", EDGE]]
)
def test_negative_seed_is_a_usage_error_not_a_traceback(cmd):
    """--seed -1 is refused by the parser, before it reaches numpy's SeedSequence (fit in a fresh
    process, the other commands through main in this process: argparse's exit, same checks)."""
    r = (_run if cmd[0] == "fit" else _main)(*cmd, "--seed", "-1")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "argument --seed: expected a whole number >= 0, got -1" in r.stderr


def test_scene_exposure_beyond_any_plausible_value_is_refused():
    """--scene-exposure-s 1e308 (which would overflow the dark signal in the report's noise
    breakdown) is refused."""
    r = _run("fit", BASLER, "--quality", "fast", "--scene-exposure-s", "1e308")
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "scene exposure time must be a number in [0, 1e+30] s" in lines[0], r.stderr
