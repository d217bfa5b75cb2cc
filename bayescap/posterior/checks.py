"""Checks of the data against a fitted model: outlier rows, a variance turnover the model has no
term for, and dark rows clipped at the ADC's zero."""

from __future__ import annotations

import numpy as np

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
        if self.outliers:
            desc = ", ".join(f"row {o['row']} ({o['block']}, P = {o['probability']:.2f})" for o in self.outliers)
            self.notes.append(f"outlier rows (down-weighted by the mixture, not removed): {desc}")
        self._check_dark_floor()
        # variance turning over below the clip: the top unclipped rows sit well below the model
        obs, model, k, _ = pred["bright_var"]
        med = np.median(model, axis=0)
        kk = np.median(np.broadcast_to(k, model.shape), axis=0)
        z = (obs - med) / (med / np.sqrt(kk))
        order = np.argsort(m.s_obs)
        top = order[-4:]
        out_rows = {o["row"] for o in self.outliers}
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
