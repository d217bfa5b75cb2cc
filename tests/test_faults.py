"""Faults while writing and running (issue 48): a file-size limit or a full disk while the
posterior is written, crafted result files, races on one output folder, pool workers whose parent
dies, stale temporary folders. Each leaves the last good result or nothing, and no process or
temporary file behind."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import bayescap
from bayescap.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _env():
    return dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    from bayescap.simulate import SensorTruth, simulate_ptc

    p = tmp_path_factory.mktemp("csv") / "cam.csv"
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
def saved_result(small_csv, tmp_path_factory):
    r = bayescap.fit(small_csv, seed=1, quality="fast")
    return r.save(tmp_path_factory.mktemp("nc") / "fit.nc")


def _run_limited(code: str, limit_bytes: int):
    """``code`` in a fresh interpreter whose files may not grow beyond ``limit_bytes`` (``ulimit
    -f``; Python ignores SIGXFSZ, so a write past it fails with EFBIG)."""
    pre = f"import resource; resource.setrlimit(resource.RLIMIT_FSIZE, ({limit_bytes}, resource.RLIM_INFINITY))\n"
    return subprocess.run(
        [sys.executable, "-c", pre + textwrap.dedent(code)], env=_env(), capture_output=True, text=True, timeout=120
    )


def test_save_and_out_under_a_file_size_limit_fail_cleanly(saved_result, tmp_path):
    """``FitResult.save`` and ``--out``'s writer under ``ulimit -f``: an OSError (EFBIG; exit 1 in
    the CLI), the previous set kept, no temporary file or folder. Was: SIGSEGV (rc 139) inside
    h5py, a temporary file and a ``.DIR.*.tmp`` folder left."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "result.json").write_text("{}")  # a previous run's set (one file of it)
    dest = tmp_path / "again.nc"
    p = _run_limited(
        f"""
        import bayescap
        from bayescap.report.text import write_outputs
        r = bayescap.FitResult.load({str(saved_result)!r})
        for f, a in ((r.save, {str(dest)!r}), (lambda d: write_outputs(r, d), {str(out)!r})):
            try:
                f(a)
            except OSError as e:
                print("OSError", e.errno)
        """,
        200_000,
    )
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.split("\n")[:2] == ["OSError 27", "OSError 27"]  # EFBIG, twice
    assert os.listdir(tmp_path) == ["o"] and os.listdir(out) == ["result.json"]


def test_saved_posterior_reads_back_identical(saved_result, tmp_path):
    """The in-memory netCDF writer gives the content ArviZ's own writer gives."""
    import arviz as az
    import xarray.testing as xt

    from bayescap.posterior.storage import netcdf_bytes

    idata = az.from_netcdf(str(saved_result)).load()
    (tmp_path / "a.nc").write_bytes(netcdf_bytes(idata))
    idata.to_netcdf(str(tmp_path / "b.nc"))
    a, b = (az.from_netcdf(str(tmp_path / n)) for n in ("a.nc", "b.nc"))
    assert a.groups() == b.groups() == idata.groups()
    for g in a.groups():
        xt.assert_identical(a[g], b[g])
    assert a.attrs == b.attrs


def _crafted(saved_result, tmp_path, edit):
    """A copy of the saved result whose ``bayescap_result`` state went through ``edit``."""
    import arviz as az

    from bayescap.posterior.storage import netcdf_bytes

    idata = az.from_netcdf(str(saved_result)).load()
    state = json.loads(idata.attrs["bayescap_result"])
    edit(state)
    idata.attrs["bayescap_result"] = json.dumps(state)
    p = tmp_path / "crafted.nc"
    p.write_bytes(netcdf_bytes(idata))
    return p


def test_load_refuses_an_mtf_class_bayescap_does_not_write(saved_result, tmp_path):
    """Was: ``"mtf": {"class": ...}`` built any attribute of the optics module (a module function,
    an imported class) with the file's arguments."""

    def edit(s):
        s["mtf"] = {"class": "np", "x": 1}

    p = _crafted(saved_result, tmp_path, edit)
    with pytest.raises(ValueError, match="not a bayescap MTF class"):
        bayescap.FitResult.load(p)


def test_load_refuses_a_crafted_chain_shape_before_allocating(saved_result, tmp_path):
    """Was: a crafted ``chains.shape`` asked numpy for 30 GiB (MemoryError, or the machine's swap)."""

    def edit(s):
        s["chains"]["shape"] = [1, 1_000_000, 4000, s["chains"]["shape"][3]]

    p = _crafted(saved_result, tmp_path, edit)
    with pytest.raises(ValueError, match="shape"):
        bayescap.FitResult.load(p)
