"""What a command imports: each module below costs a user's every process its import time (issue 50;
benchmarks/results/process_stages.md), so a command loads only what it uses. Pinned here so that an
eager import added somewhere cannot slow every fit silently."""

from pathlib import Path

from conftest import python_stdout

ROOT = Path(__file__).resolve().parents[1]

#: never needed by ``fit --json --no-progress``: plotting, the InferenceData and NetCDF outputs (and
#: h5py, which emcee's HDF5 backend would import), progress bars, the tables libraries, the scipy sub-packages the fit does
#: without (scipy.stats, ~1 s, comes with emcee's KDE move; scipy.optimize: the start is a Newton
#: iteration of its own)
NEVER_IN_A_FIT = (
    "matplotlib",
    "corner",
    "arviz",
    "xarray",
    "h5netcdf",
    "h5py",
    "tqdm",
    "pandas",
    "dask",
    "scipy.stats",
    "scipy.optimize",
    "bayescap.report.plots",
    "bayescap.report.html",
    "bayescap.posterior.storage",
    "bayescap.posterior.inference_data",
)

_SNAPSHOT = "def loaded(names):\n    return sorted(n for n in names if n in sys.modules)\n"


def test_import_bayescap_and_version_are_light():
    """``import bayescap`` loads neither numpy nor ctypes (nor subprocess, which ctypes.util's
    library search imports); ``bayescap --version`` loads no numpy either."""
    code = (
        "import sys\n" + _SNAPSHOT + "import bayescap\n"
        "heavy = ('numpy', 'scipy', 'ctypes', 'subprocess', 'bayescap.api', 'bayescap.cli')\n"
        "print(loaded(heavy))\n"
        "from bayescap.cli import main\n"
        "try:\n"
        "    status = main(['--version'])\n"
        "except SystemExit as e:\n"
        "    status = e.code\n"
        "print(status or 0)\n"
        "print(loaded(('numpy', 'scipy', 'bayescap.api', 'bayescap.cli.fit')))\n"
    )
    lines = python_stdout(code).splitlines()
    assert lines[0] == "[]"
    assert lines[1].startswith("bayescap ") and lines[2] == "0"  # the version printed, exit status 0
    assert lines[3] == "[]"


def test_fit_json_imports_only_what_it_uses():
    """``bayescap fit CSV --json`` in a fresh interpreter: at ``fast`` (an accepted Laplace–IS fit)
    no emcee and none of NEVER_IN_A_FIT; at ``standard`` emcee (the MCMC) and still none of them."""
    fast_csv = ROOT / "data" / "simulated" / "sim_industrial_3p45um_12bit.csv"
    std_csv = ROOT / "data" / "simulated" / "sim_scientific_6p5um_16bit_unsaturated.csv"
    code = (
        "import contextlib, io, json, sys\n" + _SNAPSHOT + f"never = {NEVER_IN_A_FIT!r}\n"
        "from bayescap.cli import main\n"
        "def fit(csv, quality):\n"
        "    out = io.StringIO()\n"
        "    with contextlib.redirect_stdout(out):\n"
        "        status = main(['fit', csv, '--quality', quality, '--json', '--seed', '1', '--no-progress'])\n"
        "    return status, json.loads(out.getvalue())['diagnostics']['method']\n"
        f"print(*fit({str(fast_csv)!r}, 'fast'))\n"
        "print(loaded(never + ('emcee',)))\n"
        f"print(*fit({str(std_csv)!r}, 'standard'))\n"
        "print(loaded(never + ('emcee',)))\n"
    )
    lines = python_stdout(code, timeout=300).splitlines()
    assert lines == ["0 laplace-is", "[]", "0 emcee", "['emcee']"]


def test_emcee_whole_after_bayescap_imports_it(tmp_path):
    """bayescap imports emcee without h5py and tqdm (bayescap.inference.moves._import_emcee), and
    emcee stays whole: its HDF5 backend imports h5py when it opens its file and stores the chain,
    and its progress bar imports tqdm when shown."""
    code = (
        "import sys, numpy as np\n"
        "import bayescap.inference.moves\n"
        "print([m for m in ('h5py', 'tqdm') if m in sys.modules])\n"
        "import emcee\n"
        f"backend = emcee.backends.HDFBackend({str(tmp_path / 'chain.h5')!r})\n"
        "s = emcee.EnsembleSampler(8, 2, lambda x: -0.5 * np.sum(x**2), backend=backend)\n"
        "s.run_mcmc(np.random.default_rng(0).standard_normal((8, 2)), 10, progress=True)\n"
        "print([m for m in ('h5py', 'tqdm') if m in sys.modules], backend.iteration, backend.get_chain().shape)\n"
    )
    assert python_stdout(code).splitlines() == ["[]", "['h5py', 'tqdm'] 10 (10, 8, 2)"]
