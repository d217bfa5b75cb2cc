"""What a fit result says about its input and its start: the plausibility warnings of the table
(:func:`bayescap.io.plausibility.plausibility_warnings`), a start that the prior had to pull in
from a far tail, walkers stranded far below the mode (left out of every interval), and bounds of
the prior that bind (a parameter piled against a hard wall)."""

from __future__ import annotations

import numpy as np

from bayescap.inference.chains import stuck_threshold, stuck_walkers
from bayescap.io.plausibility import plausibility_warnings

__all__ = ["InputsMixin", "BINDING_GAP_FRACTION"]

#: a parameter binds at a hard bound when the gap between the bound and its nearest 2.5 % point is
#: below this fraction of its 95 % width (in the sampling coordinate): the mass is piled at the wall
BINDING_GAP_FRACTION = 0.05


def _quantity(p):
    return f"{p['parameter']} {p['guess']:.3g} {p['unit']}"


#: what a wall the model names means for the result, where a generic sentence would say too little
_CONSEQUENCE = {
    ("clip_dn", "lower"): "the clip sits just above the brightest unclipped row: full well is known only to "
    "lie between that row's signal and the next row's, and its interval is cut there",
    **{
        (f"response_shape_{j}", side): "the response's slope changes by more than e^8 over the measured range: "
        "K and full well are not to be trusted; fit the rows below the bend"
        for j in range(1, 9)
        for side in ("lower", "upper")
    },
}


class InputsMixin:
    """Checks of :class:`~bayescap.posterior.FitResult` on its input and start, written to
    ``input_warnings``, ``diag``, ``notes`` and ``flags``; and the draws the summaries use."""

    # ------------------------------------------------------------------ draws of the summaries
    def _kept_mask(self):
        """Boolean mask over the flat draws (E·S·W) of the walkers not stranded, or None to keep
        all (the fast path's independent draws, or no walker stranded)."""
        c = self.chains
        if c is None or c.extra.get("method") == "laplace-is" or c.log_prob is None:
            return None
        E, S, W, D = c.chain.shape
        if W < 2:
            return None
        lp_w = np.transpose(c.log_prob, (1, 0, 2)).reshape(S, E * W)
        stuck = stuck_walkers(lp_w, D).reshape(E, W)
        if not stuck.any() or stuck.all():
            return None
        return np.broadcast_to(~stuck[:, None, :], (E, S, W)).reshape(-1)

    def _kept(self, x):
        mask = self.__dict__.get("_keep_cache", "unset")
        if isinstance(mask, str):
            mask = self._kept_mask()
            self.__dict__["_keep_cache"] = mask
        x = np.asarray(x)
        return x if mask is None or x.shape[:1] != mask.shape else x[mask]

    def summary_draws(self) -> dict:
        """The physical draws the summaries are computed from: every draw, less those of walkers
        stranded far below the mode (their values are not posterior draws and must not set an
        interval end)."""
        return {k: self._kept(v) for k, v in self.draws.items()}

    def summary_derived(self) -> dict:
        """The derived draws the summaries are computed from (as :meth:`summary_draws`)."""
        return {k: self._kept(v) for k, v in self.derived.items()}

    # ------------------------------------------------------------------ checks
    def _check_inputs(self):
        """Plausibility warnings of the input table, the start's projection into the prior,
        stranded walkers left out, and bounds that bind."""
        self.input_warnings = plausibility_warnings(self.model.data)
        self._check_start()
        self._check_stranded()
        self._check_bounds()

    def _check_start(self):
        m = self.model
        if not hasattr(m, "initial_guess"):
            return
        try:
            _, moved = m.initial_guess(projections=True)
        except TypeError:
            return
        self.diag["start_outside_prior"] = moved
        if moved:
            self.notes.append(
                "the data-driven start lay far in the prior's tail ("
                + "; ".join(f"{_quantity(p)}, {p['prior_scale_sd']:.3g} prior scales" for p in moved)
                + "): the fit started inside the prior's 99.9 % range instead; a start that far out "
                "usually means a unit problem ("
                + ("see the warnings" if self.input_warnings else "check the units of the columns")
                + ")"
            )

    def _check_stranded(self):
        mask = self._kept_mask()
        if mask is None:
            return
        E, S, W, D = self.chains.chain.shape
        n = int(E * W - mask.sum() // S)
        self.diag["walkers_left_out"] = n
        self.notes.append(
            f"{n} of {E * W} walkers stayed more than {stuck_threshold(D):.0f} nats below the mode "
            "after burn-in: their draws are left out of every interval"
        )

    def _binding(self, u, bound, side):
        """Whether draws ``u`` (sampling coordinate) pile against ``bound`` (scalar or per draw)
        on ``side`` ("upper" or "lower")."""
        u = np.asarray(u, float)
        gap = (bound - u) if side == "upper" else (u - bound)
        width = float(np.subtract(*np.quantile(u, [0.975, 0.025])))
        return bool(width > 0 and float(np.quantile(gap, 0.025)) < BINDING_GAP_FRACTION * width)

    def _check_bounds(self):
        """Flag parameters piled against a hard bound of the prior (``flags["bound_binding"]``,
        name -> {bound, side, consequence}) with a note each."""
        m = self.model
        c = self.chains
        if c is None or not hasattr(m, "idx"):
            return
        th = self._kept(c.chain.reshape(-1, c.chain.shape[-1]))
        found = {}
        if "log_tau" in m.idx and hasattr(m, "tau_cap_dn"):
            cap = np.log(m.tau_cap_dn(th))
            if self._binding(th[:, m.idx["log_tau"]], cap, "upper"):
                found["clip_spread_dn"] = {
                    "side": "upper",
                    "bound": f"{100 * m.PRIOR['tau_max_frac']:g} % of the clip level "
                    f"({float(np.median(np.exp(cap))):.4g} DN)",
                    "consequence": "the pixels roll off into saturation more gradually than the model allows: "
                    "full well and the variances of the top rows are biased (a non-linear response near "
                    "saturation?); exclude the rows near the clip to check",
                }
        if "clip_dn" in m.idx and m.clip_bounds is not None:
            lo, hi = m.clip_bounds
            if self._binding(th[:, m.idx["clip_dn"]], hi, "upper"):
                found["full_well_e"] = {
                    "side": "upper",
                    "bound": f"clip level {hi:.6g} DN",
                    "consequence": "the clip level sits at the highest value the data allow: full well is at most this",
                }
        if "qe" in m.idx:
            qhi = (m.PRIOR["qe_bounds"] or (0.0, 1.0))[1]
            if self._binding(th[:, m.idx["qe"]], qhi, "upper"):
                found["quantum_efficiency"] = {
                    "side": "upper",
                    "bound": f"{qhi:g}",
                    "consequence": "the photon counts ask for a quantum efficiency at its bound: "
                    "photons_per_pixel is likely too small (see the warnings)",
                }
        for coord, name, key in (
            ("log_read", "read_noise_e", "read_log_bounds"),
            ("log_dc", "dark_current_e_per_s", "dark_current_log_bounds"),
            ("log_prnu", "prnu_percent", "prnu_log_bounds"),
            ("log_dsnu", "dsnu_e", "dsnu_log_bounds"),
        ):
            b = m.PRIOR.get(key)
            if coord not in m.idx or b is None:
                continue
            for side, v in (("lower", np.log(b[0])), ("upper", np.log(b[1]))):
                if self._binding(th[:, m.idx[coord]], v, side):
                    found[name] = {
                        "side": side,
                        "bound": f"the prior's {side} bound {b[0 if side == 'lower' else 1]:g}",
                        "consequence": "the interval ends at the bound you set, not where the data put it",
                    }
        # every other wall the model names (:meth:`PTCModel.parameter_bounds`), judged on the draws
        # (the physical ones of ``th``, as the summaries have them)
        if hasattr(m, "binding_bounds"):
            same = {"clip_dn": "full_well_e"}
            for name, b in m.binding_bounds(self.summary_draws()).items():
                if name in found or same.get(name) in found:
                    continue
                found[name] = {
                    "side": b["side"],
                    "bound": f"{b['bound']:.4g} ({100 * b['fraction_near']:.0f} % of the draws within 1 % of it)",
                    "consequence": _CONSEQUENCE.get(
                        (name, b["side"]),
                        "its interval is cut at the bound, and what depends on it is conditional on it",
                    ),
                }
        if found:
            self.flags["bound_binding"] = found
            for name, f in found.items():
                self.notes.append(f"{name} sits at its {f['side']} bound ({f['bound']}): {f['consequence']}")
