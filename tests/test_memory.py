"""Memory of a ``log_prob`` call on many rows: bounded by the chunking over draws
(:meth:`bayescap.model.PTCModel._chunked_loglik`), with the same numbers bit for bit."""

from __future__ import annotations

import tracemalloc

import numpy as np

from bayescap.io.ptc_csv import read_ptc_csv
from bayescap.model import PTCModel
from bayescap.validation.framesim import Acquisition, FrameSensor, simulate_rows, write_csv


def _model(tmp_path, n_rows, spatial, adc_bits=10, top=1.3):
    s = FrameSensor(
        k_e_per_dn=9.5,
        read_noise_e=6.0,
        full_well_e=1e5,
        dark_current_e_per_s=50.0,
        prnu_frac=0.01,
        dsnu_e=5.0,
        adc_bits=adc_bits,
        black_level_dn=64.0,
        width_px=8,
        height_px=8,
    )
    clip_e = (1023 - 64) * 9.5
    f = np.linspace(0.02, top, n_rows)
    acq = Acquisition(tuple(0.02 * f / 1.3), tuple(f * clip_e / 0.5), tuple(range(n_rows)) if spatial else (), 2)
    path = tmp_path / f"rows{n_rows}.csv"
    write_csv(path, simulate_rows(s, acq, 1), {"adc_bits": adc_bits, "sensor": "many rows"})
    return PTCModel(read_ptc_csv(path))


def _rows_csv(tmp_path, n_rows):
    """A contract CSV of ``n_rows`` unclipped rows from the closed forms (K 2 e-/DN, read 6 e-),
    with 1 % scatter: quick to make for many rows."""
    rng = np.random.default_rng(0)
    t = np.linspace(1e-3, 0.1, n_rows)
    s_e = 2e4 * t / 0.1
    var = (s_e + 36.0 + 5.0 * t) / 4.0 + 1 / 12
    dvar = (36.0 + 5.0 * t) / 4.0 + 1 / 12
    lines = ["# adc_bits: 16", "exposure_time_s,mean_dn,temporal_var_dn2,dark_mean_dn,dark_temporal_var_dn2,n_pixels"]
    for i in range(n_rows):
        sc = 1 + 0.01 * rng.standard_normal(2)
        lines.append(
            f"{t[i]:.17g},{1000 + s_e[i] / 2.0:.17g},{var[i] * sc[0]:.17g},1000.0,{dvar[i] * sc[1]:.17g},10000"
        )
    path = tmp_path / f"closed{n_rows}.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def _peak_mb(fn):
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()


def test_log_prob_memory_does_not_grow_with_the_draws_on_many_rows(tmp_path):
    # 3 000 rows (~6 000 observations a draw): unchunked, the intermediates of 500 draws took five
    # times those of 100 (~95 bytes per draw x observation); chunked, the peak stays near one chunk's
    m = PTCModel(read_ptc_csv(_rows_csv(tmp_path, 3000)))
    x0 = m.initial_guess()
    rng = np.random.default_rng(0)
    small = x0 + 1e-3 * rng.standard_normal((100, m.ndim))
    large = x0 + 1e-3 * rng.standard_normal((500, m.ndim))
    p_small = _peak_mb(lambda: m.log_prob(small))
    p_large = _peak_mb(lambda: m.log_prob(large))
    assert p_large < 2.0 * p_small, (p_small, p_large)


def test_chunked_log_prob_is_bit_identical(tmp_path, monkeypatch):
    import bayescap.model.ptc_model as pm

    m = _model(tmp_path, 120, spatial=True)
    assert m.clip_rows.size  # the rows near the clip are chosen over the call's draws
    x0 = m.initial_guess()
    th = x0 + 0.05 * np.random.default_rng(1).standard_normal((300, m.ndim))
    whole = m.log_prob(th)
    monkeypatch.setattr(pm, "CHUNK_ELEMENTS", 1)  # chunks of CHUNK_MIN_DRAWS draws
    chunked = m.log_prob(th)
    assert np.isfinite(whole).sum() > 200
    assert np.array_equal(whole, chunked)


def test_chunked_predict_is_bit_identical(tmp_path, monkeypatch):
    import bayescap.model.ptc_model as pm

    m = _model(tmp_path, 120, spatial=True)
    x0 = m.initial_guess()
    th = x0 + 0.02 * np.random.default_rng(2).standard_normal((50, m.ndim))
    with np.errstate(all="ignore"):
        whole = m.predict(th)
        latent = m._last_latent_signal_dn.copy()
        monkeypatch.setattr(pm, "CHUNK_ELEMENTS", 1)
        chunked = m.predict(th)
    assert whole.keys() == chunked.keys()
    for b in whole:
        for x, y in zip(whole[b], chunked[b]):
            assert np.array_equal(np.broadcast_to(x, np.shape(y)), y) and np.shape(x) == np.shape(y), b
    assert np.array_equal(latent, m._last_latent_signal_dn)


def test_outlier_probabilities_in_chunks_equal_the_whole_mean(tmp_path, monkeypatch):
    m = _model(tmp_path, 120, spatial=True)
    th = m.initial_guess() + 0.02 * np.random.default_rng(3).standard_normal((40, m.ndim))
    with np.errstate(all="ignore"):
        pred = m.predict(th)
        whole = {
            b: np.nanmean(m._block_loglik(b, *blk, with_outlier_prob=True)[1], axis=0)
            for b, blk in pred.items()
            if b in ("bright_var", "dark_var", "mean")
        }
        monkeypatch.setattr(type(m), "OUTLIER_CHUNK_ELEMENTS", 7)
        chunked = m.outlier_probabilities(th, pred)
    assert whole.keys() == chunked.keys()
    for b in whole:
        assert np.array_equal(whole[b], chunked[b][1]), b
