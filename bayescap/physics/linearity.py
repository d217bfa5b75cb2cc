"""EMVA 1288's linearity error LE of a response curve.

The standard fits the line ``a·μp + b`` to the mean signal over the rows between 5 % and 95 % of
the saturation signal, minimising the relative deviations, and reports
``LE = (max δ − min δ)/2`` with ``δ = 100·(μy − fit)/fit`` (%). :func:`linearity_error_percent`
applies the same recipe to a response ``S(x)`` sampled on a uniform grid of the linear signal
``x`` (which the photon count is proportional to), one curve per posterior draw, so LE gets an
interval.
"""

from __future__ import annotations

import numpy as np

__all__ = ["relative_line_fit", "linearity_error_percent"]


def relative_line_fit(X, Y):
    """The line ``a·X + b`` minimising Σ((Y − aX − b)/Y)², along the last axis of ``Y`` (X (m,),
    Y (..., m)): returns (a, b) of shape (...)."""
    X = np.asarray(X, float)
    Y = np.asarray(Y, float)
    xy = np.sum(X / Y, axis=-1)
    xy2 = np.sum(X / Y**2, axis=-1)
    x2y2 = np.sum((X / Y) ** 2, axis=-1)
    _y = np.sum(1.0 / Y, axis=-1)
    _y2 = np.sum(1.0 / Y**2, axis=-1)
    b = (xy * xy2 - x2y2 * _y) / (xy2**2 - x2y2 * _y2)
    a = (xy - b * xy2) / x2y2
    return a, b


def linearity_error_percent(response, x_sat, n_points=64):
    """LE (%) of the response ``response(x)`` (a callable taking x (1, m) and returning (n, m),
    one curve per draw) over 5–95 % of the saturation's linear signal ``x_sat`` ((n,) or scalar):
    per draw, LE = (max δ − min δ)/2 of the relative deviations from the standard's line."""
    x_sat = np.atleast_1d(np.asarray(x_sat, float))[:, None]
    u = np.linspace(0.05, 0.95, n_points)[None, :]
    x = u * x_sat  # (n, m)
    Y = response(x)
    a, b = relative_line_fit(u[0], Y)  # the grid in units of x_sat (a line in x is a line in u)
    fit = a[..., None] * u + b[..., None]
    dev = 100.0 * (Y - fit) / fit
    return 0.5 * (dev.max(axis=-1) - dev.min(axis=-1))
