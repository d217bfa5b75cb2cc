"""Command-line habits (issue 49): ``fit -`` reads standard input, ``--quiet`` prints only what was
asked for, every progress option has help text, and ``datasheet`` and ``report`` show progress."""

import subprocess
import sys
from pathlib import Path

import pytest
from conftest import python_stdout

from bayescap import _progress
from bayescap.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "data/benchmark/M1_1.75um.csv"


def _run(args, stdin=None):
    return subprocess.run(
        [sys.executable, "-m", "bayescap", *args],
        input=stdin,
        capture_output=True,
        cwd=ROOT,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "MPLBACKEND": "Agg", "OMP_NUM_THREADS": "1"},
        timeout=300,
    )


def test_fit_dash_reads_standard_input(capsys):
    piped = _run(["fit", "-", "--quality", "fast", "--seed", "1", "--json"], stdin=SMALL.read_bytes())
    assert piped.returncode == 0, piped.stderr.decode()[-2000:]
    assert main(["fit", str(SMALL), "--quality", "fast", "--seed", "1", "--json"]) == 0  # the file, in this process
    import json

    a, b = json.loads(piped.stdout), json.loads(capsys.readouterr().out)
    assert a["input"] == "<stdin>"
    assert a["parameters"] == b["parameters"] and a["derived"] == b["derived"]


def test_fit_dash_bad_input_names_stdin_in_one_line():
    proc = _run(["fit", "-", "--quality", "fast"], stdin=b"exposure_time_s,mean_dn\n0.1,abc\n")
    err = proc.stderr.decode()
    assert proc.returncode == 2 and "<stdin>" in err and "Traceback" not in err and err.count("\n") == 1, err


def test_fit_dash_twice_is_refused(capsys):
    assert main(["fit", "-", "-", "--quality", "fast"]) == 2
    assert "standard input" in capsys.readouterr().err


def _help_of(parser, command):
    sub = next(a for a in parser._actions if a.dest == "command")
    return sub.choices[command]


@pytest.mark.parametrize("command", ["fit", "datasheet", "report", "compare"])
def test_progress_and_quiet_options_have_help(command):
    p = _help_of(build_parser(), command)
    opts = {o: a for a in p._actions for o in a.option_strings}
    for o in ("--progress", "--no-progress", "--quiet", "-q"):
        assert o in opts and opts[o].help, (command, o)


@pytest.mark.slow
def test_quiet_fit_with_out_prints_nothing(tmp_path, capsys):
    assert main(["fit", str(SMALL), "--quality", "fast", "--seed", "1", "--out", str(tmp_path / "o"), "-q"]) == 0
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err == ""
    assert (tmp_path / "o" / "report.txt").read_text().startswith("bayescap")


class _Recorder:
    made = []

    def __init__(self, enabled, *, total, desc, unit="it", leave=False):
        self.enabled, self.total, self.desc, self.n = enabled, total, desc, 0
        _Recorder.made.append(self)

    def update(self, n=1):
        self.n += n

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.parametrize("command", ["datasheet", "report"])
@pytest.mark.slow
def test_datasheet_and_report_show_progress(command, tmp_path, monkeypatch, capsys):
    """With ``--progress`` the fit is asked for its bars and a bar for writing the page is made,
    enabled, and reaches its total; with ``--quiet`` no bar is enabled, the fit is asked for none,
    and nothing but errors is printed."""
    import bayescap.api
    from bayescap.studies import compare as compare_mod

    asked, fitted = [], []
    real_fit = bayescap.api.fit

    def fit(*a, **kw):
        """The real fit once; the second run (``--quiet``) gets the same result: what it is asked
        for is recorded, and the page is written again from it."""
        asked.append(kw.get("progress"))
        if not fitted:
            fitted.append(real_fit(*a, **kw))
        return fitted[0]

    monkeypatch.setattr(bayescap.api, "fit", fit)
    for mod in (_progress, compare_mod):  # (the report command imports bar from _progress when it runs)
        monkeypatch.setattr(mod, "bar", _Recorder)
    out = tmp_path / "page.html"
    args = [command, str(SMALL), "-o", str(out), "--quality", "fast", "--seed", "1"]
    _Recorder.made = []
    assert main([*args, "--progress"]) == 0
    shown = [b for b in _Recorder.made if b.enabled]
    assert any(b.desc.startswith(command) and b.n == b.total for b in shown), [b.desc for b in _Recorder.made]
    assert asked == [True]
    capsys.readouterr()
    _Recorder.made, asked[:] = [], []
    assert main([*args, "--quiet"]) == 0
    assert _Recorder.made and not any(b.enabled for b in _Recorder.made) and asked == [False]
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err == ""


def test_help_pages_print_percent_signs_once(capsys):
    """argparse %-formats help strings but not descriptions: a description written with '%%' printed
    it doubled ('68 %% and 95 %%')."""
    import pytest

    from bayescap.cli import main

    for cmd in ("fit", "datasheet", "ingest", "mtf", "compare", "report", "sweep", "colour", "summary"):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        assert "%%" not in capsys.readouterr().out, cmd


def test_a_command_imports_only_its_own_module():
    """``bayescap fit ...`` builds only the fit command's parser (build_parser("fit")): the other
    commands' modules (frame readers, the sweep's optics, the colour fit) are not imported, and the
    arguments parse as with the whole parser."""
    code = (
        "import sys\n"
        "from bayescap.cli import build_parser\n"
        "argv = ['fit', 'a.csv', '--json', '--seed', '3', '--quality', 'fast']\n"
        "one = vars(build_parser('fit').parse_args(argv))\n"
        "print(sorted(m for m in sys.modules if m.startswith('bayescap.cli.')))\n"
        "every = vars(build_parser().parse_args(argv))\n"
        "print(one == every)\n"
    )
    stdout = python_stdout(code)
    assert stdout.splitlines() == ["['bayescap.cli.common', 'bayescap.cli.fit']", "True"]
