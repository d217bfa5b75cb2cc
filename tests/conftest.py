import json
import os
import sys
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


def pytest_collection_modifyitems(config, items):
    """Under ``pytest -n 2`` (pytest-xdist, ``--dist loadgroup`` in pyproject's addopts) a module whose
    tests share a module-scoped fixture (a fit, a simulated sensor) runs on one worker, as one group,
    so the fixture is built once rather than once per worker. The other tests are handed out one by
    one (xdist sends the largest groups first, then the rest in order). A test that already names its
    xdist_group keeps it."""
    shared = set()
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs if info is not None else {}
        if any(d and d[-1].scope == "module" for d in defs.values()):
            shared.add(item.module.__name__)
    for item in items:
        module = getattr(item, "module", None)
        if module is not None and module.__name__ in shared and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(module.__name__))
    # the long tests outside a group (marked slow) are handed out first, so that neither worker is left
    # running one alone at the end; they use no module fixture, so moving them sets up nothing twice
    items.sort(key=lambda it: not (it.get_closest_marker("slow") and not it.get_closest_marker("xdist_group")))


@pytest.fixture(scope="session")
def basler_csv():
    return DATA / "emva1288_basler_ccd12.csv"


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
