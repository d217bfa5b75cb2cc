"""BLAS thread pools are held to one thread inside the sampling entry points (bayescap/_blas.py)."""

import pytest

import bayescap

threadpoolctl = pytest.importorskip("threadpoolctl")

from bayescap._blas import one_blas_thread  # noqa: E402
from bayescap.model.ptc_model import PTCModel  # noqa: E402


def _blas_threads():
    return {p["filepath"]: p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"}


def test_one_blas_thread_inside_and_restored_after():
    if not _blas_threads():
        pytest.skip("threadpoolctl finds no BLAS library")
    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        before = _blas_threads()
        seen = one_blas_thread(_blas_threads)()
        assert set(seen.values()) == {1}
        assert _blas_threads() == before


def test_fast_posterior_runs_with_one_blas_thread(monkeypatch, basler_csv):
    if not _blas_threads():
        pytest.skip("threadpoolctl finds no BLAS library")
    seen = []
    orig = PTCModel.log_prob

    def spy(self, X):
        seen.append(set(_blas_threads().values()))
        return orig(self, X)

    monkeypatch.setattr(PTCModel, "log_prob", spy)
    with threadpoolctl.threadpool_limits(2, user_api="blas"):
        r = bayescap.fit(basler_csv, seed=1, quality="fast")  # the fast path as a fit runs it
    assert r.to_dict()["diagnostics"]["method"] == "laplace-is"  # accepted: no MCMC fallback
    assert seen and all(s == {1} for s in seen)
