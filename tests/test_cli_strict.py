"""``--strict`` on every command that fits (``fit``, ``report``, ``datasheet``): the outputs are
written, then exit status 3 when a result is not converged; without ``--strict`` status 0 (the
output says NOT CONVERGED). The fit is the Basler CCD's fast one (fitted once), marked converged or not."""

from __future__ import annotations

import copy

import pytest

import bayescap.api
from bayescap.cli import main
from bayescap.cli.common import EXIT_NOT_CONVERGED


@pytest.fixture(scope="module")
def basler_fast(basler_fast_fit):
    """``bayescap.api.fit`` of the Basler table at seed 1, fast: the session's (tests/conftest.py),
    never changed here (:func:`_fit_returns` marks a copy)."""
    return basler_fast_fit


def _fit_returns(monkeypatch, result, converged):
    """bayescap.api.fit returns ``result`` (fitted once for the module), marked converged or not."""
    r = copy.copy(result)
    r.diag = {**result.diag, "converged": converged}
    monkeypatch.setattr(bayescap.api, "fit", lambda *a, **k: r)


def _stub_report(monkeypatch):
    """The HTML report's figures take ~15 s: the exit status does not depend on them (the report
    command imports write_report from bayescap.report.html when it runs)."""
    import bayescap.report.html as report_html

    def write_report(cmp, path, title="", **kw):
        open(path, "w").write(f"<html>{len(cmp.sensors)} sensors</html>")
        return path

    monkeypatch.setattr(report_html, "write_report", write_report)


def test_report_strict(basler_csv, basler_fast, tmp_path, capsys, monkeypatch):
    _stub_report(monkeypatch)
    out = tmp_path / "r.html"
    argv = ["report", str(basler_csv), "--quality", "fast", "-o", str(out)]
    _fit_returns(monkeypatch, basler_fast, converged=False)
    assert main(argv) == 0  # the report says NOT CONVERGED; the status does not without --strict
    out.unlink()
    capsys.readouterr()
    assert main(argv + ["--strict"]) == EXIT_NOT_CONVERGED == 3
    assert out.exists()  # written first
    assert "1 of 1 result(s) NOT CONVERGED (--strict)" in capsys.readouterr().err
    _fit_returns(monkeypatch, basler_fast, converged=True)
    assert main(argv + ["--strict"]) == 0


def test_datasheet_strict(basler_csv, basler_fast, tmp_path, capsys, monkeypatch):
    out = tmp_path / "d.html"
    argv = ["datasheet", str(basler_csv), "--quality", "fast", "-o", str(out), "--strict"]
    _fit_returns(monkeypatch, basler_fast, converged=False)
    assert main(argv) == 3
    assert "NOT CONVERGED" in out.read_text()  # written first, and it says so
    assert "NOT CONVERGED (--strict)" in capsys.readouterr().err
    import bayescap.report.datasheet as ds

    monkeypatch.setattr(ds, "datasheet_html", lambda result, **k: "<html></html>")
    assert main(argv[:-1]) == 0
    _fit_returns(monkeypatch, basler_fast, converged=True)
    assert main(argv) == 0


def test_help_of_report_and_datasheet_documents_strict(capsys):
    for cmd in ("report", "datasheet"):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        out = capsys.readouterr().out
        assert "--strict" in out and "3  --strict and a result not converged" in out, cmd


def test_datasheet_pdf(basler_csv, basler_fast, tmp_path, capsys, monkeypatch):
    """``-o NAME.pdf`` writes a one-page PDF (matplotlib's PDF backend, no pyplot, no backend
    switch) atomically: a valid PDF, one page, no temporary file left; a '$' in the name is no
    math text. ``--pdf`` beside the HTML is refused onto the input before any fitting."""
    import re

    import matplotlib

    _fit_returns(monkeypatch, basler_fast, converged=True)
    backend = matplotlib.get_backend()
    out = tmp_path / "sheet $5.pdf"
    assert main(["datasheet", str(basler_csv), "-o", str(out), "--strict"]) == 0
    data = out.read_bytes()
    assert data.startswith(b"%PDF-") and data.rstrip().endswith(b"%%EOF")
    assert len(re.findall(rb"/Type\s*/Page\b", data)) == 1
    assert re.search(rb"/Type\s*/Pages\b.*?/Count\s+1\b", data, flags=re.S)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sheet $5.pdf"]
    assert matplotlib.get_backend() == backend
    capsys.readouterr()
    assert main(["datasheet", str(basler_csv), "-o", str(tmp_path / "d.html"), "--pdf", str(basler_csv)]) == 2
    assert "would overwrite an input" in capsys.readouterr().err
