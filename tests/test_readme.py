"""README.md's examples run as written: every ```python block, and every ``bayescap ...`` command
of the ```bash blocks, in a temporary folder where the repository's ``data/`` is reachable under
the same relative path.

Shell commands that are not ``bayescap`` (the quick start's venv set-up and test run, the lint
commands) are listed in :data:`NOT_RUN` with the reason; a new one in the README fails
:func:`test_every_bash_command_is_accounted_for` until it is run here or listed.
"""

from __future__ import annotations

import glob
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

#: shell commands of the README's bash blocks that this test does not run, and why
NOT_RUN = {
    "python3 -m venv .venv": "quick start: sets up the environment these tests run in (.ci/run)",
    '.venv/bin/pip install -q -e ".[test]"': "quick start: sets up the environment these tests run in (.ci/run)",
    ".venv/bin/python -m pytest -n 2": "quick start: runs this test suite",
    "ruff check .": "run by tests/test_lint.py",
    "ruff format --check .": "run by tests/test_lint.py",
    "lint-imports": "run by tests/test_lint.py",
    "pre-commit install": "installs a git hook into the clone",
}

#: python blocks that fail today for a known bug: block index -> reason (strict xfail: the test
#: fails once the bug is fixed, so the entry must then go)
KNOWN_BROKEN: dict[int, str] = {}


class PicklingCrash(Exception):
    """The README block died of the fit_many(n_jobs=2) pickling bug."""


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.M | re.S)


def _bash_commands() -> list[str]:
    """Each command of the bash blocks: lines split at ``&&``, comments dropped."""
    out = []
    for block in _blocks("bash"):
        for line in block.splitlines():
            line = line.split(" #", 1)[0].strip()
            out += [c.strip() for c in line.split("&&") if c.strip()]
    return out


def _is_bayescap(cmd: str) -> bool:
    return shlex.split(cmd)[0].rsplit("/", 1)[-1] == "bayescap"


BAYESCAP_COMMANDS = [c for c in _bash_commands() if _is_bayescap(c)]
PYTHON_BLOCKS = _blocks("python")


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.setdefault("MPLBACKEND", "Agg")
    return env


@pytest.fixture
def workdir(tmp_path):
    (tmp_path / "data").symlink_to(ROOT / "data", target_is_directory=True)
    return tmp_path


#: (args) -> the finished process: the README's ``bayescap fit data/emva1288_basler_ccd12.csv --seed 1``
#: is both a command of its quick start and the command whose output it shows, run once for both tests
#: (they share an xdist group, so one worker runs them). Only runs whose arguments name no file the
#: command writes are shared: each reads ``data/`` by the same relative path from its working folder.
_RUNS: dict[tuple[str, ...], subprocess.CompletedProcess] = {}


def _run_bayescap(args: list[str], workdir: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "bayescap", *args], cwd=workdir, env=_env(), capture_output=True, text=True, timeout=300
    )


def _main_in_process(args: list[str], workdir: Path) -> subprocess.CompletedProcess:
    """``bayescap ARGS`` through the console script's entry point (``bayescap.cli.main``) in this
    process, from ``workdir``: its exit status and printed output, without a fresh interpreter's
    imports. (.ci/run runs the quick start's fit as a real command before the tests.)"""
    import contextlib
    import io

    from bayescap.cli import main

    out, err, here = io.StringIO(), io.StringIO(), os.getcwd()
    os.chdir(workdir)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(args)
            except SystemExit as e:  # argparse's usage errors
                code = e.code
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(args, code or 0, out.getvalue(), err.getvalue())


def _bayescap(args: list[str], workdir: Path, request) -> subprocess.CompletedProcess:
    """``bayescap ARGS`` (a fit that writes no file) in this process, once per argument list in this
    session (the shared fit). The quick start's Basler fit (conftest.BASLER_README_ARGS) is the
    session fixture ``basler_standard_fit``: the command runs (arguments, reading the CSV from the
    working folder, printing), its fit call checked to be the fixture's and answered by its result
    (conftest.cli_fit_from); tests/test_golden.py holds that fit's numbers to the golden file."""
    from conftest import BASLER_README_ARGS, cli_fit_from

    key = tuple(args)
    if key not in _RUNS:
        if args == BASLER_README_ARGS:
            with cli_fit_from(request.getfixturevalue("basler_standard_fit")) as calls:
                _RUNS[key] = _main_in_process(args, workdir)
            assert len(calls) == 1, calls
        else:
            _RUNS[key] = _main_in_process(args, workdir)
    return _RUNS[key]


def _shared_fit(args: list[str]) -> bool:
    """A ``fit`` whose output is only printed (no --out, -o, --save, --json file), so sharing it is safe."""
    return args[:1] == ["fit"] and not any(a.startswith(("-o", "--out", "--save")) for a in args)


def test_readme_has_examples():
    assert PYTHON_BLOCKS and BAYESCAP_COMMANDS


def test_every_bash_command_is_accounted_for():
    unknown = [c for c in _bash_commands() if not _is_bayescap(c) and c not in NOT_RUN]
    assert unknown == [], f"README bash commands neither run by tests/test_readme.py nor listed in NOT_RUN: {unknown}"


#: the one line .ci/run adds to the README's two commands: the browser the HTML test opens
CI_BROWSER_INSTALL = (
    "(command -v chromium || apt-get install -y -qq chromium || { apt-get update -qq; apt-get install -y -qq chromium; } "
    "|| true) >/dev/null 2>&1"
)


def test_ci_runs_the_readme_commands_and_the_test_command_installs_nothing():
    """The README's test command is pytest and nothing else (no system package installed as a side
    effect); .ci/run runs the README's two quick-start commands verbatim, plus the browser install
    before them."""
    quick = [b.strip() for b in _blocks("bash")[:2]]
    assert quick[1] == ".venv/bin/python -m pytest -n 2", quick[1]
    assert "apt-get" not in quick[0] + quick[1]
    lines = [
        ln.strip()
        for ln in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    steps = [ln for ln in lines if not ln.startswith(("set -", "cd "))]
    assert steps == [quick[0], CI_BROWSER_INSTALL, quick[1]], steps


@pytest.mark.xdist_group("readme_fit")  # with the output test: the shared Basler fit runs once
@pytest.mark.parametrize("cmd", BAYESCAP_COMMANDS)
def test_readme_command(cmd, workdir, request):
    argv = shlex.split(cmd)
    # the shell's glob expansion (data/benchmark/M*.csv), in the working folder
    args = [x for a in argv[1:] for x in (sorted(glob.glob(a, root_dir=workdir)) if "*" in a else [a])]
    # the quick start's .venv/bin/bayescap is this interpreter's bayescap
    proc = _bayescap(args, workdir, request) if _shared_fit(args) else _run_bayescap(args, workdir)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    if argv[1] == "fit" and "--json" not in argv:
        # the parameters the README's abridged output lists
        for name in ("conversion_gain_e_per_dn", "read_noise_e", "full_well_e", "capacity C ="):
            assert name in proc.stdout, name


@pytest.mark.slow  # the quick start's standard fit, fit_many in two processes, save, the EMVA view
@pytest.mark.parametrize(
    "i",
    [
        pytest.param(i, marks=pytest.mark.xfail(strict=True, raises=PicklingCrash, reason=KNOWN_BROKEN[i]))
        if i in KNOWN_BROKEN
        else i
        for i in range(len(PYTHON_BLOCKS))
    ],
)
def test_readme_python_block(i, workdir):
    script = workdir / f"readme_block_{i}.py"
    script.write_text(PYTHON_BLOCKS[i], encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, script.name], cwd=workdir, env=_env(), capture_output=True, text=True, timeout=300
    )
    if proc.returncode != 0 and "Can't pickle local object" in proc.stderr:
        raise PicklingCrash(proc.stderr[-1500:])
    assert proc.returncode == 0, proc.stderr[-3000:]


def _output_blocks() -> list[tuple[str, list[str]]]:
    """The README's printed outputs of ``bayescap fit CSV --seed 1``: plain blocks whose first line
    is the header a fit prints (``bayescap <version>: <csv>  (...)``), as (csv, lines)."""
    out, block, lang = [], None, None
    for line in README.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            if block is None:
                block, lang = [], line[3:].strip()
                continue
            m = re.match(r"bayescap \S+: (\S+\.csv)  \(", block[0]) if block and not lang else None
            if m:
                out.append((m.group(1), block))
            block = None
        elif block is not None:
            block.append(line)
    return out


@pytest.mark.xdist_group("readme_fit")
@pytest.mark.parametrize("csv, lines", _output_blocks(), ids=[c for c, _ in _output_blocks()])
def test_readme_output_is_what_the_fit_prints(csv, lines, workdir, request):
    """Every line of an abridged output in the README is a line the command prints now (``...``
    marks lines left out, ``…`` a part that changes from run to run: the time), so the README's
    numbers are the program's."""
    proc = _bayescap(["fit", csv, "--seed", "1"], workdir, request)
    assert proc.returncode == 0, proc.stderr[-2000:]
    printed = [line.rstrip() for line in proc.stdout.splitlines()]
    for line in lines:
        if line.strip() == "...":
            continue
        pattern = ".*".join(re.escape(part) for part in line.rstrip().split("…"))
        assert any(re.fullmatch(pattern, p) for p in printed), f"README line not printed by the fit: {line!r}"
