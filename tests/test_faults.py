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


@pytest.fixture(scope="module")
def saved_idata(saved_result):
    """``saved_result`` as ArviZ reads it (read-only: a test that edits it edits a copy)."""
    import arviz as az

    return az.from_netcdf(str(saved_result)).load()


def _run_limited(code: str, limit_bytes: int):
    """``code`` in a fresh interpreter whose files may not grow beyond ``limit_bytes`` (``ulimit
    -f``; Python ignores SIGXFSZ, so a write past it fails with EFBIG)."""
    pre = f"import resource; resource.setrlimit(resource.RLIMIT_FSIZE, ({limit_bytes}, resource.RLIM_INFINITY))\n"
    return subprocess.run(
        [sys.executable, "-c", pre + textwrap.dedent(code)], env=_env(), capture_output=True, text=True, timeout=120
    )


@pytest.mark.slow
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


def test_saved_posterior_reads_back_identical(saved_idata, tmp_path):
    """The in-memory netCDF writer gives the content ArviZ's own writer gives."""
    import arviz as az
    import xarray.testing as xt

    from bayescap.posterior.storage import netcdf_bytes

    idata = saved_idata
    (tmp_path / "a.nc").write_bytes(netcdf_bytes(idata))
    idata.to_netcdf(str(tmp_path / "b.nc"))
    a, b = (az.from_netcdf(str(tmp_path / n)) for n in ("a.nc", "b.nc"))
    assert a.groups() == b.groups() == idata.groups()
    for g in a.groups():
        xt.assert_identical(a[g], b[g])
    assert a.attrs == b.attrs


def _crafted(saved_idata, tmp_path, edit):
    """A copy of the saved result whose ``bayescap_result`` state went through ``edit``."""
    from bayescap.posterior.storage import netcdf_bytes

    idata = saved_idata.copy()  # its own attrs: the module's saved_idata stays as read
    assert idata.attrs is not saved_idata.attrs
    state = json.loads(idata.attrs["bayescap_result"])
    edit(state)
    idata.attrs["bayescap_result"] = json.dumps(state)
    p = tmp_path / "crafted.nc"
    p.write_bytes(netcdf_bytes(idata))
    return p


def test_load_refuses_an_mtf_class_bayescap_does_not_write(saved_idata, tmp_path):
    """Was: ``"mtf": {"class": ...}`` built any attribute of the optics module (a module function,
    an imported class) with the file's arguments."""

    def edit(s):
        s["mtf"] = {"class": "np", "x": 1}

    p = _crafted(saved_idata, tmp_path, edit)
    with pytest.raises(ValueError, match="not a bayescap MTF class"):
        bayescap.FitResult.load(p)


def test_load_refuses_a_crafted_chain_shape_before_allocating(saved_idata, tmp_path):
    """Was: a crafted ``chains.shape`` asked numpy for 30 GiB (MemoryError, or the machine's swap)."""

    def edit(s):
        s["chains"]["shape"] = [1, 1_000_000, 4000, s["chains"]["shape"][3]]

    p = _crafted(saved_idata, tmp_path, edit)
    with pytest.raises(ValueError, match="shape"):
        bayescap.FitResult.load(p)


# ------------------------------------------------------------------ an output folder's twins


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_twins_of_a_dead_run_are_cleaned_and_its_set_aside_restored(tmp_path):
    """Was: ``kill -9`` during ``--out`` left ``.DIR.*.tmp`` folders that nothing removed."""
    from bayescap.io.atomic import write_dir_atomically

    dead, target = _dead_pid(), tmp_path / "o"
    (tmp_path / f".o.{dead}.abcd1234.tmp").mkdir()  # killed while filling
    old = tmp_path / f".o.{dead}.ef.old"  # killed between setting the set aside and the swap
    old.mkdir()
    (old / "a").write_text("last good")
    alive = tmp_path / f".o.{os.getpid()}.99.tmp"  # a running process's: not touched
    alive.mkdir()

    def fill(d):
        (d / "a").write_text("new")

    write_dir_atomically(target, fill)
    assert sorted(os.listdir(tmp_path)) == sorted(["o", alive.name])
    assert (target / "a").read_text() == "new"


def test_a_dead_runs_set_aside_is_the_last_good_result(tmp_path):
    from bayescap.io.atomic import clean_stale_twins

    dead = _dead_pid()
    old = tmp_path / f".o.{dead}.ef.old"
    old.mkdir()
    (old / "a").write_text("last good")
    clean_stale_twins(tmp_path / "o")
    assert os.listdir(tmp_path) == ["o"] and (tmp_path / "o" / "a").read_text() == "last good"


def _swap_many(target, tag, n):
    from bayescap.io.atomic import write_dir_atomically

    for k in range(n):

        def fill(d, k=k):
            for f in ("a", "b", "c"):
                (d / f).write_text(f"{tag}{k}")

        write_dir_atomically(target, fill)


def test_concurrent_swaps_leave_one_whole_set_and_no_twin(tmp_path):
    """Was: two runs swapping one folder could leave a whole ``.DIR.*.old`` set (ENOTEMPTY on the
    way back)."""
    import multiprocessing as mp

    target = tmp_path / "o"
    ctx = mp.get_context("fork")
    ps = [ctx.Process(target=_swap_many, args=(target, t, 40)) for t in "XYZ"]
    for p in ps:
        p.start()
    for p in ps:
        p.join(60)
    assert [p.exitcode for p in ps] == [0, 0, 0]
    assert os.listdir(tmp_path) == ["o"]
    assert len({(target / f).read_text() for f in ("a", "b", "c")}) == 1  # one run's set
