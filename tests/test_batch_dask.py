"""The batch on a Dask cluster and written as it runs (issue 41, docs/batch.md): a ``LocalCluster``
of 2 single-threaded worker processes gives every sensor the numbers of the local run; a worker
killed mid-run and the batch still completes, every result written once; a run stopped halfway
resumes without refitting what is done; an edited CSV is refitted.

Dask is part of the ``test`` extra: without it this module fails, naming what to install."""

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from bayescap.batch import fit_many, gpixel_sensors
from bayescap.batch.cluster import DASK_HINT, local_cluster
from bayescap.batch.runner import fit_to_folder

try:
    import distributed
except ImportError:  # not a skip: the test extra installs it
    raise ImportError(DASK_HINT) from None


ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def client():
    with local_cluster(2) as cluster, distributed.Client(cluster) as c:  # the cluster `--dask 2` starts
        yield c


@pytest.fixture(scope="module")
def sensors():
    # 8 ROIs in chunks of 2: four chunks on the two workers, as 16 in chunks of 4 were; the fifth
    # (index 4) fails the fast path's check and falls back to MCMC
    datas, _ = gpixel_sensors(n_max=8, seed=3)
    return datas


def _numbers(doc):
    """A fit JSON without its wall times (a batch's are amortised over its sensors)."""
    doc = json.loads(json.dumps(doc))
    doc["diagnostics"] = {k: v for k, v in doc["diagnostics"].items() if not k.endswith("wall_s")}
    return doc


def _docs(out, report):
    return [json.loads((Path(out) / r["name"] / "result.json").read_text()) for r in report]


def _inodes(out):
    return {p.parent.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in Path(out).glob("*/result.json")}


@pytest.mark.slow
def test_dask_gives_every_sensor_the_local_runs_numbers(client, sensors, tmp_path):
    """Same seeds, same numbers: the result.json files the cluster wrote (chunks of 2, on 2 workers)
    against the batch run in this process (one chunk, in memory: FitResult.to_dict()). (The local
    pool writing the same files is tests/test_batch.py's and the resume test's below.)"""
    rd = fit_many(sensors, seed=7, out=tmp_path / "dask", client=client, chunk_size=2)
    assert [r["status"] for r in rd] == ["fitted"] * len(sensors)
    dd = _docs(tmp_path / "dask", rd)
    mem = fit_many(sensors, seed=7)
    for a, r in zip(dd, mem, strict=True):
        b = _numbers(r.to_dict())
        assert _numbers({k: v for k, v in a.items() if k != "batch"}) == b
    methods = Counter(d["diagnostics"]["method"] for d in dd)
    assert methods["laplace-is"] >= 6 and len(methods) == 2, methods  # and an MCMC fallback


def test_a_stopped_run_resumes_without_refitting(client, sensors, tmp_path):
    """Stopped after two chunks (as by Ctrl-C), rerun into the same folder: the sensors written
    are kept untouched (same file, same mtime), only the rest are fitted; the local pool then finds
    everything done."""
    out = tmp_path / "out"
    seen = []

    def stop_after_two(ix):
        seen.append(ix)
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fit_to_folder(sensors, seed=7, out=out, client=client, chunk_size=2, on_chunk=stop_after_two, fallback=False)
    before = _inodes(out)
    assert 0 < len(before) < len(sensors)
    report = fit_many(sensors, seed=7, out=out, client=client, chunk_size=2, fallback=False)
    status = Counter(r["status"] for r in report)
    assert status == {"resumed": len(before), "fitted": len(sensors) - len(before)}
    assert {r["name"] for r in report if r["status"] == "resumed"} == set(before)
    after = _inodes(out)
    assert all(after[n] == before[n] for n in before) and len(after) == len(sensors)
    again = fit_many(sensors, seed=7, out=out, n_jobs=2, fallback=False)
    assert {r["status"] for r in again} == {"resumed"} and _inodes(out) == after


def test_an_edited_csv_or_another_seed_is_refitted(tmp_path):
    """The resume key is the seed, the data's hash and the settings: an edited CSV is fitted again,
    the other kept; another base seed fits everything again."""
    from bayescap.io.ptc_csv import write_ptc_csv

    datas, _ = gpixel_sensors(n_max=2, seed=5)
    paths = [tmp_path / f"roi{i}.csv" for i in range(2)]
    for d, p in zip(datas, paths):
        write_ptc_csv(d, p)
    out = tmp_path / "out"
    assert [r["status"] for r in fit_many(paths, seed=1, out=out, fallback=False)] == ["fitted", "fitted"]
    lines = paths[1].read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln and not ln.startswith("#") and ln[0].isdigit())
    cells = lines[i].split(",")
    cells[1] = repr(float(cells[1]) + 0.5)  # the first level's mean, half a DN up
    lines[i] = ",".join(cells)
    paths[1].write_text("\n".join(lines) + "\n")
    report = fit_many(paths, seed=1, out=out, fallback=False)
    assert [r["status"] for r in report] == ["resumed", "fitted"]
    assert [r["name"] for r in report] == ["roi0", "roi1"]
    assert {r["status"] for r in fit_many(paths, seed=2, out=out, fallback=False)} == {"fitted"}


@pytest.mark.slow
def test_cli_runs_the_batch_on_a_scheduler_and_resumes(client, tmp_path, capsys):
    """``bayescap fit *.csv --out DIR --scheduler ADDRESS``: the dashboard link on stderr, one
    result.json per CSV with the local run's numbers; rerun, nothing refitted. Without --out, or with
    --dask 0, exit 2 in one line. The runs on the scheduler and one refusal are fresh processes; the
    local run and the other refusal go through the CLI's main in this process."""
    from bayescap.cli import main
    from bayescap.io.ptc_csv import write_ptc_csv

    datas, _ = gpixel_sensors(n_max=3, seed=6)
    paths = [tmp_path / f"roi{i}.csv" for i in range(3)]
    for d, p in zip(datas, paths):
        write_ptc_csv(d, p)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))

    def run(*args):
        cmd = [sys.executable, "-m", "bayescap", "fit", *map(str, paths), "--quality", "fast", "--seed", "3", *args]
        return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)

    addr = client.scheduler.address
    r = run("--out", tmp_path / "d", "--scheduler", addr, "--json")
    assert r.returncode == 0, r.stderr
    assert "Dask dashboard: http" in r.stderr
    docs = json.loads(r.stdout)
    assert sorted(x.name for x in (tmp_path / "d").iterdir() if x.is_dir()) == ["roi0", "roi1", "roi2"]
    assert (tmp_path / "d" / "summary.csv").is_file()  # the batch's table, beside the sensors' folders
    assert json.loads((tmp_path / "d" / "roi1" / "result.json").read_text()) == docs[1]
    capsys.readouterr()
    args = ["fit", *map(str, paths), "--quality", "fast", "--seed", "3"]
    assert main([*args, "--out", str(tmp_path / "l"), "--json"]) == 0
    assert [_numbers(d) for d in json.loads(capsys.readouterr().out)] == [_numbers(d) for d in docs]
    r = run("--out", tmp_path / "d", "--scheduler", addr)
    assert r.returncode == 0 and "3 found done and not refitted" in r.stdout, r.stderr
    r = run("--out", tmp_path / "x", "--dask", "0")
    assert r.returncode == 2 and "--dask must be at least 1" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert main([*args, "--scheduler", addr]) == 2
    err = capsys.readouterr().err
    assert "give --out DIR" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x").exists()


def test_without_dask_one_line_names_the_extra(monkeypatch):
    from bayescap.batch.cluster import import_distributed
    from bayescap.exceptions import InputError

    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(InputError, match=r"pip install 'bayescap\[dask\]'"):
        import_distributed()


@pytest.mark.slow
def test_a_worker_killed_mid_run_and_the_batch_completes_every_result_once(client, sensors, tmp_path):
    """After the first chunk, the worker running a chunk is killed (os._exit): Dask runs its tasks
    again elsewhere; every sensor is fitted and written exactly once, with the numbers of a run
    without the kill."""
    out = tmp_path / "out"
    written, killed = [], []

    def kill_once(ix):
        written.extend(ix)
        if not killed:
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                killed.append(busy[0])
                try:
                    client.run(os._exit, 1, workers=busy[:1])
                except Exception:  # the worker's connection closes as it dies
                    pass

    report = fit_to_folder(sensors, seed=7, out=out, client=client, chunk_size=2, on_chunk=kill_once, fallback=False)
    assert killed
    assert Counter(written) == Counter(range(len(sensors)))
    assert [r["status"] for r in report] == ["fitted"] * len(sensors)
    ref = fit_many(sensors[:4], seed=7, fallback=False)
    for r, m in zip(report, ref):
        doc = json.loads((out / r["name"] / "result.json").read_text())
        assert _numbers({k: v for k, v in doc.items() if k != "batch"}) == _numbers(m.to_dict())


def test_workers_keep_freed_memory(client):
    """A Dask nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, under which every fit takes about
    1.5x as long; the cluster bayescap starts gives its workers the thresholds
    bayescap.retain_freed_memory sets in this process."""
    import os

    from bayescap.batch.cluster import WORKER_MALLOC_ENV

    for name, value in WORKER_MALLOC_ENV.items():
        assert set(client.run(os.environ.get, name).values()) == {value}, name


def test_workers_run_without_the_profiler(client):
    """The cluster bayescap starts leaves out the workers' statistical profiler and the 20 ms
    ticks (QUIET_CLUSTER): ~0.17 of a core on an idle 2-worker cluster; a worker restarted after the
    kill test above too."""
    import dask

    from bayescap.batch.cluster import QUIET_CLUSTER

    for key, value in QUIET_CLUSTER.items():
        assert set(client.run(dask.config.get, key).values()) == {value}, key
