"""Colour sensitivity (CS): the log₂ of the number of colours a camera distinguishes up to its noise.

DxOMark's definition, written in the paper's Eq. 7 form: over the reachable colour volume V,

    CS = log₂ ∫_V dc / max(1, σ̄(c))³,    σ̄ = (det Σ_out)^{1/6},    Σ_out = A Σ_raw Aᵀ,  A = D M W,

with ``Σ_raw = diag(σ_R², σ_G², σ_B²)`` the raw noise (independent pixels; G the average of Gr and
Gb, so ``σ_G² = (σ_Gr² + σ_Gb²)/4`` at a common signal), ``W = diag(wb_gains)`` the white balance,
``M`` the colour-correction matrix and ``D`` the 8-bit-equivalent grid: output channel i is counted
in ``2^out_bits`` levels from 0 to its white, the image under ``A`` of the brightest neutral no raw
channel clips (``L_w = min_c w_c·clip_c``), so that ``D = diag(2^out_bits / (L_w·(M·1)_i))``. This
is the monochrome convention of :mod:`bayescap.physics.capacity` (``S_max/256`` per grey level)
applied to each output channel. CS is at most log₂ of the domain's output volume in levels:
``3·out_bits`` when the colours are clipped to ``[0, white]`` after M (``clip_output=True``); over
the raw cube it can exceed that, since the white-balanced raw channels reach beyond white (every
channel but the first to clip) and M enlarges the volume by |det M|.

How it is evaluated (exactly, no Monte Carlo). Integrate in raw coordinates ``s`` (DN above
black): ``dc = |det A| ds`` and ``σ̄³ = |det A|·σ_R σ_G σ_B``. Substituting each raw axis by its
noise-equalised coordinate ``t_c = ∫ ds_c / σ_c`` (the tonal range integral of Eq. 7 without the
floor) the integrand becomes ``min(1, σ̄³)``, and along the B axis the integral is Eq. 7's closed
form with a floor ``1/k``, ``k = |det A|·σ_R·σ_G``:

    ∫ ds_B |det A| / max(1, k σ_B) = ∫ ds_B / max(σ_B, 1/k)

(:func:`bayescap.physics.capacity.integral_inv_sqrt_quadratic`). The remaining (t_R, t_G) plane is
integrated by Gauss-Legendre quadrature (``n_grid`` nodes per axis). Consequences, which the tests
hold the code to: without the floor and over the full cube the integrand is 1 and CS is exactly
``Σ_c log₂ TR_c`` (the three channels' tonal ranges without the floor); an invertible M or W then
changes nothing (the Jacobian cancels); only the floor, clipping after M and the domain move CS.

Domains. ``"cube"``: every raw triple in ``[σ_c(0), clip_c]`` (the dark noise floor to the clip, the
dynamic range of Eq. 2 per channel). A reflectance set: an ``(n, 3)`` array of raw R, G, B responses
(e.g. :func:`bayescap.colour.spectral.reflectance_domain`); the domain is the cube ∩ the convex cone
they span (every exposure of every mixture of those colours). ``clip_output=True`` also drops the
colours that leave ``[0, white]`` after M (out of gamut / clipped in the output).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from bayescap.physics.capacity import integral_inv_sqrt_quadratic

__all__ = [
    "ColourSensitivity",
    "colour_sensitivity",
    "colour_sensitivity_bits",
    "raw_rgb_coefficients",
    "CS_DEFINITION",
]

CS_DEFINITION = (
    "colour sensitivity CS = log2 of the number of colours distinguishable up to noise, "
    "log2 ∫ dc / max(1, det(Σ_out)^(1/6))^3 over the reachable colours, Σ_out = D M W Σ_raw W M' D' "
    "(G = mean of Gr and Gb; D: each output channel in 2^out_bits levels from 0 to white)"
)
_DRAW_CHUNK = 256
#: draws whose (draw, node, node) arrays are computed at once (n_grid = 40: ~200 kB an array)
_NODE_CHUNK = 16


@dataclass(frozen=True)
class ColourSensitivity:
    """CS per draw (bits) and the choices it was computed with."""

    bits: np.ndarray
    choices: dict = field(default_factory=dict)

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.bits, dtype=dtype)

    def __len__(self):
        return len(self.bits)


def raw_rgb_coefficients(var_coeffs_dn2, clip_dn):
    """R, G, B noise coefficients (n, 3, 3) and clip levels (n, 3) from R, Gr, Gb, B ones.

    G is the average of Gr and Gb at a common signal: its variance is ``(σ_Gr² + σ_Gb²)/4``
    (independent pixels) and it clips where the first of the two clips."""
    v = np.asarray(var_coeffs_dn2, float)
    if v.ndim == 2:
        v = v[None]
    if v.ndim != 3 or v.shape[1:] != (4, 3):
        raise ValueError(f"var_coeffs_dn2 must have shape (n_draws, 4, 3) (R, Gr, Gb, B × c0, c1, c2), got {v.shape}")
    n = v.shape[0]
    clip = np.asarray(clip_dn, float)
    if clip.ndim == 0:
        clip = np.full((n, 4), float(clip))
    elif clip.ndim == 1:
        if clip.shape[0] != n:
            raise ValueError(f"clip_dn must have shape (n_draws, 4) or (n_draws,), got {clip.shape}")
        clip = np.repeat(clip[:, None], 4, axis=1)
    if clip.shape != (n, 4):
        raise ValueError(f"clip_dn must have shape (n_draws, 4) or (n_draws,), got {np.shape(clip_dn)}")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(clip))):
        raise ValueError("var_coeffs_dn2 and clip_dn must be finite")
    if np.any(v[..., 0] <= 0) or np.any(v[..., 1:] < 0) or np.any(clip <= 0):
        raise ValueError("need c0 > 0, c1 ≥ 0, c2 ≥ 0 and clip_dn > 0 in every draw and channel")
    rgb = np.stack([v[:, 0], (v[:, 1] + v[:, 2]) / 4.0, v[:, 3]], axis=1)
    clip3 = np.stack([clip[:, 0], np.minimum(clip[:, 1], clip[:, 2]), clip[:, 3]], axis=1)
    return rgb, clip3


def _per_draw(x, n, shape, name):
    x = np.asarray(x, float)
    if x.shape == shape:
        x = np.broadcast_to(x, (n, *shape))
    if x.shape != (n, *shape):
        raise ValueError(f"{name} must have shape {shape} or (n_draws, *{shape}), got {np.shape(x)}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} must be finite")
    return x


@lru_cache(maxsize=8)
def _unit_gauss_legendre(n: int):
    """Gauss-Legendre nodes and weights on [0, 1] (cached: numpy's take ~4 ms at 40 nodes)."""
    x, w = np.polynomial.legendre.leggauss(n)
    u, wu = 0.5 * (x + 1.0), 0.5 * w
    u.setflags(write=False)
    wu.setflags(write=False)
    return u, wu


def _inverse_tonal(a, b, c, lo, t):
    """s ≥ lo with ∫_lo^s dS/√(a + bS + cS²) = t (vectorised; t ≥ 0): the closed-form inverse of
    the integral, polished by Newton's method to 1e-13 relative.

    With e = √c the integral is ln((2e·σ(s) + 2c·s + b)/(2e·σ(lo) + 2c·lo + b))/e; solved for s,

        s = (D² − 4a) / (4(b + e·D)),   D = 2(σ(lo) + e·lo)·exp(e·t) + b·t·expm1(e·t)/(e·t),

    which has no division by c and tends to the c = 0 solution lo + σ(lo)·t + b·t²/4 as c → 0."""
    r_lo = np.sqrt(a + b * lo + c * lo * lo)
    e = np.sqrt(c)
    x = e * t
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        g = np.where(x > 1e-8, np.expm1(x) / np.where(x > 1e-8, x, 1.0), 1.0 + x / 2.0)
        big_d = 2.0 * (r_lo + e * lo) * np.exp(x) + b * t * g
        s = np.where((b > 0) | (c > 0), (big_d * big_d - 4.0 * a) / (4.0 * (b + e * big_d)), lo + r_lo * t)
    s = np.maximum(s, lo)
    for _ in range(60):
        f = integral_inv_sqrt_quadratic(a, b, c, lo, s)
        step = (t - f) * np.sqrt(a + b * s + c * s * s)
        s = np.maximum(s + step, lo)
        if np.all(np.abs(step) <= 1e-13 * np.maximum(s, 1.0)):
            break
    return s


def checked_inputs(var_coeffs_dn2, clip_dn, ccm, wb_gains):
    """Every draw's R, G, B noise coefficients (n, 3, 3), clips (n, 3), CCM (n, 3, 3) and white
    balance (n, 3), checked (ValueError: the first problem, in words)."""
    rgb, clip3 = raw_rgb_coefficients(var_coeffs_dn2, clip_dn)
    n = rgb.shape[0]
    ccm_d = _per_draw(ccm, n, (3, 3), "ccm")
    wb_d = _per_draw(wb_gains, n, (3,), "wb_gains")
    if np.any(wb_d <= 0):
        raise ValueError("wb_gains must be positive")
    if np.any(np.abs(np.linalg.det(ccm_d)) <= 1e-12 * np.max(np.abs(ccm_d), axis=(1, 2)) ** 3):
        raise ValueError("the colour-correction matrix is singular (or nearly) in some draw")
    if np.any(ccm_d.sum(axis=2) <= 0):
        raise ValueError("the colour-correction matrix maps white to a non-positive output (a row sum ≤ 0)")
    return rgb, clip3, ccm_d, wb_d


def _cone_halfspaces(directions):
    """Normals n_k (m, 3) with n_k·s ≥ 0 exactly on the convex cone spanned by ``directions``."""
    from scipy.spatial import ConvexHull

    d = np.asarray(directions, float)
    if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] < 3 or not np.all(np.isfinite(d)):
        raise ValueError("a reflectance domain needs (n ≥ 3, 3) finite raw R, G, B responses")
    if np.any(d < 0) or np.any(d.sum(axis=1) <= 0):
        raise ValueError("raw responses must be ≥ 0 and not all zero")
    chroma = d / d.sum(axis=1, keepdims=True)
    hull = ConvexHull(chroma[:, :2])
    centre = d[hull.vertices].mean(axis=0)
    normals = []
    for i, j in hull.simplices:
        nvec = np.cross(d[i], d[j])
        if nvec @ centre < 0:
            nvec = -nvec
        normals.append(nvec / np.linalg.norm(nvec))
    return np.array(normals)


def _interval_b(coef_r, coef_g, coef_b, rhs, s_r, s_g, lo, hi, lo_min, hi_max):
    """Tighten the B interval ``[lo, hi]`` of every node, in place, by the constraints
    coef_r·s_R + coef_g·s_G + coef_b·s_B ≥ rhs.

    coef_*, rhs: (n, m); s_r, s_g: (n, p), the nodes' raw R and G; lo, hi: (n, p, p) (node (i, k)
    at s_R = s_r[:, i], s_G = s_g[:, k]); lo_min, hi_max: (n,), bounds on every node's ``lo`` and
    ``hi`` (the interval before any constraint). A constraint with coef_b > 0 bounds s_B below by
    (rhs − coef_r·s_R − coef_g·s_G)/coef_b, one with coef_b < 0 above; the division is done on the
    (n, m) coefficients, the R and G terms on the (n, p) nodes, and a constraint that does not bound
    a side is an infinite bound there. A constraint whose bound is nowhere inside
    ``[lo_min, hi_max]`` on the grid (its largest lower or smallest upper bound, from the (n, p)
    terms) is skipped: it would change no node."""
    n, p = s_r.shape
    pos, neg = coef_b > 0, coef_b < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v, w = rhs / coef_b, coef_r / coef_b, coef_g / coef_b
    buf = None
    for side, inf in ((pos, -np.inf), (neg, np.inf)):
        uu, vv, ww = np.where(side, u, inf), np.where(side, v, 0.0), np.where(side, w, 0.0)
        for j in np.flatnonzero(side.any(axis=0)):
            r_part = uu[:, j, None] - vv[:, j, None] * s_r  # (n, p)
            g_part = ww[:, j, None] * s_g
            # the bound at node (i, k) is r_part[i] − g_part[k]: its extreme over the grid is that
            # of the (n, p) terms (rounding is monotonic)
            if inf < 0 and not np.any(r_part.max(axis=1) - g_part.min(axis=1) > lo_min):
                continue
            if inf > 0 and not np.any(r_part.min(axis=1) - g_part.max(axis=1) < hi_max):
                continue
            if buf is None:
                buf = np.empty((n, p, p))
            np.subtract(r_part[:, :, None], g_part[:, None, :], out=buf)
            if inf < 0:
                np.maximum(lo, buf, out=lo)
            else:
                np.minimum(hi, buf, out=hi)
    for j in np.flatnonzero((coef_b == 0).any(axis=0)):
        zero = (coef_b[:, j] == 0)[:, None, None]
        rest = (
            rhs[:, j, None, None]
            - coef_r[:, j, None, None] * s_r[:, :, None]
            - coef_g[:, j, None, None] * s_g[:, None, :]
        )
        np.copyto(hi, lo, where=zero & (rest > 0))  # violated whatever s_B is: empty
    np.maximum(hi, lo, out=hi)


def _cs_chunk(rgb, clip3, ccm, wb, floor, n_levels, clip_output, cone, nodes, lower):
    n = rgb.shape[0]
    a, b, c = rgb[..., 0], rgb[..., 1], rgb[..., 2]  # (n, 3)
    lo = np.sqrt(a) if lower == "dark_noise" else np.zeros_like(a)
    lo = np.minimum(lo, clip3)
    t_max = integral_inv_sqrt_quadratic(a, b, c, lo, clip3)  # (n, 3): each channel's TR, no floor
    u, wu = nodes
    # nodes per draw on the R and G axes
    tr = t_max[:, 0, None] * u  # (n, p)
    tg = t_max[:, 1, None] * u
    s_r = _inverse_tonal(a[:, :1], b[:, :1], c[:, :1], lo[:, :1], tr)
    s_g = _inverse_tonal(a[:, 1:2], b[:, 1:2], c[:, 1:2], lo[:, 1:2], tg)
    sig_r = np.sqrt(a[:, :1] + b[:, :1] * s_r + c[:, :1] * s_r**2)
    sig_g = np.sqrt(a[:, 1:2] + b[:, 1:2] * s_g + c[:, 1:2] * s_g**2)
    # output scale: white = L_w · (M·1), L_w = min_c w_c clip_c
    l_w = np.min(wb * clip3, axis=1)  # (n,)
    m1 = ccm.sum(axis=2)  # (n, 3)
    d = n_levels / (l_w[:, None] * m1)  # (n, 3)
    amat = d[:, :, None] * ccm * wb[:, None, :]  # A = D M W
    det_a = np.abs(np.linalg.det(amat))  # (n,)
    inner_sum = np.empty(n)
    per_draw = (a, b, c, lo, clip3, t_max, s_r, s_g, sig_r, sig_g, amat, det_a)
    # the (draw, node, node) arrays a few draws at a time: they stay in the core's cache (the closed
    # form's ~30 elementwise passes over 256 draws' nodes at once took twice as long)
    for i in range(0, n, _NODE_CHUNK):
        sl = slice(i, i + _NODE_CHUNK)
        inner = _b_axis(*(x[sl] for x in per_draw), floor, n_levels, clip_output, cone)
        inner_sum[sl] = np.einsum("npq,p,q->n", inner, wu, wu)
    total = inner_sum * t_max[:, 0] * t_max[:, 1]
    with np.errstate(divide="ignore"):
        return np.log2(total)


def _b_axis(a, b, c, lo, clip3, t_max, s_r, s_g, sig_r, sig_g, amat, det_a, floor, n_levels, clip_output, cone):
    """The B axis's integral at every node of the (t_R, t_G) plane, (n, p, p): Eq. 7's closed form
    between the B interval's ends that the domain leaves, with the floor ``1/(|det A| σ_R σ_G)``."""
    n, n_grid = s_r.shape
    shape = (n, n_grid, n_grid)
    lo_b = np.empty(shape)
    lo_b[...] = lo[:, 2, None, None]
    hi_b = np.empty(shape)
    hi_b[...] = clip3[:, 2, None, None]
    if clip_output:
        # 0 ≤ (A s)_i ≤ n_levels  ⇔  A_i·s ≥ 0 and −A_i·s ≥ −n_levels
        cr = np.concatenate([amat[:, :, 0], -amat[:, :, 0]], axis=1)
        cg = np.concatenate([amat[:, :, 1], -amat[:, :, 1]], axis=1)
        cb = np.concatenate([amat[:, :, 2], -amat[:, :, 2]], axis=1)
        rhs = np.concatenate([np.zeros((n, 3)), -n_levels * np.ones((n, 3))], axis=1)
        _interval_b(cr, cg, cb, rhs, s_r, s_g, lo_b, hi_b, lo[:, 2], clip3[:, 2])
    if cone is not None:
        m = cone.shape[0]
        cn = np.broadcast_to(cone, (n, m, 3))
        _interval_b(cn[..., 0], cn[..., 1], cn[..., 2], np.zeros((n, m)), s_r, s_g, lo_b, hi_b, lo[:, 2], clip3[:, 2])
    if floor:
        fl = (det_a[:, None] * sig_r)[:, :, None] * sig_g[:, None, :]
        np.divide(1.0, fl, out=fl)
    else:
        fl = np.zeros((n, 1, 1))
    a_b, b_b, c_b = (x[:, 2, None, None] for x in (a, b, c))
    # the closed form only where it is not known without it: an empty B interval (cut away by
    # the constraints: three quarters of the nodes where the colours are clipped after a typical M)
    # contributes 0; over the full cube, a node where the floor does not bind anywhere on the B axis
    # (σ_B(lo) ≥ floor, σ_B increasing) contributes the B channel's TR
    need = hi_b > lo_b
    inner = np.zeros(shape)
    if not clip_output and cone is None:
        free = need & (np.sqrt(a_b + b_b * lo_b + c_b * lo_b * lo_b) >= fl)
        inner[free] = np.broadcast_to(t_max[:, 2, None, None], shape)[free]
        need &= ~free
    inner[need] = integral_inv_sqrt_quadratic(
        *(np.broadcast_to(x, shape)[need] for x in (a_b, b_b, c_b, lo_b, hi_b, fl))
    )
    return inner


def colour_sensitivity(
    var_coeffs_dn2,
    clip_dn,
    ccm,
    wb_gains,
    *,
    domain="cube",
    floor: bool = True,
    out_bits: int = 8,
    n_grid: int = 32,
    clip_output: bool = False,
    lower: str = "dark_noise",
    colour_space: str = "as given by the CCM",
) -> ColourSensitivity:
    """Colour sensitivity per draw, with the choices it was computed with.

    Parameters
    ----------
    var_coeffs_dn2 : (n_draws, 4, 3): per channel R, Gr, Gb, B the raw variance
        ``σ²(S) = c0 + c1·S + c2·S²`` (DN²) at raw signal S (DN above black).
    clip_dn : (n_draws, 4) or (n_draws,): the raw clip level (DN above black).
    ccm : (3, 3) raw white-balanced RGB → output colour space, or (n_draws, 3, 3).
    wb_gains : (3,) or (n_draws, 3): white-balance gains of R, G, B.
    domain : ``"cube"`` (the raw cube from each channel's dark noise floor to its clip) or an
        ``(n, 3)`` array of raw R, G, B responses of a reflectance set (the cube ∩ their cone).
    floor : Eq. 7's ``max(σ̄, 1)`` on the ``2^out_bits``-level grid (False: no floor).
    clip_output : drop the colours that leave ``[0, white]`` in the output after M.
    lower : ``"dark_noise"`` (each raw axis starts at σ_c(0), as Eq. 2/7) or ``"zero"``.
    n_grid : Gauss-Legendre nodes per axis on the (t_R, t_G) plane (the B axis is exact).
    """
    rgb, clip3, ccm_d, wb_d = checked_inputs(var_coeffs_dn2, clip_dn, ccm, wb_gains)
    n = rgb.shape[0]
    if lower not in ("dark_noise", "zero"):
        raise ValueError(f"lower must be 'dark_noise' or 'zero', got {lower!r}")
    if isinstance(domain, str):
        if domain != "cube":
            raise ValueError(f"domain must be 'cube' or an (n, 3) array of raw responses, got {domain!r}")
        cone, domain_desc = None, "the full raw cube (each channel from its dark noise floor to its clip)"
    else:
        cone = _cone_halfspaces(domain)
        domain_desc = f"the raw cube ∩ the cone of {np.shape(domain)[0]} reflectance responses"
    n_levels = float(2**out_bits)
    nodes = _unit_gauss_legendre(int(n_grid))
    bits = np.empty(n)

    # one thread: on two threads (numpy releasing the GIL) the same CS took 1.5x the wall time on the
    # project's 2-core VM, the node arrays being small enough to stay in the core's cache
    for i in range(0, n, _DRAW_CHUNK):
        sl = slice(i, i + _DRAW_CHUNK)
        bits[sl] = _cs_chunk(rgb[sl], clip3[sl], ccm_d[sl], wb_d[sl], floor, n_levels, clip_output, cone, nodes, lower)
    choices = {
        "definition": CS_DEFINITION,
        "colour_space": colour_space,
        "domain": domain_desc,
        "lower_end": "dark noise floor σ(0)" if lower == "dark_noise" else "zero signal",
        "floor": f"max(σ̄, 1) on a {int(n_levels)}-level ({out_bits}-bit-equivalent) grid per output channel"
        if floor
        else "none",
        "clip_output": bool(clip_output),
        "clipping": "after M: colours outside [0, white] in the output are not counted (as in an output image)"
        if clip_output
        else "none: every colour of the domain counts, also beyond the output's [0, white] (a noise-amplifying M "
        "then raises CS)",
        "green": "G = mean of Gr and Gb at a common signal (variance (σ_Gr² + σ_Gb²)/4)",
        "ccm_uncertain": bool(np.ndim(ccm) == 3),
        "wb_uncertain": bool(np.ndim(wb_gains) == 2),
        "n_grid": int(n_grid),
        "max_bits": 3 * out_bits if (floor and clip_output) else None,
    }
    return ColourSensitivity(bits=bits, choices=choices)


def colour_sensitivity_bits(
    var_coeffs_dn2, clip_dn, ccm, wb_gains, *, domain="cube", floor=True, out_bits=8, n_grid=32, **kw
):
    """CS draws (bits), shape (n_draws,): :func:`colour_sensitivity`'s ``.bits`` (its ``.choices``
    state the definition, domain, floor and grid)."""
    return colour_sensitivity(
        var_coeffs_dn2, clip_dn, ccm, wb_gains, domain=domain, floor=floor, out_bits=out_bits, n_grid=n_grid, **kw
    ).bits
