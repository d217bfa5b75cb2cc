"""Checks of the data against a fitted model: outlier rows, a variance turnover the model has no
term for, and dark rows clipped at the ADC's zero."""

from __future__ import annotations

import numpy as np

from bayescap.model.terms import SKEWED_CLIP_E

__all__ = ["ChecksMixin"]


class ChecksMixin:
    """The data checks of :class:`~bayescap.posterior.FitResult` (its ``model`` and ``chains``),
    written to ``outliers``, ``notes`` and ``flags``."""

    def _check_rows(self, n_draws=400):
        """Outlier probabilities per row, and systematic residuals the model has no term for."""
        m = self.model
        E, S, W, D = self.chains.chain.shape
        th = self.chains.chain.reshape(-1, D)[self.thin_index(n_draws)]
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            pred = m.predict(th)  # shared by the outlier probabilities and the turnover check
        self.outliers = []
        for block, (rows, prob) in m.outlier_probabilities(th, pred).items():
            for r, pr in zip(rows, prob):
                if pr > 0.5:
                    self.outliers.append({"row": int(r), "block": block, "probability": float(pr)})
        down_weighted = {o["row"] for o in self.outliers}
        self._separate_systematic_rows(_residual_z(m, pred))
        if self.outliers:
            desc = ", ".join(f"row {o['row']} ({o['block']}, P = {o['probability']:.2f})" for o in self.outliers)
            self.notes.append(f"outlier rows (down-weighted by the mixture, not removed): {desc}")
        self._check_dark_floor()
        self._check_clip_skew()
        # variance turning over below the clip: the top unclipped rows sit well below the model
        obs, model, k, _ = pred["bright_var"]
        med = np.median(model, axis=0)
        kk = np.median(np.broadcast_to(k, model.shape), axis=0)
        z = (obs - med) / (med / np.sqrt(kk))
        order = np.argsort(m.s_obs)
        top = order[-4:]
        out_rows = down_weighted
        rows = m.observation_rows("bright_var")
        low = [i for i in top if z[i] < -4 and int(rows[i]) not in out_rows]
        if len(low) >= 2 and m.terms.clip in ("none", "adc"):
            self.flags["variance_turnover_unexplained"] = [int(rows[i]) for i in low]
            self.notes.append(
                "the variance turns over below the clip level on rows "
                + ", ".join(str(int(rows[i])) for i in low)
                + ": the model has no term for that (non-linearity or a soft clip before "
                "full well?); treat full well and the top of the range with caution"
            )

    #: a row with at least this fraction of its pixels clipped sits in the clip (see below): its
    #: mean and variance then depend on the pixels' distribution at the clip, which the model takes as
    #: normal (half-clipped rows of bent responses misfit by tens of sd while every other row fits)
    NEAR_CLIP_FRACTION = 0.1
    #: ... and with at least this fraction, only a few unclipped pixels are left
    MOSTLY_CLIPPED = 0.9
    #: this many neighbouring rows along the signal departing together: a shape, not outliers
    RUN_LENGTH = 3
    #: a row departs with a down-weighted neighbour when its residual in the same block has the same
    #: sign and at least this many standard deviations (a corrupted row's two neighbours both do
    #: so by chance with probability 0.16² = 2.5 %)
    DEPART_Z = 1.0

    def _separate_systematic_rows(self, residual_z=None):
        """Rows the mixture down-weights that are not outliers of the measurement, moved from
        ``outliers`` to flags with a note: rows in the clip (``frac_saturated`` ≥
        :data:`NEAR_CLIP_FRACTION`; without that column, the rows past the PTC's turnoff), where the
        model of the clipped pixels' distribution (a normal tail under the response's local slope) is
        an approximation; and runs of at least :data:`RUN_LENGTH` neighbouring rows along the signal
        that depart from the model together, a shape the model does not follow (a knee, a kink):
        down-weighted rows, and (``residual_z``: {block: {row: median standardised residual}})
        rows whose residual in a down-weighted row's block has its sign and at least
        :data:`DEPART_Z` sd. Neither is a corrupted row, and the mixture's down-weighting of them
        means the intervals assume the model's shape there."""
        d = self.model.data
        if not self.outliers:
            return
        pos = {
            int(r): i for i, r in enumerate(d.row_numbers if d.row_numbers is not None else range(1, d.n_levels + 1))
        }
        fs = d.frac_saturated
        if fs is not None:
            clipped = {r for r, i in pos.items() if fs[i] >= self.NEAR_CLIP_FRACTION}
        else:  # no frac_saturated column (a mean/variance table): the rows past the PTC's turnoff
            from bayescap.posterior.derived import ptc_turnoff

            _, past = ptc_turnoff(d.signal_dn, d.temporal_var_dn2)
            clipped = {int(d.row_label(k)) for k in past}
        near = sorted({o["row"] for o in self.outliers if o["row"] in clipped})
        rest = sorted({o["row"] for o in self.outliers} - set(near))
        order = np.argsort(d.mean_dn - d.dark_mean_dn, kind="stable")
        rank = {int(r): k for k, r in enumerate(np.asarray(list(pos))[order])}
        runs = _neighbours(set(rest), rank, self.RUN_LENGTH)
        for block, z in (residual_z or {}).items():
            flagged = {o["row"] for o in self.outliers if o["block"] == block and o["row"] in rest and o["row"] in z}
            for sign in (1.0, -1.0):
                mine = {r for r in flagged if sign * z[r] > 0}
                if mine:
                    with_them = mine | {r for r, v in z.items() if sign * v >= self.DEPART_Z}
                    runs += [[r for r in run if r in mine] for run in _neighbours(with_them, rank, self.RUN_LENGTH)]
        runs = [run for run in runs if run]
        in_runs = {r for run in runs for r in run}
        runs = _neighbours(in_runs, rank, 1, gap=2)  # for the note: runs a row apart told as one
        if near:
            self.flags["rows_in_the_clip_misfit"] = near
            few_left = fs is None or all(fs[pos[r]] >= self.MOSTLY_CLIPPED for r in near)
            self.notes.append(
                "rows "
                + ", ".join(map(str, near))
                + (
                    " lie past the PTC's turnoff, at the clip"
                    if fs is None
                    else " have most of their pixels clipped"
                    if few_left
                    else " have a tenth or more of their pixels clipped"
                )
                + " and fit the model poorly: "
                + (
                    "there the model of the few unclipped pixels is an approximation"
                    if few_left
                    else "there the model of the pixels at the clip (a normal distribution under the response's "
                    "local slope) is an approximation"
                )
                + "; they are down-weighted, not outliers of the measurement"
            )
        if runs:
            self.flags["structured_residuals"] = [r for run in runs for r in run]
            spans = "; ".join(f"rows {run[0]}–{run[-1]}" if len(run) > 1 else f"row {run[0]}" for run in runs)
            n_rows = len(rank)
            where = [
                "at the shortest exposures: a shutter-time offset?"
                if rank[run[-1]] < n_rows / 4
                else "near the top: a knee or a kink the response does not follow"
                if rank[run[0]] >= n_rows / 2
                else "a shape the response does not follow"
                for run in runs
            ]
            self.notes.append(
                f"neighbouring rows depart from the model together ({spans}, in order of signal; "
                + "; ".join(dict.fromkeys(where))
                + "), not outliers; they are down-weighted, so the intervals assume the model's shape there"
            )
        self.outliers = [o for o in self.outliers if o["row"] not in near and o["row"] not in in_runs]

    def _check_clip_skew(self):
        """Flag partly clipped rows at a clip of few electrons that are still in the fit (a fit
        leaves them out itself at an ADC clip, :func:`bayescap.model.terms.rows_to_fit`; a well's clip,
        or a model built on every row, keeps them). The model takes each pixel's charge
        near the clip as normal; at N electrons its Poisson skewness is 1/√N, and the clipped
        pixels' tail then differs from the normal's enough to pull K by about a percent through
        those rows (an 8-bit camera at K 0.5 e⁻/DN, clip ~95 e⁻: K 1.3 % high, its interval ±0.7 %,
        while the rows below the clip alone hold the truth)."""
        d = self.model.data
        fw = self.draws.get("full_well_e")
        fs = d.frac_saturated
        if fw is None or fs is None:
            return
        n_e = float(np.median(fw))
        partial = np.flatnonzero((fs > 1e-3) & (fs < 0.999))
        if not (n_e < SKEWED_CLIP_E and partial.size):
            return
        rows = d.row_numbers if d.row_numbers is not None else np.arange(1, d.n_levels + 1)
        self.flags["skewed_clip_tail"] = [int(rows[i]) for i in partial]
        self.notes.append(
            f"{partial.size} rows are partly clipped at a clip of about {n_e:.0f} e⁻, where the charge's Poisson "
            f"skewness (1/√N = {1 / np.sqrt(max(n_e, 1.0)):.2f}) makes the model's normal tail of the clipped pixels "
            "approximate: K and the quantities that follow it can be off by about a percent, more than their "
            "intervals say; compare a fit of the rows without clipped pixels"
        )

    #: dark rows whose mean sits fewer than this many sd (temporal and, where measured, spatial)
    #: above 0 DN: the ADC's zero clips the low tail, shrinking the dark variances (≈ 1.1 % at 2.5 sd,
    #: 4 % at 2 sd, against a ≈ 1 % sampling error), a censoring the model does not have
    DARK_FLOOR_SD = 2.5

    def _check_dark_floor(self):
        """Flag dark rows whose pixel distribution reaches the ADC's zero (black level too low for
        the read noise and DSNU): read noise and DSNU are then biased low, silently otherwise."""
        d = self.model.data
        if not d.has_dark_rows:  # a mean/variance table: no dark pairs to check
            self.dark_floor_margin_sd = float("inf")
            return
        var = np.asarray(d.dark_temporal_var_dn2, float).copy()
        if d.dark_spatial_var_dn2 is not None:
            sp = np.asarray(d.dark_spatial_var_dn2, float)
            var = np.where(np.isfinite(sp), np.maximum(var, sp), var)
        with np.errstate(divide="ignore", invalid="ignore"):
            margin = np.asarray(d.dark_mean_dn, float) / np.sqrt(np.maximum(var, 1e-12))
        low = np.nonzero(margin < self.DARK_FLOOR_SD)[0]
        self.dark_floor_margin_sd = float(np.min(margin)) if margin.size else float("inf")
        if low.size:
            rows = [int(d.row_label(i)) for i in low]
            self.flags["dark_floor_clipping"] = rows
            self.notes.append(
                f"dark mean only {float(np.min(margin[low])):.1f} sd above 0 DN on rows "
                + ", ".join(str(r) for r in rows[:8])
                + (" …" if len(rows) > 8 else "")
                + ": the ADC's zero clips the darkest pixels, so read noise and DSNU are biased low "
                "(raise the black level / offset, as EMVA 1288 requires)"
            )


def _neighbours(rows, rank, length, gap=1):
    """Groups of at least ``length`` rows of ``rows`` that follow each other along the signal
    (``rank``: row label -> position in signal order) at most ``gap`` positions apart, each in
    signal order."""
    out, cur = [], []
    for r in sorted(rows, key=lambda r: rank[r]):
        if cur and rank[r] <= rank[cur[-1]] + gap:
            cur.append(r)
        else:
            if len(cur) >= length:
                out.append(cur)
            cur = [r]
    if len(cur) >= length:
        out.append(cur)
    return out


def _residual_z(model, pred):
    """{block: {row label: median standardised residual over the draws}} of the robust blocks (a
    gamma block's sd is model/√shape)."""
    from bayescap.model.likelihood import ROBUST_BLOCKS

    out = {}
    for name in ROBUST_BLOCKS:
        if name not in pred:
            continue
        obs, mod, spread, kind = pred[name]
        mod = np.atleast_2d(mod)
        shape = (mod.shape[0], np.shape(mod)[-1])
        mod, spread, obs = (np.broadcast_to(a, shape) for a in (mod, spread, obs))
        sd = mod / np.sqrt(spread) if kind == "gamma" else spread
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.median((obs - mod) / sd, axis=0)
        out[name] = {int(r): float(v) for r, v in zip(model.observation_rows(name), z) if np.isfinite(v)}
    return out
