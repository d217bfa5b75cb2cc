"""The rich log-slope of :mod:`bayescap.model.response`: a quadratic B-spline, its knots closer
together towards the clip.

L(u) = Σ_k θ_k B_k(u), the B-splines of the clamped knot vector on :data:`SPLINE_INTERVALS`
intervals of [0, 1] less the first (the only one not zero at u = 0: L(0) = 0, so K stays the
small-signal gain). Local: a knee or a kink bends L only within about an interval of it. C¹, so
exp(L) and its derivative are continuous for the response's Hermite table, whose nodes include the
knots (:func:`knots`: 1 − (1 − j/n)², on the 128-interval table's grid for n = 8).

**Why the knots crowd towards u = 1.** A response that saturates softly before the ADC clips (a
knee: slope 1 − tanh²) has a log-slope L = −log(1 − ((S − S_k)/w)²) in the output S: it rises without
bound towards the asymptote, so most of its change is in the last few per cent of the signal (on
the non-linear zoo's 16-bit soft knee, L goes from 0.5 to 2.0 over the last 5 % of S, and those 5 %
hold 14 % of the clip charge). Uniform knots (one interval per 12.5 % of S) cannot follow it: the
fit's h(clip), hence ``full_well_e``, comes out low by more than its interval allows (docs/
real_sensors.md, "The soft knee at the clip"). Knots at 1 − (1 − j/n)² make the last interval 1/n² wide (1.6 %) and the first
2/n − 1/n² (23 %): a smooth compression (quadratic, cubic) needs no more resolution low down,
and a kink (a two-slope ADC) is taken up within an interval wherever it falls.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SPLINE_INTERVALS", "RICH_BASIS", "knots", "spline_basis", "is_spline", "h_table_spline"]

#: the log-slope when the data show a shape a degree-4 polynomial cannot follow (a knee or a kink in
#: the top rows: :func:`bayescap.model.response.response_degree_evidence`): a quadratic B-spline on this many
#: intervals of [0, 1] (:func:`knots`; local: a kink bends L only within about one interval of it, where a global
#: polynomial's overshoot reaches down into the low rows and pulls K; C¹, so h' and h'' stay
#: continuous for the table's Hermite data)
SPLINE_INTERVALS = 8
#: ... its coefficients: the B-splines of the clamped knot vector less the first (the only one not
#: zero at u = 0, so L(0) = 0 and K stays the small-signal gain). Any other number of coefficients
#: is a Bernstein log-slope of that degree (results saved with a degree-8 polynomial read as before)
RICH_BASIS = SPLINE_INTERVALS + 1


def knots(n=SPLINE_INTERVALS):
    """The spline's n + 1 distinct knots on [0, 1]: 1 − (1 − j/n)², j = 0..n (module docstring)."""
    return 1.0 - (1.0 - np.arange(n + 1) / n) ** 2


def spline_basis(u, derivative=False):
    """The :data:`RICH_BASIS` quadratic B-splines (or their derivatives) at ``u`` (clipped to
    [0, 1]): u's shape + (m,)."""
    from scipy.interpolate import BSpline

    n = SPLINE_INTERVALS
    t = np.concatenate([[0.0, 0.0], knots(n), [1.0, 1.0]])
    b = BSpline(t, np.eye(n + 2)[:, 1:], 2, extrapolate=False)
    if derivative:
        b = b.derivative()
    return np.nan_to_num(b(np.clip(np.asarray(u, float), 0.0, 1.0)))


def is_spline(m):
    """Whether ``m`` log-slope coefficients are the spline's (else a Bernstein polynomial's)."""
    return m == RICH_BASIS


def _spline_nodes(n_table):
    """The spline basis and its derivative at the table's nodes, (m, n_table + 1) each, once."""
    out = _SPLINE_NODES.get(n_table)
    if out is None:
        g = np.linspace(0.0, 1.0, n_table + 1)
        out = (np.ascontiguousarray(spline_basis(g).T), np.ascontiguousarray(spline_basis(g, True).T))
        for a in out:
            a.setflags(write=False)
        out = _SPLINE_NODES.setdefault(n_table, out)
    return out


_SPLINE_NODES = {}


def h_table_spline(theta, n_table):
    """``bayescap.model.response._h_table`` for the spline log-slope: L and L' at the nodes as sums
    over the basis, element by element (the same numbers whatever the number of draws)."""
    B, dB = _spline_nodes(n_table)
    n, m = theta.shape
    h = 1.0 / n_table
    L = np.zeros((n, n_table + 1))
    dL = np.zeros((n, n_table + 1))
    for k in range(m):
        tk = theta[:, k : k + 1]
        L += tk * B[k]
        dL += tk * dB[k]
    np.exp(L, out=L)
    dL *= L
    s = 0.5 * h * (L[:, :-1] + L[:, 1:]) + (h * h / 12.0) * (dL[:, :-1] - dL[:, 1:])
    H = np.empty((n, n_table + 1))
    H[:, 0] = 0.0
    np.cumsum(s, axis=1, out=H[:, 1:])
    return H, L * h, dL * h
