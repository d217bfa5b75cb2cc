"""Colour sensitivity (bayescap.colour.sensitivity) against closed forms and a brute-force count."""

import numpy as np
import pytest
from scipy.spatial import Delaunay

from bayescap.colour.sensitivity import colour_sensitivity, colour_sensitivity_bits, raw_rgb_coefficients
from bayescap.physics.capacity import tonal_range
from bayescap.physics.noise import NoiseCoefficients

M_SRGB_LIKE = np.array([[1.76, -0.66, -0.10], [-0.16, 1.64, -0.48], [0.06, -0.56, 1.50]])
WB = np.array([1.72, 1.0, 1.17])


def _draws(n=40, seed=0, c0=2.3, c1=0.5, prnu=(0.008, 0.006, 0.006, 0.01), clip=4031.0):
    rng = np.random.default_rng(seed)
    base = np.array([[c0, c1, p**2] for p in prnu])
    v = base[None] * np.exp(0.05 * rng.standard_normal((n, 4, 3)))
    return v, clip * np.exp(0.01 * rng.standard_normal((n, 4)))


def _tr_bits_no_floor(v, clip):
    """Σ_c log2 TR_c with the existing Eq. 7 code (no floor: an infinite number of grey levels)."""
    rgb, clip3 = raw_rgb_coefficients(v, clip)
    total = 0.0
    for j in range(3):
        co = NoiseCoefficients(a=rgb[:, j, 0], b=rgb[:, j, 1], c=rgb[:, j, 2])
        total = total + np.log2(tonal_range(co, clip3[:, j], n_levels=np.inf))
    return total


def test_no_floor_full_cube_is_the_sum_of_tonal_ranges():
    v, clip = _draws()
    cs = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, floor=False)
    assert np.max(np.abs(cs - _tr_bits_no_floor(v, clip))) < 1e-6


def test_invertible_matrices_change_nothing_without_floor():
    v, clip = _draws(n=20, seed=1)
    rng = np.random.default_rng(2)
    ref = colour_sensitivity_bits(v, clip, np.eye(3), np.ones(3), floor=False)
    for _ in range(5):
        m = np.eye(3) + 0.6 * rng.standard_normal((3, 3))
        m = m / np.abs(m.sum(axis=1, keepdims=True))  # rows with a positive white
        if np.any(m.sum(axis=1) <= 0) or abs(np.linalg.det(m)) < 0.05:
            continue
        ms = m[None] * np.exp(0.02 * rng.standard_normal((20, 3, 3)))  # an uncertain CCM
        wb = np.exp(0.3 * rng.standard_normal((20, 3)))
        cs = colour_sensitivity_bits(v, clip, ms, wb, floor=False)
        assert np.max(np.abs(cs - ref)) < 1e-6


def test_only_floor_clipping_and_domain_move_cs():
    """With the floor, M moves CS: the floor loses the colours where σ̄ < 1 level, and a matrix
    that amplifies noise (|det A| larger) makes that region smaller, so CS rises towards the
    floor-free value (which M cannot change). Clipping after M fixes the output volume: there the
    amplified noise costs colours. The domain of a reflectance set is smaller than the cube."""
    v, clip = _draws(n=10, seed=3)
    plain = colour_sensitivity_bits(v, clip, np.eye(3), WB)
    plain_clipped = colour_sensitivity_bits(v, clip, np.eye(3), WB, clip_output=True)
    mixed = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB)
    no_floor = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, floor=False)
    clipped = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, clip_output=True)
    cone = np.array([[1.0, 0.2, 0.1], [0.2, 1.0, 0.2], [0.1, 0.3, 1.0], [0.6, 0.6, 0.2]])
    in_cone = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, domain=cone)
    assert np.all(np.abs(np.linalg.det(M_SRGB_LIKE)) > 1)
    assert np.all(mixed > plain + 1e-3)  # the floor binds less where M amplifies the noise
    assert np.all(mixed <= no_floor + 1e-9)  # the floor only removes colours
    assert np.all(clipped < mixed - 0.05)  # out-of-gamut colours are lost
    assert np.all(clipped < plain_clipped - 0.05)  # in a fixed output volume, amplified noise costs
    assert np.all(in_cone < mixed - 0.05)  # a reflectance set spans less than the cube
    assert np.all(clipped <= 3 * 8 + 1e-9)  # the output volume [0, 256]³ bounds it


def test_quadrature_converged():
    v, clip = _draws(n=4, seed=4)
    a = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, n_grid=48)
    b = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, n_grid=160)
    assert np.max(np.abs(a - b)) < 1e-5


def _mc_count(v, clip, m, wb, out_bits, n_mc, seed, clip_output=False, cone=None, floor=True):
    """Brute force: colours drawn uniformly in a box around the output volume; each counts
    1/max(1, σ̄)³ cells, σ̄ from the explicit output covariance A Σ_raw Aᵀ. Returns (count, SE)."""
    c0, c1, c2 = (v[..., j] for j in range(3))
    sig2 = lambda ch, s: c0[ch] + c1[ch] * s + c2[ch] * s * s  # noqa: E731
    lo = np.array([np.sqrt(c0[0]), np.sqrt((c0[1] + c0[2]) / 4), np.sqrt(c0[3])])
    hi = np.array([clip[0], min(clip[1], clip[2]), clip[3]])
    n_lev = 2.0**out_bits
    white = np.min(wb * hi) * m.sum(axis=1)
    a = np.diag(n_lev / white) @ m @ np.diag(wb)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) @ a.T
    bmin, bmax = corners.min(axis=0), corners.max(axis=0)
    rng = np.random.default_rng(seed)
    c = bmin + (bmax - bmin) * rng.random((n_mc, 3))
    s = c @ np.linalg.inv(a).T
    inside = np.all((s >= lo) & (s <= hi), axis=1)
    if clip_output:
        inside &= np.all((c >= 0) & (c <= n_lev), axis=1)
    if cone is not None:
        chroma = cone / cone.sum(axis=1, keepdims=True)
        tri = Delaunay(chroma[:, :2])
        sp = np.where(s.sum(axis=1, keepdims=True) > 0, s / s.sum(axis=1, keepdims=True), -1)
        inside &= tri.find_simplex(sp[:, :2]) >= 0
    s = np.clip(s, lo, hi)  # outside colours count zero; keep their variances finite
    var = np.stack([sig2(0, s[:, 0]), (sig2(1, s[:, 1]) + sig2(2, s[:, 1])) / 4, sig2(3, s[:, 2])], axis=1)
    cov = np.einsum("ij,nj,kj->nik", a, var, a)
    sbar = np.linalg.det(cov) ** (1 / 6)
    f = np.where(inside, 1.0 / (np.maximum(1.0, sbar) if floor else sbar) ** 3, 0.0)
    vol = np.prod(bmax - bmin)
    return vol * f.mean(), vol * f.std() / np.sqrt(n_mc)


@pytest.mark.parametrize("case", ["cube", "clip_output", "cone", "no_floor", "chart"])
def test_brute_force_count_agrees(case):
    """A small noisy sensor on a 4-bit grid (the floor binds over much of the volume); without the
    floor the count checks the Jacobian's cancellation in the output space, independently."""
    v = np.array([[[4.0, 0.5, 1e-4], [4.0, 0.5, 4e-5], [4.5, 0.5, 4e-5], [5.0, 0.5, 2e-4]]])
    clip = np.array([[300.0, 320.0, 310.0, 290.0]])
    cone = np.array([[1.0, 0.3, 0.1], [0.3, 1.0, 0.3], [0.1, 0.3, 1.0], [0.7, 0.7, 0.2]])
    if case == "chart":  # the ColorChecker under D65 through the Nikon's sensitivities, balanced by WB
        from bayescap.colour.spectral import reflectance_domain

        cone = reflectance_domain("Nikon 5100 (NPL)", "ColorChecker N Ohta", "D65", wb_gains=WB)
    kw = {"clip_output": case in ("clip_output", "chart"), "domain": cone if case in ("cone", "chart") else "cube"}
    floor = case != "no_floor"
    cs = colour_sensitivity(v, clip, M_SRGB_LIKE, WB, out_bits=4, n_grid=96, floor=floor, **kw)
    count, se = _mc_count(
        v[0],
        clip[0],
        M_SRGB_LIKE,
        WB,
        4,
        400_000,
        seed=7,
        clip_output=kw["clip_output"],
        cone=kw["domain"] if case in ("cone", "chart") else None,
        floor=floor,
    )
    z = (2.0 ** cs.bits[0] - count) / se
    assert abs(z) < 4.0, (case, cs.bits[0], np.log2(count), z)
    assert cs.choices["floor"].startswith("max(σ̄, 1) on a 16-level") if floor else cs.choices["floor"] == "none"


def test_choices_and_result_object():
    v, clip = _draws(n=3)
    r = colour_sensitivity(v, clip, M_SRGB_LIKE, WB)
    assert r.bits.shape == (3,) and np.asarray(r).shape == (3,)
    assert r.choices["domain"].startswith("the full raw cube")
    assert r.choices["ccm_uncertain"] is False


def test_uncertain_ccm_widens_the_interval():
    """Certain noise, uncertain CCM: the CS interval is not zero wide where M matters (a fixed
    output volume; over the raw cube only the floor feels M)."""
    v = np.broadcast_to(_draws(n=1)[0], (200, 4, 3))
    clip = np.full((200, 4), 4031.0)
    rng = np.random.default_rng(5)
    ms = M_SRGB_LIKE[None] * (1 + 0.05 * rng.standard_normal((200, 3, 3)))
    cs = colour_sensitivity_bits(v, clip, ms, WB, clip_output=True)
    width = np.ptp(np.quantile(cs, [0.025, 0.975]))
    assert width > 0.05, width


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"ccm": np.zeros((3, 3))}, "singular"),
        ({"ccm": np.full((3, 3), np.nan)}, "finite"),
        ({"wb_gains": np.array([1.0, -1.0, 1.0])}, "positive"),
        ({"domain": "sphere"}, "domain"),
        ({"var_coeffs_dn2": np.ones((2, 3, 3))}, "shape"),
    ],
)
def test_bad_input_is_refused(kw, msg):
    args = {"var_coeffs_dn2": _draws(n=2)[0], "clip_dn": np.full(2, 4000.0), "ccm": M_SRGB_LIKE, "wb_gains": WB}
    args.update(kw)
    with pytest.raises(ValueError, match=msg):
        colour_sensitivity_bits(**args)


@pytest.mark.parametrize("clip_output", [False, True])
def test_a_set_spanning_every_raw_direction_is_the_cube(clip_output):
    """Responses that include each pure raw channel span the whole octant: their cone cuts nothing
    from the cube, so CS over them is CS over the cube (a closed form of the domain)."""
    v, clip = _draws(8)
    octant = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.4, 0.5, 0.3]])
    cube = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, clip_output=clip_output, n_grid=40)
    cone = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, clip_output=clip_output, n_grid=40, domain=octant)
    np.testing.assert_allclose(cone, cube, rtol=0, atol=1e-9)


def test_a_draws_cs_does_not_depend_on_the_other_draws():
    """CS is computed in chunks of draws (and their nodes in smaller ones): a draw's value is the one
    it has alone, to the Newton polish's 1e-13 (a chunk iterates until its slowest draw converges)."""
    v, clip = _draws(n=600, seed=3)  # three chunks of draws, each of many node chunks
    kw = dict(clip_output=True, n_grid=12)
    every = colour_sensitivity_bits(v, clip, M_SRGB_LIKE, WB, **kw)
    for i in (0, 17, 300, 599):
        alone = colour_sensitivity_bits(v[i : i + 1], clip[i : i + 1], M_SRGB_LIKE, WB, **kw)
        np.testing.assert_allclose(alone, every[i : i + 1], rtol=0, atol=1e-12)


def _posterior_like(n, seed, scatter=0.01):
    """Draws like a fitted camera's: R, Gr, Gb, B noise coefficients scattered by ``scatter`` (log),
    clips by a fifth of it, and a CCM with 2 % element uncertainty."""
    rng = np.random.default_rng(seed)
    base = np.array([[2.3, 0.5, p**2] for p in (0.008, 0.006, 0.006, 0.01)])
    v = base[None] * np.exp(scatter * rng.standard_normal((n, 4, 3)))
    clip = 4031.0 * np.exp(0.2 * scatter * rng.standard_normal((n, 4)))
    ms = M_SRGB_LIKE[None] * (1 + 0.02 * rng.standard_normal((n, 3, 3)))
    return v, clip, ms


@pytest.mark.parametrize("clip_output", [True, False])
def test_emulated_cs_agrees_with_the_quadrature_on_every_draw(clip_output):
    """The linear map from 128 pilot draws: on the draws it was not fitted on its error is within what
    its leave-one-out check admits (≤ 0.1 of CS's sd, so ≤ 1 % of the variance), and the interval's
    ends and median move by less than their own Monte Carlo error over the n draws (0.68/√n of the
    95 % width for independent draws: the 2.5 % quantile's sd √(p(1 − p)/n)/φ(1.96)·σ over 3.92σ)."""
    from bayescap.colour.cs_emulator import EMULATOR_MAX_RESID_FRAC, EMULATOR_PILOTS, colour_sensitivity_emulated

    n = 400
    v, clip, ms = _posterior_like(n, seed=1)
    em = colour_sensitivity_emulated(v, clip, ms, WB, clip_output=clip_output, n_grid=40)
    ex = colour_sensitivity(v, clip, ms, WB, clip_output=clip_output, n_grid=40).bits
    check = em.choices["emulator"]
    assert em.choices["evaluation"].startswith(f"the quadrature on {EMULATOR_PILOTS} evenly spaced pilot draws")
    assert check["loo_resid_frac_of_sd"] <= EMULATOR_MAX_RESID_FRAC
    pilots = np.linspace(0, n - 1, EMULATOR_PILOTS).round().astype(int)
    unseen = np.setdiff1d(np.arange(n), pilots)
    assert np.sqrt(np.mean((em.bits - ex)[unseen] ** 2)) <= EMULATOR_MAX_RESID_FRAC * np.std(ex)
    q_ex, q_em = np.quantile(ex, [0.025, 0.5, 0.975]), np.quantile(em.bits, [0.025, 0.5, 0.975])
    assert np.max(np.abs(q_em - q_ex)) <= 0.68 / np.sqrt(n) * (q_ex[2] - q_ex[0])
    assert (
        em.choices["domain"]
        == colour_sensitivity(v[:2], clip[:2], ms[:2], WB, clip_output=clip_output).choices["domain"]
    )


def test_emulator_falls_back_to_the_quadrature_where_cs_is_not_linear_or_draws_are_few():
    """Draws scattered so widely that CS is not linear in them (c0 over a factor ~e³ both ways): the
    leave-one-out check fails and every draw is evaluated exactly, as colour_sensitivity does; with
    fewer than twice the pilots, exactly too."""
    from bayescap.colour.cs_emulator import colour_sensitivity_emulated

    v, clip, ms = _posterior_like(300, seed=2)
    rng = np.random.default_rng(3)
    v[..., 0] *= np.exp(1.5 * rng.standard_normal((300, 1)))
    v[..., 2] *= np.exp(1.5 * rng.standard_normal((300, 1)))
    em = colour_sensitivity_emulated(v, clip, ms, WB, clip_output=True, n_grid=24)
    assert em.choices["evaluation"].startswith("the quadrature on every draw (the linear map's leave-one-out")
    assert em.choices["emulator"]["loo_resid_frac_of_sd"] > 0.1
    assert np.array_equal(em.bits, colour_sensitivity(v, clip, ms, WB, clip_output=True, n_grid=24).bits)
    few = colour_sensitivity_emulated(v[:200], clip[:200], ms[:200], WB, n_grid=24)
    assert few.choices["evaluation"].startswith("the quadrature on every draw (200 draws")
    assert np.array_equal(few.bits, colour_sensitivity(v[:200], clip[:200], ms[:200], WB, n_grid=24).bits)


def test_emulator_checks_every_draw_not_only_its_pilots():
    """A singular CCM or a negative coefficient in a draw the map does not evaluate is refused, as the
    quadrature refuses it."""
    from bayescap.colour.cs_emulator import colour_sensitivity_emulated

    v, clip, ms = _posterior_like(300, seed=4)
    bad = ms.copy()
    bad[1] = [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # draw 1 is not a pilot
    with pytest.raises(ValueError, match="singular"):
        colour_sensitivity_emulated(v, clip, bad, WB, clip_output=True)
    vb = v.copy()
    vb[1, 0, 1] = -0.1
    with pytest.raises(ValueError, match="c1 ≥ 0"):
        colour_sensitivity_emulated(vb, clip, ms, WB, clip_output=True)
