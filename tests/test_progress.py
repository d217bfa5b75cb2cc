"""Progress bars: each counts up to a total fixed when it is made (it never goes back when the
MCMC adds a round), on stderr, and only when asked for (the CLI asks when stderr is a terminal)."""

from dataclasses import replace

import numpy as np

from bayescap import _progress
from bayescap.inference import QUALITY_PRESETS
from bayescap.inference import mcmc as inf_mcmc
from bayescap.io.ptc_csv import read_ptc_csv
from bayescap.model import PTCModel


class _Recorder:
    made = []

    def __init__(self, enabled, *, total, desc, unit="it", leave=False):
        self.enabled, self.total, self.desc, self.n, self.closed = enabled, total, desc, 0, False
        _Recorder.made.append(self)

    def update(self, n=1):
        self.n += n
        assert self.n <= self.total, f"{self.desc}: {self.n} of {self.total}"

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def test_sampling_bars_never_go_back(monkeypatch, basler_csv):
    """A run that needs more rounds gets a bar per round; before, the one bar's total grew after it
    had reached 100 %, so the bar went back."""
    _Recorder.made = []
    monkeypatch.setattr(inf_mcmc, "bar", _Recorder)
    model = PTCModel(read_ptc_csv(basler_csv))
    # never converges: 3 rounds. Short ones (the fast preset's adaptive sizing kept, at its cap of
    # 3 n + extend_steps: 12, 42 and 168 steps) after a short burn-in: the bars are checked, not the draws
    settings = replace(QUALITY_PRESETS["fast"], ess_target=1e12, max_rounds=3, n_burn=10, n_steps=12, extend_steps=6)
    inf_mcmc.run_ensembles(model, settings=settings, seed=3, progress=True, n_jobs=1)
    descs = [b.desc for b in _Recorder.made]
    assert descs == ["start: optimiser", "sampling, round 1", "sampling, round 2", "sampling, round 3"]
    for b in _Recorder.made:
        assert b.enabled and b.closed and b.n == b.total, (b.desc, b.n, b.total)


def test_no_bar_unless_asked(capsys):
    with _progress.bar(False, total=3, desc="x") as b:
        b.update(3)
    assert capsys.readouterr().err == ""
    with _progress.bar(True, total=3, desc="shown", leave=True) as b:
        b.update(3)
    err = capsys.readouterr().err
    assert "shown" in err and "3/3" in err
    assert np.isfinite(len(err))
