"""Proposals of the fast path beyond the Laplace t: the tail probe and the defensive components it
calls for (the clip floor, long one-sided tails, a tail paired with the clip floor), and the
targeted top-up's t components aimed at the interval ends whose Monte Carlo error is too large."""

from __future__ import annotations

import numpy as np

from bayescap.inference.coordinates import SamplerCoordinates
from bayescap.inference.curvature import _proposal_cov
from bayescap.inference.end_errors import _END_PROBS, _end_errors
from bayescap.inference.importance import _moment_matched, _t_logpdf, student_t_draws


def _floor_top(x_map, c1, j):
    """log of the clip floor's reach above the lower bound: the MAP plus 3 Laplace sds in z."""
    return float(x_map[j] + 3.0 * np.sqrt(c1[j, j]))


def _clip_floor_proposal(model, x_map, c1, nu):
    """Defensive proposal for the clip level near its lower bound, in :class:`SamplerCoordinates`.

    Where the clip's posterior density stays up down to its data-derived lower bound ``lo`` (the
    well clips just above the last unclipped row), ``z = log(clip − lo)`` has a long exponential
    left tail that a t around the mode does not reach: on a simulated 10-bit sensor the MCMC put
    2.5 % of the mass below z = −3.85 where 48 000 t draws put 0.1 % below −3.22,
    and the clip spread's lower interval end came out ~0.2 of
    the width too high with k̂ 0.4–0.5 (k̂ cannot see a region no draw visits). This component draws ``clip − lo`` uniform on (0, e^{z_MAP + 3 sd})
    and the other coordinates from the Laplace t's marginal (Hesterberg 1995, defensive importance
    sampling). Returns (draw(n, rng) -> (z, log q), logpdf(z))."""
    D = x_map.size
    j = model.j
    oth = np.array([i for i in range(D) if i != j], int)
    m_o, c_o = x_map[oth], c1[np.ix_(oth, oth)]
    log_a = _floor_top(x_map, c1, j)

    def draw(n, rng):
        xo, lqo = student_t_draws(m_o, c_o, nu, n, rng)
        z = np.empty((n, D))
        z[:, oth] = xo
        z[:, j] = log_a + np.log1p(-rng.random(n))  # log of a uniform on (0, 1]
        return z, lqo + (z[:, j] - log_a)

    t_o = _t_logpdf(m_o, c_o, nu)

    def logpdf(z):
        z = np.atleast_2d(z)
        out = t_o(z[:, oth]) + (z[:, j] - log_a)
        return np.where(z[:, j] <= log_a, out, -np.inf)

    return draw, logpdf


#: where :func:`_tail_probe` looks, in Laplace sds from the MAP, and how far a tail must reach
_TAIL_GRID = np.array([3.0, 4.5, 6.0, 8.0, 11.0, 16.0, 24.0, 36.0])
_TAIL_DROP = 10.0  # a tail reaches as far as log p stays within this of the MAP's (nats)
_TAIL_MIN_REACH = 6.0  # a Gaussian reaches 4.47 sd: beyond 6, the Laplace t under-covers the tail


def _tail_probe(model, x_map, lp_map, cov, skip=()):
    """Long one-sided tails of the posterior that the Laplace t does not reach.

    For every coordinate j and side, log p on two rays from the MAP, at the multiples
    :data:`_TAIL_GRID` of the Laplace sd of x_j: along the axis (the others at the MAP) and along
    the Laplace conditional line (the others at their Laplace conditional mean,
    ``x_MAP + s·Σ[:, j]/√Σ_jj``). A Gaussian posterior drops by s²/2 on the line, so stays within
    :data:`_TAIL_DROP` (10 nats) of the MAP out to 4.5 sd. A scale parameter the data bound on one
    side only (a dark current, a clip spread or a discrepancy that may be zero) has a posterior
    that follows its prior far out on the other side: on the bundled Basler, log p is within
    10 nats of the MAP out to 16 sd below the MAP in log(clip spread) and log(DSNU), where the
    importance proposals put almost no draw (``docs/performance.md``, "The fast
    preset"). One ``log_prob`` call (4·D·8 points; the axis ray is left out where it is the line).
    Returns ``[(j, side, direction (D,), reach in sds), ...]`` for the rays that stay within 10 nats
    beyond :data:`_TAIL_MIN_REACH` sds (the better of the two rays of a side), ``skip`` a set of
    (j, side) to leave out."""
    D = x_map.size
    sd = np.sqrt(np.diag(cov))
    G = _TAIL_GRID
    rays = []
    for j in range(D):
        line = cov[:, j] / sd[j]  # one Laplace sd of x_j, the others conditional
        axis = np.zeros(D)
        axis[j] = sd[j]
        dirs = [line] if np.array_equal(line, axis) else [line, axis]
        for side in (-1.0, 1.0):
            if (j, side) not in skip:
                rays += [(j, side, side * v) for v in dirs]
    if not rays:
        return []
    pts = x_map + (G[None, :, None] * np.array([r[2] for r in rays])[:, None, :]).reshape(-1, D)
    with np.errstate(all="ignore"):
        drop = (model.log_prob(pts) - lp_map).reshape(len(rays), G.size)
    drop = np.where(np.isfinite(drop), drop, -np.inf)
    best = {}
    for (j, side, v), dr in zip(rays, drop):
        above = dr >= -_TAIL_DROP
        # the reach: the last grid point within the drop, before the first one beyond it
        n_in = int(np.argmin(above)) if not above.all() else G.size
        if n_in == 0:
            continue
        reach = G[n_in - 1]
        if n_in < G.size and np.isfinite(dr[n_in]):  # linear interpolation to the crossing
            a, b = dr[n_in - 1], dr[n_in]
            reach += (G[n_in] - G[n_in - 1]) * (a + _TAIL_DROP) / (a - b)
        if reach > _TAIL_MIN_REACH and reach > best.get((j, side), (0.0, None))[0]:
            best[(j, side)] = (reach, v)
    return [(j, side, v, reach) for (j, side), (reach, v) in sorted(best.items())]


def _coord_name(model, j):
    names = getattr(model, "names", None)
    n = names[j] if names is not None and j < len(names) else f"x{j}"
    if isinstance(model, SamplerCoordinates):
        n = {model.j: "log(clip_dn - lower bound)", model.q: "log(qe)"}.get(j, n)
    return n


def _tail_entry(model, tail, n_draws, suffix=""):
    """A tail of :func:`_tail_probe` (or a pair with the clip floor) as the diagnostics list it."""
    j, side, _, reach = tail
    return {
        "parameter": _coord_name(model, j) + suffix,
        "side": "lower" if side < 0 else "upper",
        "reach_sd": round(float(reach), 2),
        "n_draws": int(n_draws),
    }


def _tail_proposal(x_map, c1, nu, j, direction, reach):
    """Defensive proposal for one long one-sided tail found by :func:`_tail_probe`: the distance s
    (in Laplace sds of x_j) uniform on (0, 1.25·reach) along ``direction`` from the MAP, and the
    other coordinates a Laplace t about that ray: the conditional covariance of the Laplace t given
    x_j when the ray is the conditional line, its marginal when the ray is the axis (the others held
    at the MAP). :func:`_clip_floor_proposal` is the same idea for the clip level. Returns
    (draw(n, rng) -> (x, log q), logpdf(x))."""
    D = x_map.size
    oth = np.array([i for i in range(D) if i != j], int)
    sd_j = float(np.sqrt(c1[j, j]))
    step = np.asarray(direction, float) / direction[j]  # per unit of x_j − x_MAP,j
    side = float(np.sign(direction[j]))
    top = 1.25 * reach * sd_j  # the range of |x_j − x_MAP,j|
    c_o = c1[np.ix_(oth, oth)]
    if np.count_nonzero(step[oth]):  # the conditional line
        c_o = c_o - np.outer(c1[oth, j], c1[j, oth]) / c1[j, j]
    c_o = _proposal_cov(c_o, 1.0)
    zero = np.zeros(oth.size)

    def draw(n, rng):
        d = side * top * rng.random(n)
        eo, lqo = student_t_draws(zero, c_o, nu, n, rng)
        x = x_map + d[:, None] * step
        x[:, oth] += eo
        return x, lqo - np.log(top)

    t_o = _t_logpdf(zero, c_o, nu)

    def logpdf(x):
        x = np.atleast_2d(x)
        d = x[:, j] - x_map[j]
        r = x[:, oth] - (x_map[oth] + d[:, None] * step[oth])
        out = t_o(r) - np.log(top)
        return np.where((side * d >= 0) & (side * d <= top), out, -np.inf)

    return draw, logpdf


def _pair_proposal(x_map, c1, nu, axis, floor):
    """Defensive proposal for a long tail meeting the clip floor: coordinate ``axis = (j, side,
    reach)`` uniform on its side out to 1.25 reach Laplace sds, the clip (``floor = (k, log_a)``) as
    in :func:`_clip_floor_proposal`, the other coordinates from the Laplace t's marginal.

    On a sensor with a sharp clip edge (a simulated 10-bit, 878 e⁻ well), the posterior's draws in
    the clip spread's lower tail have the clip level spread down towards its bound: a corner that
    neither the floor (the clip spread near its mode) nor the clip spread's own tail proposal (the
    clip near its mode) reaches, and where the clip spread's lower interval end comes out
    0.04–0.11 of the width too high with k̂ ≈ 0. Returns (draw(n, rng) -> (x, log q), logpdf(x))."""
    D = x_map.size
    j, side, reach = int(axis[0]), float(axis[1]), float(axis[2])
    k, log_a = floor
    top = 1.25 * reach * np.sqrt(c1[j, j])
    oth = np.array([i for i in range(D) if i not in (j, k)], int)
    m_o, c_o = x_map[oth], c1[np.ix_(oth, oth)]

    def draw(n, rng):
        x = np.empty((n, D))
        xo, lq = student_t_draws(m_o, c_o, nu, n, rng)
        x[:, oth] = xo
        x[:, j] = x_map[j] + side * top * rng.random(n)
        x[:, k] = log_a + np.log1p(-rng.random(n))
        return x, lq - np.log(top) + (x[:, k] - log_a)

    t_o = _t_logpdf(m_o, c_o, nu)

    def logpdf(x):
        x = np.atleast_2d(x)
        d = side * (x[:, j] - x_map[j])
        out = t_o(x[:, oth]) - np.log(top) + (x[:, k] - log_a)
        return np.where((d >= 0) & (d <= top) & (x[:, k] <= log_a), out, -np.inf)

    return draw, logpdf


def _end_components(xk, wk, vals, mcse, target, n_resampled, inflation, max_components, ends=None):
    """Proposals aimed at the interval ends whose predicted Monte Carlo error is above ``target``
    (the targeted top-up of :class:`FastSettings`, ``topup="targeted"``).

    The importance density that estimates P(v ≤ q) best is ∝ p(x)·|1{v ≤ q} − P| (Owen 2013,
    §9.2): half of it lies beyond the end. A moment-matched t over the whole posterior puts only
    ~2.5 % of its draws there, so topping up with it cuts an end's error as 1/√N; this puts a t at
    the weighted moments of the draws beyond the quantile at twice the end's tail probability (so
    that the end itself is inside), for the worst ends first, at most ``max_components`` of them,
    one per region (an end whose region shares half its weight with a chosen one is left to that
    one: capacity's lower end and TR's are often the same draws). Regions with an importance ESS
    below D + 2 get none. ``mcse``: {name: worst end's error} of ``vals`` (:func:`interval_end_mcse`),
    to look at those above ``target`` only; ``ends``: {name: [error of each end]} of the same draws
    (:func:`_end_table`), computed here when not given. Returns [(location, scale), ...] (worst end
    first)."""
    D = xk.shape[1]
    cands = []
    for name, v in vals.items():
        if not mcse.get(name, 0.0) > target:
            continue
        errs = _end_errors(v, wk, _END_PROBS, n_resampled) if ends is None else ends[name]
        if errs is None or not np.all(np.isfinite(errs)):
            continue
        cands += [(e, name, p) for e, p in zip(errs, _END_PROBS) if e > target]
    cands.sort(key=lambda c: -c[0])
    out, masks = [], []
    for _, name, p in cands:
        v = np.asarray(vals[name], float)
        o = np.argsort(v)
        F = np.cumsum(wk[o])
        F /= F[-1]
        if p < 0.5:
            mask = v <= np.interp(2.0 * p, F, v[o])
        else:
            mask = v >= np.interp(1.0 - 2.0 * (1.0 - p), F, v[o])
        wm = wk[mask]
        tot = wm.sum()
        if not tot > 0 or any(np.sum(wk[mask & m]) >= 0.5 * tot for m in masks):
            continue
        wm = wm / tot
        if 1.0 / np.sum(wm * wm) < D + 2:
            continue
        mc = _moment_matched(xk[mask], wm, None, inflation)
        if mc is None:
            continue
        out.append(mc)
        masks.append(mask)
        if len(out) >= max_components:
            break
    return out
