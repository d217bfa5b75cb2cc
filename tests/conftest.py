import contextlib
import json
import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"

if os.environ.get("PYTEST_XDIST_WORKER"):
    # Under ``pytest -n 2`` each of the two workers has one core: a fit's default fork pool of 2
    # processes (BAYESCAP_JOBS) and second log_prob thread (BAYESCAP_THREADS) only compete with the
    # other worker, and cost 8-20 % more CPU than the ensembles in lockstep on one thread (the same
    # numbers bit for bit: tests/test_fit.py checks the pool against lockstep). Tests that pass
    # n_jobs or set these variables themselves are unaffected; subprocesses inherit the setting.
    os.environ.setdefault("BAYESCAP_JOBS", "1")
    os.environ.setdefault("BAYESCAP_THREADS", "1")


#: under ``pytest -n``: the file in which a worker writes each test's xdist group for the controller
_GROUPS_FILE = "BAYESCAP_TEST_GROUPS_FILE"


def pytest_configure(config):
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        # bayescap byte-compiled once, as a regular (not editable) install does: with
        # PYTHONDONTWRITEBYTECODE set (as in some CI images and sandboxes) nothing else writes the
        # cache, and each xdist worker and each of the ~40 processes the tests start would compile
        # the sources again (~0.4 CPU-s a process); up to date, this only compares timestamps
        import compileall

        compileall.compile_dir(ROOT / "bayescap", quiet=1)
    if config.getoption("numprocesses", None) and not os.environ.get("PYTEST_XDIST_WORKER"):
        fd, path = tempfile.mkstemp(prefix="bayescap-test-groups-", suffix=".json")
        os.close(fd)
        os.environ[_GROUPS_FILE] = path  # the workers, started after this, inherit it
        config.add_cleanup(lambda: Path(path).unlink(missing_ok=True))


def _module_fixture_groups(items) -> dict:
    """nodeid -> group for the tests that share a module-scoped fixture (a fit, a simulated sensor):
    within a module, tests joined by a module fixture they both use (directly or through another
    fixture), transitively, form one group; a test that uses none is in no group."""
    parent = {}

    def find(x):
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    uses = {}
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        module = getattr(item, "module", None)
        if info is None or module is None:
            continue
        names = sorted(n for n, d in info.name2fixturedefs.items() if d and d[-1].scope == "module")
        if names:
            keys = [f"{module.__name__}:{n}" for n in names]
            uses[item.nodeid] = keys[0]
            for k in keys[1:]:
                parent[find(k)] = find(keys[0])
    return {nodeid: "module:" + find(key) for nodeid, key in uses.items()}


#: the scheduler's estimate of a test's cost, in units of a typical test's (~0.5 CPU-s): a test marked
#: slow (about 3 CPU-s or more) counts as SLOW_WEIGHT, and a module fixture (a fit, a simulated
#: sensor) adds FIXTURE_WEIGHT to the group of the tests that share it
SLOW_WEIGHT = 10
FIXTURE_WEIGHT = 5


def pytest_collection_modifyitems(config, items):
    """Under ``pytest -n 2`` (``--dist loadgroup`` in pyproject's addopts) the tests of one xdist group
    run on one worker: those marked ``xdist_group(name)``, and the tests of a module that share a
    module-scoped fixture (:func:`_module_fixture_groups`), so the fixture is built once rather than
    once per worker; the module's other tests are free. Each worker is handed the costliest group or
    test left (longest first: :data:`SLOW_WEIGHT`, :data:`FIXTURE_WEIGHT`), so that the short ones come
    last and neither worker is left running a long one alone at the end. (pytest-xdist's own
    loadgroup renames each test ``nodeid@group``, which pytest 9 no longer reads: its groups would be
    ignored. The groups and costs go to the controller in a file instead, and
    :func:`pytest_xdist_make_scheduler` schedules by them.)"""
    groups = _module_fixture_groups(items)
    for item in items:
        mark = item.get_closest_marker("xdist_group")
        if mark is not None:
            groups[item.nodeid] = "group:" + str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
    weights = {it.nodeid: SLOW_WEIGHT for it in items if it.get_closest_marker("slow")}
    path = os.environ.get(_GROUPS_FILE)
    if path and os.environ.get("PYTEST_XDIST_WORKER") == "gw0":  # every worker collects the same tests
        tmp = f"{path}.{os.getpid()}.tmp"
        Path(tmp).write_text(json.dumps({"groups": groups, "weights": weights}), encoding="utf-8")
        os.replace(tmp, path)


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: unknown without it
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup``: xdist's scope scheduler with the groups the workers wrote (a test without
    a group is a scope of its own), handing out the costliest scope left first; any other ``--dist``
    is xdist's own."""
    if config.getvalue("dist") != "loadgroup" or not os.environ.get(_GROUPS_FILE):
        return None
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        _groups = None
        _weights = None

        def _read(self):
            if self._groups is None:  # read once, when the workers have collected (schedule())
                text = Path(os.environ[_GROUPS_FILE]).read_text(encoding="utf-8")
                doc = json.loads(text) if text else {}
                self._groups, self._weights = doc.get("groups", {}), doc.get("weights", {})

        def _split_scope(self, nodeid):
            self._read()
            return self._groups.get(nodeid, nodeid)

        def _cost(self, scope):
            tests = self.workqueue[scope]
            fixture = FIXTURE_WEIGHT if scope.startswith("module:") else 0
            return fixture + sum(self._weights.get(nodeid, 1) for nodeid in tests)

        def _assign_work_unit(self, node):
            """The costliest scope left (the first of equals, in collection order) goes next."""
            self._read()
            best = max(self.workqueue, key=self._cost)
            self.workqueue.move_to_end(best, last=False)
            super()._assign_work_unit(node)

    return GroupScheduling(config, log)


@pytest.fixture(scope="session")
def basler_csv():
    return DATA / "emva1288_basler_ccd12.csv"


#: the README's quick-start fit: ``bayescap fit data/emva1288_basler_ccd12.csv --seed 1`` (from the
#: repository's root, or a folder with the same ``data``)
BASLER_README_ARGS = ["fit", "data/emva1288_basler_ccd12.csv", "--seed", "1"]

#: the bundled simulated phone sensor's table (tests/test_results.py, tests/test_golden.py)
PHONE_CSV = "data/simulated/sim_phone_1p75um_10bit.csv"


def _seed1_kwargs(quality):
    """The keyword arguments with which ``bayescap fit CSV --seed 1 [--quality QUALITY]`` calls
    :func:`bayescap.api.fit` (bayescap/cli/fit.py: no --scene, --mtf, --fast-tolerance; progress off
    when the output is not a terminal or with --no-progress)."""
    return {"seed": 1, "quality": quality, "scene": None, "progress": False, "mtf": None, "fast_settings": None}


def _fit_seed1(relpath, quality="standard"):
    """The call ``bayescap fit RELPATH --seed 1 --quality QUALITY`` makes from the repository's root:
    the table read by :func:`bayescap.api.load` from that relative path (its ``source``, printed and
    in the JSON, is that path), then :func:`bayescap.api.fit` with :func:`_seed1_kwargs`."""
    from bayescap.api import fit, load

    with contextlib.chdir(ROOT):
        data = load(relpath)
    return fit(data, **_seed1_kwargs(quality))


def _same_table(a, b) -> bool:
    """Two PTCData equal field by field (arrays element by element, NaN equal to NaN)."""
    import dataclasses

    import numpy as np

    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if x is None or y is None or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
                return False
        elif x != y:
            return False
    return True


@contextlib.contextmanager
def cli_fit_from(result):
    """Within it, :func:`bayescap.api.fit` (the function ``bayescap fit`` calls) returns ``result``,
    a session fixture's fit (:func:`basler_standard_fit`, :func:`phone_standard_fit`,
    :func:`basler_fast_fit`), when it is called exactly as :func:`_fit_seed1` called it for that
    fixture: the same table (field by field, ``source`` included) and the same keyword arguments.
    ``bayescap.cli.main(["fit", RELPATH, "--seed", "1", "--quality", QUALITY, ...])`` then parses,
    reads the CSV, calls the fit and prints the result as the command does, without fitting the same
    table and seed a second time. Any other call of the fit fails the test (the command no longer
    makes the call the fixture made). Yields the calls seen."""
    import bayescap.api

    calls = []
    expected = _seed1_kwargs(result.diag["quality"])

    def fit(data, **kw):
        calls.append(kw)
        assert kw == expected, f"bayescap fit called the fit with {kw}, not {expected}"
        assert _same_table(data, result.model.data), "bayescap fit read another table than the fixture's"
        return result

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bayescap.api, "fit", fit)
        yield calls


def _session_fit(tmp_path_factory, name, relpath, quality="standard"):
    """:func:`_fit_seed1` of ``relpath``, once per test run. Under ``pytest -n`` the first
    worker to ask fits it and pickles it beside the workers' temporary folders; the other waits for
    the pickle (a lock) and loads it (tests/test_results.py checks that a result pickles and comes
    back the same)."""
    import fcntl
    import pickle

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # this run's folder, shared by its workers
    path = root / f"{name}.pickle"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if path.exists():
            return pickle.loads(path.read_bytes())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = _fit_seed1(relpath, quality)
        tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
        tmp.write_bytes(pickle.dumps(result))
        os.replace(tmp, path)
        return result


@pytest.fixture(scope="session")
def basler_standard_fit(tmp_path_factory):
    """The README's and the docs' fit, ``bayescap fit data/emva1288_basler_ccd12.csv --seed 1``
    (:data:`BASLER_README_ARGS`; :func:`_fit_seed1`), once per test run (:func:`_session_fit`).
    tests/test_golden.py compares its JSON with the golden file of that command, and the README's
    tests print it through the command's own code (:func:`cli_fit_from`). Read-only: a test that
    changes it copies it first."""
    return _session_fit(tmp_path_factory, "basler_standard_seed1", BASLER_README_ARGS[1])


@pytest.fixture(scope="session")
def phone_standard_fit(tmp_path_factory):
    """``bayescap fit data/simulated/sim_phone_1p75um_10bit.csv --seed 1`` (:func:`_fit_seed1`),
    once per test run: tests/test_results.py's standard result and tests/test_golden.py's
    fit_phone_standard (through :func:`cli_fit_from`). Read-only: a test that changes it copies it first."""
    return _session_fit(tmp_path_factory, "phone_standard_seed1", PHONE_CSV)


@pytest.fixture(scope="session")
def basler_fast_fit(tmp_path_factory):
    """``bayescap fit data/emva1288_basler_ccd12.csv --seed 1 --quality fast`` (:func:`_fit_seed1`),
    once per test run: tests/test_emva.py, tests/test_emva_gain.py, tests/test_datasheet_page.py, tests/test_cli_strict.py and tests/test_golden.py's
    fit_basler_fast (through :func:`cli_fit_from`). Read-only: a test that changes it copies it first."""
    return _session_fit(tmp_path_factory, "basler_fast_seed1", BASLER_README_ARGS[1], "fast")


def standard_recipe_gain(result):
    """EMVA 1288's gain recipe (Δσ² against Δμ through the origin, unweighted, over the rows up to
    70 % of the signal of the largest temporal variance) applied to the model's variances at the
    posterior median of ``result``: the K the standard would read off the fitted model. With a
    non-linear response the model's own K is the small-signal gain, which this averages."""
    import numpy as np

    m = result.model
    x = result.chains.chain
    th = np.median(x.reshape(-1, x.shape[-1]), axis=0)[None]
    pred = m.predict(th)
    sig = m.s_obs
    v = pred["bright_var"][1][0] - pred["dark_var"][1][0][~m.full_sat]
    rows = sig <= 0.7 * sig[np.argmax(m.v)]
    return float(np.sum(sig[rows] ** 2) / np.sum(sig[rows] * v[rows]))


@pytest.fixture(autouse=True)
def _quiet_arviz():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning)
        yield


@pytest.fixture
def python3_kernel(tmp_path, monkeypatch):
    """A "python3" kernelspec pointing at this interpreter, first on a temporary JUPYTER_PATH, so
    notebooks execute in a fresh venv after ``pip install -e .[test]`` without activating it (the
    stock kernelspec runs whatever ``python`` is on PATH)."""
    spec_dir = tmp_path / "kernels" / "python3"
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(
        json.dumps(
            {
                "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                "display_name": "Python 3 (bayescap test)",
                "language": "python",
            }
        )
    )
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    return "python3"


def python_stdout(code, timeout=120):
    """What ``python -c code`` prints in a fresh interpreter (a new process's imports: what a user's
    command loads), after checking that it exits 0."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr
    return out.stdout
