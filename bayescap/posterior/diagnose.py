"""Convergence diagnostics of a fit result: R-hat, ESS, autocorrelation time and stuck walkers of
the MCMC chains, or Pareto k̂ and importance-sampling ESS of the fast path (Laplace–IS), and the
Monte Carlo error of every reported 95 % interval end."""

from __future__ import annotations

import warnings

import numpy as np

from bayescap.exceptions import ConvergenceWarning
from bayescap.inference.chains import stuck_threshold, stuck_walkers
from bayescap.inference.diagnostics import fast_diagnostics, interval_end_mcse_mcmc, worst_end
from bayescap.inference.end_errors import _varies, interval_end_mcse
from bayescap.posterior.summary import rerun_advice

__all__ = ["DiagnoseMixin", "IMPRECISE_END_MCSE"]

#: the start of the failed check of an interval end's Monte Carlo error (DiagnoseMixin._set_end_mcse)
_END_MCSE_FAILURE = "Monte Carlo error of a 95 % interval end"

#: an MCMC result whose preset does not check its interval ends' Monte Carlo error (``standard``, the
#: fast path's fallback) flags the quantities whose error is above this fraction of the width
#: (``flags["imprecise_interval_ends"]`` and a note). Worst ends: ``standard`` (5 walkers per
#: parameter) 0.028 in the median and 0.063 at most on 28 of 29 zoo sensors, 0.24 on the 29th, which
#: its ``end_mcse_goal`` of this value now runs on; the fallback (ESS ≥ 200) 0.024–0.073; on the
#: clip-shelf ROIs of the batch whose fast path was rejected, 0.075–0.69.
IMPRECISE_END_MCSE = 0.1
_IMPRECISE_NOTE = "imprecise interval ends:"


def _mcmc_description(st) -> str:
    """The moves the ensembles ran (:func:`bayescap.inference.mcmc._moves`): the standard and
    accurate presets mix the IndependenceMove in."""
    moves = []
    if getattr(st, "independence_fraction", 0.0) > 0:
        moves.append(
            f"IndependenceMove (Student-t ν={st.independence_nu:g}) up to "
            f"{100 * st.independence_fraction:.0f} % of steps"
        )
    moves.append("DEMove" if st.de_fraction >= 1 else "DEMove + StretchMove")
    return "emcee ensembles (" + ", ".join(moves) + "), Gamma likelihood with discrepancy"


class DiagnoseMixin:
    """The convergence checks of :class:`~bayescap.posterior.FitResult` (its ``chains``,
    ``draws``, ``derived``, ``quality`` and ``seed``), written to ``diag``, ``notes`` and ``flags``."""

    def _diagnose(self):
        if self.chains.extra.get("method") == "laplace-is":
            self._diagnose_importance()
        else:
            self._diagnose_mcmc()
        f = np.median(self.draws["variance_discrepancy"])
        if f > 0.05:
            self.notes.append(
                f"the variances scatter {100 * f:.1f} % beyond their statistical error: "
                "the model or the measurements are inadequate (check linearity, lamp "
                "stability, outlier rows)"
            )
        self._check_dark_witnesses()

    def _check_dark_witnesses(self):
        """Flag and note a disagreement of the dark current's two witnesses, the dark means and
        the dark variances (:func:`~bayescap.posterior.dark_current.dark_witness_notes`)."""
        from bayescap.posterior.dark_current import dark_current_evidence, dark_witness_notes

        if not self.model.terms.dark_current:
            return
        self._dark_evidence = dark_current_evidence(self)
        flag, note = dark_witness_notes(self._dark_evidence)
        if flag:
            self.flags[flag] = True
            self.notes.append(note)

    def _diagnose_importance(self):
        """Draws resampled from Laplace–IS (:mod:`bayescap.inference.fast`): independent draws, so R-hat,
        walker ESS and τ do not apply; the checks are PSIS's Pareto k̂ and the IS ESS."""
        c = self.chains
        x = c.extra
        E, S, W, D = c.chain.shape
        failed = [] if x["accepted"] else [x["reason"]]
        self.diag = {
            "method": "laplace-is",
            "method_description": "Laplace approximation + Pareto-smoothed importance sampling "
            f"(Student-t ν={x['nu']:g} proposal), Gamma likelihood with discrepancy",
            "quality": self.quality,
            "converged": bool(x["accepted"]),
            "failed_checks": failed,
            "rhat_max": None,  # R-hat does not apply to resampled independent draws
            "rhat_applicable": False,
            "ess_min": float(x["ess_is"]),
            "rhat_target": c.settings.rhat_target,
            "ess_target": float(x["min_ess_is"]),
            "khat": float(x["khat"]),
            "khat_max": float(x["khat_max"]),
            "ess_is": float(x["ess_is"]),
            "n_proposals": int(x["n_proposals"]),
            "n_draws": int(S),
            "retried_with_restarts": bool(x.get("retried_with_restarts", False)),
            # why the retry's importance draws were not drawn again (fast.fast_posterior)
            **({"retry_skipped": x["retry_skipped"]} if x.get("retry_skipped") else {}),
            "fast_path_accepted": bool(x["accepted"]),
            "n_ensembles": E,
            "n_walkers": W,
            "n_steps": S,
            "n_burn": 0,
            "n_rounds": 0,
            "tau_max_steps": 1.0,
            "acceptance": [1.0],
            "wall_s": c.wall_s,
            "seed": self.seed,
            "fast_path": (
                f"fast path (Laplace–IS): Pareto k̂ {x['khat']:.2f} (accept < "
                f"{x['khat_max']:g}), importance-sampling ESS {x['ess_is']:.0f} of "
                f"{x['n_proposals']} proposals (accept ≥ {x['min_ess_is']:g}); R-hat does not apply"
            ),
            "per_quantity": {},
        }
        # the importance draws' own Monte Carlo error of each 95 % interval end
        # (bayescap.inference.end_errors.interval_end_mcse):
        # the physical parameters' from the fast path, the derived quantities' computed here
        mcse = {**(x.get("end_mcse") or {}), **self._derived_end_mcse_importance()}
        if mcse:
            gate = x.get("end_mcse_max")
            failure = self._set_end_mcse(mcse, gate)
            worst = self.diag["interval_end_mcse_worst"]
            self.diag["n_topup"] = int(x.get("n_topup", 0))
            if failure and worst in self.derived:
                # the fast path's gate covers the parameters (a parameter above it is already in
                # its reason); a derived quantity above it fails here
                self.diag["failed_checks"].append(failure)
                self.diag["converged"] = False
            self.diag["fast_path"] += (
                f"; Monte Carlo error of the 95 % interval ends up to "
                f"{mcse[worst]:.3f} of the width ({worst}"
                + (f"; accept ≤ {gate:g}" if gate is not None else "")
                + ")"
                + (f", after {x['n_topup']} more draws" if x.get("n_topup") else "")
            )
            p_within = x.get("end_within_probability")
            if p_within is not None:
                # all ends at once (bayescap.inference.end_errors._joint_target): the chance that none is off
                # by more than end_tolerance of its width, if the predicted errors are right
                conf = x.get("end_confidence")
                self.diag["interval_end_within_probability"] = float(p_within)
                self.diag["fast_path"] += (
                    f"; predicted probability that every end is within "
                    f"{x['end_tolerance']:g} of its width {p_within:.2f}"
                    + (f" (accept ≥ {conf:g})" if conf is not None and gate is not None else "")
                )
        if x.get("settings") is not None:
            # the knobs behind this result (FastSettings; the CLI's --fast-tolerance/--fast-confidence)
            self.diag["fast_settings"] = dict(x["settings"])
        tails = x.get("tails")
        if tails is not None:
            # long one-sided tails the probe found, each given defensive draws
            # (bayescap.inference.proposals._tail_probe)
            self.diag["fast_path_tails"] = [dict(t) for t in tails]
            if tails:
                self.diag["fast_path"] += "; defensive draws for long tails: " + ", ".join(
                    f"{t['parameter']} {t['side']} ({t['reach_sd']:g} sd)" for t in tails
                )
        if not self.diag["converged"]:
            self.notes.insert(
                0,
                "NOT CONVERGED: the Laplace–IS fast path failed its own check ("
                + "; ".join(self.diag["failed_checks"])
                + "); do not use these intervals",
            )
            warnings.warn(self.notes[0], ConvergenceWarning, stacklevel=4)

    def _derived_end_mcse_importance(self):
        """{derived quantity: Monte Carlo error of its 95 % interval ends / width} for a fast-path
        result: :func:`bayescap.inference.end_errors.interval_end_mcse` of the quantity computed on the weighted
        draws behind the resampled ones (``chains.extra["weighted_draws"]``), counting the
        resampling, as the fast path does for the parameters; quantities that vary only (NaN where
        a quantity's draws are not all finite). {} when the chains carry no weighted draws."""
        wd = self.chains.extra.get("weighted_draws")
        if not wd:
            return {}
        if self._same_derived_inputs(getattr(wd.get("derived_fn"), "inputs", None)):
            # the fast path's top-up computed them already, on the same weighted draws and resampled
            # count, with a function of the same inputs (bayescap.api.fit and the batch pass it one):
            # its errors of the quantities that are not parameters (~5 % of a batch sensor's time)
            return {n: float(e) for n, e in (self.chains.extra.get("end_mcse") or {}).items() if n not in self.draws}
        fn = type(self).derived_values_fn(
            self.model, metadata=self.metadata, scene=self.scene, mtf=self.mtf, seed=self.seed
        )
        return {
            n: float(interval_end_mcse(v, wd["w"], n_resampled=wd["n_resampled"]))
            for n, v in fn(wd["x"]).items()
            if _varies(v)
        }

    def _set_end_mcse(self, end, target):
        """The diagnostics of the interval ends' Monte Carlo error ``end`` ({quantity: error /
        width}): ``interval_end_mcse``, its ``_max`` and ``_worst`` (NaN, draws not all finite,
        counts as the worst) and ``_target``. Returns the failed check's text when the worst
        exceeds ``target``, else None."""
        end = {n: float(v) for n, v in end.items()}
        if not end:
            return None
        worst = worst_end(end)
        self.diag.update(
            {
                "interval_end_mcse": end,
                "interval_end_mcse_max": end[worst],
                "interval_end_mcse_worst": worst,
                "interval_end_mcse_target": target,
            }
        )
        if target is not None and not end[worst] <= target:
            return f"{_END_MCSE_FAILURE} {end[worst]:.3f} of the width ({worst}) > {target:g}"
        return None

    def _flag_imprecise_ends(self):
        """Where no check bounds the interval ends' Monte Carlo error (MCMC presets without
        ``end_mcse_target``), flag the quantities whose ends' error is above
        :data:`IMPRECISE_END_MCSE` of the width: a converged chain (R-hat, ESS) can still put an end
        far from where a longer one would (a clip level's shelf; the fallback's ESS of 200)."""
        self.flags.pop("imprecise_interval_ends", None)
        self.notes = [n for n in self.notes if not n.startswith(_IMPRECISE_NOTE)]
        end = self.diag.get("interval_end_mcse") or {}
        if self.diag.get("method") != "emcee" or self.diag.get("interval_end_mcse_target") is not None:
            return
        bad = {n: round(float(v), 3) for n, v in end.items() if not v <= IMPRECISE_END_MCSE}
        if not bad:
            return
        self.flags["imprecise_interval_ends"] = bad
        worst = max(bad.values(), key=lambda v: v if np.isfinite(v) else np.inf)
        up_to = f"up to {worst:.2f}" if np.isfinite(worst) else "undefined where the draws are not all finite"
        self.notes.append(
            f"{_IMPRECISE_NOTE} the Monte Carlo error of the 95 % interval ends of "
            + ", ".join(sorted(bad))
            + f" is above {IMPRECISE_END_MCSE:g} of the width ({up_to}): "
            "another seed can move those ends by that much. `--quality accurate` "
            "runs until every end's error is ≤ 0.01 of the width (and says when it cannot)"
        )

    def _diagnose_mcmc(self):
        c = self.chains
        E, S, W, D = c.chain.shape
        per = {}
        cached = c.extra.get("param_diagnostics") or {}
        for j, n in enumerate(self.model.names):
            per[n] = cached[j] if j in cached else fast_diagnostics(c.chain[..., j])
        for n in ("capacity_bits", "capacity_bits_per_pixel", "tonal_range_bits"):
            if n in self.derived:
                per[n] = cached[n] if n in cached else fast_diagnostics(self.derived[n].reshape(E, S, W))
        rhat_max = max(v["rhat"] for v in per.values())
        ess_min = min(min(v["ess_bulk"], v["ess_tail"]) for v in per.values())
        st = c.settings
        tau_max = float(np.max(c.tau))
        failed = []
        if not rhat_max < st.rhat_target:
            worst = max(per, key=lambda n: per[n]["rhat"])
            failed.append(f"R-hat max {rhat_max:.4f} ({worst}) ≥ {st.rhat_target}")
        if not ess_min >= st.ess_target:
            worst = min(per, key=lambda n: min(per[n]["ess_bulk"], per[n]["ess_tail"]))
            failed.append(f"ESS min {ess_min:.0f} ({worst}) < {st.ess_target:.0f}")
        if not np.all(np.isfinite(c.tau)):
            bad = [self.model.names[j] for j in np.flatnonzero(~np.isfinite(c.tau))]
            failed.append(
                f"autocorrelation time undefined ({', '.join(bad)}): a walker did not move in the {S} production steps"
            )
        elif not S >= st.tau_factor * tau_max:
            failed.append(
                f"chain of {S} steps shorter than {st.tau_factor:g} autocorrelation times ({tau_max:.1f} steps)"
            )
        if not np.all(c.acceptance > 0.05):
            failed.append(f"acceptance fraction {c.acceptance.min():.3f} < 0.05 in an ensemble")
        # Monte Carlo error of every reported 95 % interval end
        # (bayescap.inference.diagnostics.interval_end_mcse_mcmc), as
        # run_ensembles computed it on the final chain, or here
        end = c.extra.get("end_mcse")
        if end is None:
            end = {n: interval_end_mcse_mcmc(x) for n, x in self._reported_draws((E, S, W)).items()}
        # walkers stranded far below the mode (bayescap.inference.chains.stuck_walkers): their draws
        # are not posterior draws
        lp_w = np.transpose(c.log_prob, (1, 0, 2)).reshape(S, E * W)
        n_stuck = int(np.sum(stuck_walkers(lp_w, D)))
        if n_stuck:
            failed.append(f"{n_stuck} of {E * W} walkers stuck more than {stuck_threshold(D):.0f} nats below the mode")
        converged = not failed
        self.diag = {
            "method": "emcee",
            "method_description": _mcmc_description(st),
            "quality": self.quality,
            "converged": converged,
            "failed_checks": failed,
            "rhat_max": rhat_max,
            "ess_min": ess_min,
            "rhat_target": st.rhat_target,
            "ess_target": st.ess_target,
            "tau_factor": st.tau_factor,
            "n_ensembles": E,
            "n_walkers": W,
            "n_steps": S,
            "n_burn": int(c.extra.get("n_burn", st.n_burn)),
            # production steps turned into burn-in because the halves of the production disagreed
            # (time-split R-hat, bayescap.inference.mcmc.run_ensembles), and each such event
            "burn_in_extended_steps": int(c.extra.get("burn_in_extended", 0) or 0),
            "drift_events": list(c.extra.get("drift") or []),
            "n_rounds": c.n_rounds,
            "tau_max_steps": tau_max,
            "acceptance": [float(a) for a in c.acceptance],
            "walkers_stuck": n_stuck,
            "walkers_reset_in_burn_in": c.extra.get("walkers_reset"),
            "wall_s": c.wall_s,
            "seed": self.seed,
            "per_quantity": per,
        }
        failure = self._set_end_mcse(end, getattr(st, "end_mcse_target", None))
        if failure:
            failed.append(failure)
            self.diag["converged"] = converged = False
        self._flag_imprecise_ends()
        if self.diag["burn_in_extended_steps"]:
            ev = "; ".join(
                f"{e['quantity']} R-hat {e['rhat']:.3f} after round {e['round']}" for e in self.diag["drift_events"]
            )
            self.notes.append(
                f"burn-in extended by {self.diag['burn_in_extended_steps']} steps: the first and "
                f"second halves of the production disagreed ({ev}), so the earlier steps were "
                "discarded as burn-in and the intervals come from the steps after them"
            )
        if not converged:
            self.notes.insert(
                0,
                "NOT CONVERGED: " + "; ".join(failed) + ". Do not use these intervals; "
                f"rerun with {rerun_advice(self.quality)}",
            )
            warnings.warn(self.notes[0], ConvergenceWarning, stacklevel=4)
