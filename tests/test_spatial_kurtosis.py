"""The spatial variance of L-frame averages when the temporal noise is below a DN: the rounded values
are far from normal (at 0.2 DN of noise, most pixels read the black level and a few ±1), so the sample
variance scatters several times more than a normal's 2T²/ν. The Gamma shape of the spatial blocks
must carry that (its fourth cumulant through φ), or a few-percent wiggle of a dark spatial variance
reads as a significant DSNU. Checked against a seeded Monte Carlo of the estimator itself."""

import numpy as np
import pytest

from bayescap.model.pixel_quantization import _quantized_pixel_moments
from bayescap.model.prediction import _PredictionMixin


@pytest.mark.parametrize("n_frames", [1, 2, 16])
def test_spatial_variance_scatter_of_rounded_noise(n_frames):
    s, n_pix, reps = 0.2, 2000, 800
    rng = np.random.default_rng(11)
    sa, sd = np.empty(reps), np.empty(reps)
    for i in range(reps):
        x = np.round(s * rng.normal(size=(max(n_frames, 2), n_pix)))
        sa[i] = x[:n_frames].mean(0).var(ddof=1)  # spatial variance of the L-frame average
        sd[i] = 0.5 * (x[0] - x[1]).var(ddof=1)  # the pair's temporal variance
    V, E4, _ = _quantized_pixel_moments(np.zeros(1), np.array([s]), np.zeros(1), exact=True)
    phi = E4 / (2.0 * V * V)
    nu = float(n_pix - 1)
    obs, mean, shape, _ = _PredictionMixin._spatial_block(
        np.zeros(1), np.zeros(1), V, np.array([float(n_frames)]), sd[:1], np.array([nu]), 0.0, phi
    )
    if n_frames == 1:
        # given the pair's variance, the one-frame spatial variance's conditional scatter: the
        # residual of its regression on s²_D over the replicates
        beta = np.cov(sa, sd)[0, 1] / np.var(sd, ddof=1)
        resid = sa - beta * sd
        rel_mc = np.std(resid, ddof=2) / float(mean[0])  # relative to the model's conditional mean
        assert beta == pytest.approx(1.0 - 1.0 / phi[0], abs=0.1)
    else:
        rel_mc = np.std(sa, ddof=1) / np.mean(sa)
        assert float(mean[0]) == pytest.approx(np.mean(sa), rel=4 * rel_mc / np.sqrt(reps))
    rel_model = 1.0 / np.sqrt(float(shape[0]))
    # the MC's relative sd has a sampling error of about sqrt((κ-1)/4n) ≲ 10 % for these heavy tails
    assert rel_model == pytest.approx(rel_mc, rel=0.15), (rel_model, rel_mc, np.sqrt(2.0 / nu))


def test_floored_variance_has_the_normal_phi():
    """Below the 1e-6 DN² floor (noise far below a DN at an integer offset: a dark row of an 8-bit
    high-gain camera reads the black level on every pixel) the moments are the floor's. φ must not
    follow E4/(2·floor²), which falls with the noise and made the gamma's normalisation reward an
    ever smaller read noise (the zoo's draw25_8bit: read noise 0.005 DN for a truth of 0.05, K 0.25 %
    low, 1 interval width off)."""
    s = np.array([[0.02, 0.04, 0.08, 0.3]])
    var, phi, _ = _PredictionMixin._quantized_var(None, s * s, np.zeros(4), np.zeros((1, 4)))
    assert np.all(var[0, :3] == 1e-6)
    assert np.all(phi[0, :3] == 2.0)
    assert var[0, 3] > 1e-3 and phi[0, 3] > 2.0  # above the floor: the rounded noise's own φ
