"""Golden outputs: the bundled sensors' fit, batch and comparison JSON with fixed seeds.

A refactor must leave these bit for bit unchanged (wall-clock times aside). A deliberate
change of the numbers regenerates them, in its own commit that says why:

    python tests/test_golden.py --regenerate
"""

import contextlib
import io
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = Path(__file__).resolve().parent / "data" / "golden"

SENSORS = {
    "basler": "data/emva1288_basler_ccd12.csv",
    "industrial": "data/simulated/sim_industrial_3p45um_12bit.csv",
    "phone": "data/simulated/sim_phone_1p75um_10bit.csv",
    "scientific": "data/simulated/sim_scientific_6p5um_16bit_unsaturated.csv",
    "M1_1.75um": "data/benchmark/M1_1.75um.csv",
    "M2_2.80um": "data/benchmark/M2_2.80um.csv",
}
BENCHMARK = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "data" / "benchmark").glob("M*.csv"))

CASES = {
    **{
        f"fit_{name}_{q}": ["fit", path, "--seed", "1", "--quality", q, "--json"]
        for name, path in SENSORS.items()
        for q in ("standard", "fast")
    },
    "fit_batch_benchmark_fast": ["fit", *BENCHMARK, "--seed", "3", "--quality", "fast", "--json"],
    "compare_benchmark_fast": ["compare", *BENCHMARK, "--seed", "2", "--json"],
}

TIMING_KEYS = {"wall_s", "fast_path_wall_s"}


def _strip_timings(obj):
    if isinstance(obj, dict):
        return {k: _strip_timings(v) for k, v in obj.items() if k not in TIMING_KEYS}
    if isinstance(obj, list):
        return [_strip_timings(v) for v in obj]
    return obj


def run_case(args):
    from bayescap.cli import main

    out = io.StringIO()
    with contextlib.chdir(ROOT), contextlib.redirect_stdout(out):
        status = main(list(args) + ["--no-progress"] if args[0] == "fit" else list(args))
    assert status in (0, None), f"bayescap {' '.join(args)} exited {status}"
    return _strip_timings(json.loads(out.getvalue()))


#: the cases whose fit is a session fixture of tests/conftest.py that other tests share: the fixture
#: makes the call this command makes (the table loaded from the same relative path, the command's
#: keyword arguments). The command runs here through the CLI as the
#: other cases do, its fit call checked to be the fixture's and answered by the fixture's result
#: (conftest.cli_fit_from), so each of these seed-1 fits runs once per test run.
FROM_FIXTURE = {
    "fit_basler_standard": "basler_standard_fit",
    "fit_phone_standard": "phone_standard_fit",
    "fit_basler_fast": "basler_fast_fit",
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_golden(case, request):
    expected = json.loads((GOLDEN / f"{case}.json").read_text())
    if case not in FROM_FIXTURE:
        assert run_case(CASES[case]) == expected
        return
    from conftest import cli_fit_from

    assert CASES[case][2:5] == ["--seed", "1", "--quality"] and CASES[case][6:] == ["--json"]
    with cli_fit_from(request.getfixturevalue(FROM_FIXTURE[case])) as calls:
        got = run_case(CASES[case])
    assert len(calls) == 1
    assert got == expected


if __name__ == "__main__":
    if sys.argv[1:] != ["--regenerate"]:
        sys.exit(__doc__)
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name, args in sorted(CASES.items()):
        (GOLDEN / f"{name}.json").write_text(json.dumps(run_case(args), indent=1, sort_keys=True) + "\n")
        print("wrote", name)
