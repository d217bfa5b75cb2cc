"""The focal-plane batch's speed work: the shortcuts of the clip rows give the full formula's numbers,
the batch's tasks pack sensors that do not stack and shrink towards the end, and a mean/variance
table's start lies near its curve."""

import numpy as np
from scipy.special import ndtr, owens_t

from bayescap.batch.runner import _chunks
from bayescap.model.clipping import _clip_var_slope, _ndtr_upper


def _full_formula(s, tau, d):
    """The clipped variance and Φ(h) of ``_ClipMixin._clip_moments``, every element through the
    special functions (the shortcut-free form)."""
    s, tau, d = np.broadcast_arrays(s, tau, d)
    s2 = s * s
    sp2 = np.maximum(s2 + tau * tau, 1e-300)
    h = d / np.sqrt(sp2)
    Ph = ndtr(h)
    ph = np.exp(-0.5 * h * h) * 0.3989422804014327
    var = np.array(s2, dtype=float)
    w = ~(h > 8.5)
    hw, phw, Phw, rho = h[w], ph[w], Ph[w], tau[w] * tau[w] / sp2[w]
    k = np.sqrt((1.0 - rho) / (1.0 + rho))
    P2 = Phw - 2.0 * owens_t(hw, k)
    M = (
        (hw * hw + rho) * P2
        + 2.0 * hw * phw * ndtr(hw * k)
        + np.sqrt(1.0 - rho * rho) * 0.15915494309189535 * np.exp(-hw * hw / (1.0 + rho))
    )
    var[w] = np.maximum(sp2[w] * ((hw * hw + 1.0) * Phw + hw * phw - M), 0.0)
    return var, Ph


def test_clip_shortcuts_give_the_full_formula_bit_for_bit():
    """Φ(h) is 1.0 in double precision above h = 8.5 (so ndtr and Owen's T are skipped there), and
    the variance and Φ of the shortcut equal the full formula's exactly, across h from deep in the
    clip to far below it, with (n, 1) columns broadcast as the latent solver passes them."""
    assert np.all(ndtr(np.linspace(8.5, 60.0, 200_001)) == 1.0)
    rng = np.random.default_rng(5)
    s = rng.uniform(0.5, 300.0, (40, 60))
    tau = rng.uniform(0.0, 3000.0, (40, 1))
    d = rng.uniform(-20.0, 40.0, (40, 60)) * np.sqrt(s * s + tau * tau)
    d[:, :3] = 8.5 * np.sqrt(s[:, :3] ** 2 + tau**2)  # at the edge itself
    var, Ph, _, _ = _clip_var_slope(s, tau, d)
    ref_var, ref_Ph = _full_formula(s, tau, d)
    np.testing.assert_array_equal(var, ref_var)
    np.testing.assert_array_equal(Ph, ref_Ph)
    x = np.concatenate([np.linspace(-40, 40, 10_001), [np.nan, np.inf, -np.inf]])
    np.testing.assert_array_equal(_ndtr_upper(x), ndtr(x))


def test_batch_tasks_pack_unstackable_sensors_and_shrink_at_the_end():
    """3 024 sensors that stack with no other (a group each) make 44 tasks, not 3 024: every sensor
    in exactly one task, none above chunk_size, the sizes never growing and the last ones 8; a group
    larger than a task is still cut into pieces of at most chunk_size."""
    groups = [[i] for i in range(3024)]
    tasks = _chunks(groups, 128, 2)
    sizes = [sum(map(len, t)) for t in tasks]
    assert len(tasks) == 44 and max(sizes) == 128 and sizes[-1] == 8
    assert all(a >= b for a, b in zip(sizes, sizes[1:]))
    assert sorted(i for t in tasks for piece in t for i in piece) == list(range(3024))
    big = _chunks([list(range(1000))], 128, 2)
    assert all(len(piece) <= 128 for t in big for piece in t)
    assert sorted(i for t in big for piece in t for i in piece) == list(range(1000))
    assert [sum(map(len, t)) for t in _chunks([list(range(8))], 2, 2)] == [2, 2, 2, 2]


def test_mean_variance_table_starts_near_its_curve():
    """A mean/variance table (no dark rows) generated from the model's own curve, variance =
    read²/K² + 1/12 + S/K · (e^z − 1)/z with z = 2·bf·S/S_ref: the quadratic start recovers K and
    the read noise to a few per cent and the bend's sign and size (before, the dark noise started
    at 0.05 DN and K from a straight line through the bend)."""
    import io
    import tempfile
    from pathlib import Path

    import bayescap
    from bayescap.model import PTCModel
    from bayescap.model.response import bf_factor

    k_true, read_e = 1.3, 6.0
    S = np.geomspace(30.0, 57000.0, 120)
    rng = np.random.default_rng(2)

    def table(bf_coord, s_ref):
        z = 2.0 * bf_coord * S / s_ref
        v = read_e**2 / k_true**2 + 1.0 / 12.0 + S / k_true * bf_factor(z)
        v = v * (1.0 + 0.01 * rng.standard_normal(S.size))  # 1 % scatter, as ~40 000 pixels give
        buf = io.StringIO()
        buf.write("mean_dn,temporal_var_dn2,n_pixels\n")
        for a, b in zip(S, v):
            buf.write(f"{a:.6f},{b:.6f},40000\n")
        return buf.getvalue()

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "amp.csv"
        p.write_text(table(0.0, 1.0))
        s_ref = PTCModel.for_fit(bayescap.load(p)).response_ref_dn  # the model's reference signal
        bf_coord = -2e-6 * k_true * s_ref  # a00 = -2e-6 per e-
        p.write_text(table(bf_coord, s_ref))
        m = PTCModel.for_fit(bayescap.load(p))
    assert m.terms.brighter_fatter and not m.dark_rows
    x = m.initial_guess()
    k0 = float(np.exp(x[m.idx["log_k"]]))
    read0 = float(np.exp(x[m.idx["log_dark_noise"]]))
    assert abs(k0 / k_true - 1.0) < 0.03
    assert abs(read0 / read_e - 1.0) < 0.15
    bf0 = float(x[m.idx["bf"]])
    assert bf0 < 0 and abs(bf0 / bf_coord - 1.0) < 0.3
