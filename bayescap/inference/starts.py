"""Where the optimisers start: fixed perturbations of the initial guess, the extra starts of the
multi-start (a larger variance discrepancy, a clip spread off its prior cap), and the error raised
when no start has a finite log posterior."""

from __future__ import annotations

import numpy as np


def _no_finite_start(target, x0):
    """Raise the error for an optimiser none of whose starts has a finite log posterior: a
    :class:`~bayescap.exceptions.PTCInputError` naming the file, row and column of the first observation
    whose likelihood is not finite at ``x0`` when ``target`` is (or wraps) a :class:`PTCModel` that
    finds one (a zero spatial variance, an exposure time of 1e308 s: values the reader accepts and no
    parameter can explain); a RuntimeError otherwise."""
    model = target if hasattr(target, "nonfinite_observations") else getattr(target, "model", None)
    bad = []
    if model is not None and hasattr(model, "nonfinite_observations"):
        x = np.asarray(x0, float)
        if model is not target and hasattr(target, "to_x"):
            x = target.to_x(x)
        bad = model.nonfinite_observations(x)
    if not bad:
        raise RuntimeError(
            "no finite starting point for the optimiser: the data may be inconsistent "
            "with the model (check the units of the columns)"
        )
    from bayescap.exceptions import PTCInputError

    block, row, column, obs, mod = bad[0]
    others = sorted({r for _, r, _, _, _ in bad[1:] if r != row})
    more = f"; rows {', '.join(map(str, others[:10]))}{' ...' if len(others) > 10 else ''} likewise" if others else ""
    raise PTCInputError(
        f"the model gives the value {obs:.6g} no finite likelihood at the optimiser's start "
        f"(its prediction there: {mod:.6g}), so nothing was fitted: check this row's values "
        f"and their units{more}",
        path=model.data.source,
        row=row,
        column=column,
    )


#: shifts of log f (the variance discrepancy) for the extra optimiser starts of :func:`laplace_start`:
#: f ten times the initial guess's 1 %. A large discrepancy flattens the likelihood (like a higher
#: temperature), so the optimiser crosses what would trap it and then lowers f. Measured on 29
#: sensors (20 simulated Gpixel ROIs, the 5 benchmark CSVs, the Basler, 3 speed_accuracy sensors):
#: this start alone found the higher optimum on all 3 where the first start had missed it
#: (+1.5, +5.7 and +136 nats); a start at f/10 found none the other two did not
#: (docs/model.md, "Sampling").
MAP_START_LOG_F_SHIFTS = (2.3,)


#: shift of log τ (the clip spread) for the extra optimiser start of :func:`_map_starts` when the
#: initial guess puts τ at its prior cap (``tau_max_frac`` of the clip level). The cap is a wall
#: (log prior −∞ beyond it), and a start on it stays there: on a simulated sensor both optimisers
#: stop on the wall, 136-264 nats below the mode at τ 7 times smaller. log τ − 2 reaches the mode
#: from both f starts; so does −3.
MAP_START_LOG_TAU_SHIFT = -2.0


def _map_starts(model, x0=None):
    """Extra starting points for :func:`laplace_start`: the initial guess with the variance
    discrepancy f shifted by :data:`MAP_START_LOG_F_SHIFTS` (or the guess itself without an f term),
    and, when the guess's clip spread τ sits within a factor e of its prior cap, the guess with
    log τ shifted by :data:`MAP_START_LOG_TAU_SHIFT`.
    The discrepancy and the outlier mixture trade off: a large f explains a deviant row, a small f
    with the row as an outlier is another local optimum, and the start decides which one a local
    optimiser finds (docs/model.md, "Sampling"). ``x0``: the initial guess when the
    caller has it already (it costs ~3 ms on the Basler: a fast fit computed it twice)."""
    x0 = np.array(model.initial_guess() if x0 is None else x0, dtype=float)  # a copy
    names = list(getattr(model, "names", []))
    out = []
    if "log_f" in names:
        j = names.index("log_f")
        for df in MAP_START_LOG_F_SHIFTS:
            s = x0.copy()
            s[j] += df
            out.append(s)
    else:
        out.append(x0)
    if "log_tau" in names and hasattr(model, "tau_cap_dn"):
        if np.exp(x0[names.index("log_tau")]) > float(model.tau_cap_dn(x0)[0]) / np.e:
            s = x0.copy()
            s[names.index("log_tau")] += MAP_START_LOG_TAU_SHIFT
            out.append(s)
    out += _prior_median_starts(model, x0, names)
    return out


#: the coordinate of each half-normal scale parameter, for :func:`_prior_median_starts`
_SCALE_COORDINATES = {
    "read_noise_e": ("log_read", "read_scale_e"),
    "dark_noise_e": ("log_dark_noise", "read_scale_e"),
    "dark_current_e_per_s": ("log_dc", "dark_current_scale_e_per_s"),
    "prnu_percent": ("log_prnu", "prnu_scale"),
    "dsnu_e": ("log_dsnu", "dsnu_scale_e"),
}


def _prior_median_starts(model, x0, names):
    """One more start when the data-driven guess of a half-normal scale (dark current, read noise,
    ...) lay beyond the prior's bulk and was moved to its edge (``initial_guess(projections=True)``):
    the guess with every such coordinate at the prior's median (0.674 scales) instead. A guess that
    far out says the data and the prior disagree (often a unit); the optimiser then climbs from
    both ends of that coordinate's plausible range."""
    if not hasattr(model, "initial_guess") or not hasattr(model, "PRIOR"):
        return []
    try:
        _, moved = model.initial_guess(projections=True)
    except TypeError:  # a model without the projections
        return []
    s = np.array(x0, float)
    for p in moved:
        coord, key = _SCALE_COORDINATES.get(p["parameter"], (None, None))
        if coord in names:
            s[names.index(coord)] = np.log(0.674 * model.PRIOR[key])
    return [s] if moved else []


def _restart_points(x0, n_restarts):
    """:func:`find_map`'s fixed perturbations of the initial guess."""
    offsets = np.linspace(-1, 1, x0.size)
    return [x0 + (0.3 * (r + 1)) * np.roll(offsets, r) * (1 if r % 2 == 0 else -1) for r in range(n_restarts)]
