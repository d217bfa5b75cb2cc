"""The quantities derived from every posterior draw of the noise model: DR, SNR (Eq. 1-2),
tonal range b' (Eq. 7), MTF loss Δs (Eq. 9), effective pixels and capacity C = s'·b' (Eq. 6),
and the noise budget. Every equation comes from :mod:`bayescap.physics`."""

from __future__ import annotations

import numpy as np

from bayescap.physics.capacity import (
    N_GREY_LEVELS,
    effective_pixels,
    information_capacity_bits,
    mtf_loss_bits,
    tonal_range,
    tonal_range_bits,
)
from bayescap.physics.noise import NoiseCoefficients, dark_variance_e2, dynamic_range_db, snr_db, variance_terms
from bayescap.posterior.limits import apply_derived_limits
from bayescap.posterior.summary import DERIVED_INFO, summarize

__all__ = ["DerivedMixin"]

#: the notes :meth:`DerivedMixin._derive` writes, dropped when a result is re-evaluated at another scene
_DERIVED_NOTE_PREFIXES = (
    "width_px/height_px unknown",
    "no row reaches saturation",
    "the MTF reaches zero",
    "noise stays below one",
    "the MTF exceeds 1",
    "the posterior presses against",
    "rows past the PTC turnoff",
)
#: the flags it sets, dropped likewise
_DERIVED_FLAGS = ("capacity_lower_bound", "mtf_band_cut", "mtf_above_one")


def derived_per_draw(mtf) -> bool:
    """Whether every derived quantity of a draw is a function of that draw alone (the same values
    whichever other draws are computed with it): unless the MTF has its own draws, which
    :meth:`DerivedMixin._derive` pairs with the posterior's at random by position."""
    return not mtf_loss_bits(mtf, draws=True).has_draws


def _distinct_rows(x):
    """(rows, where): the distinct rows of ``x`` (n, D) (equal bytes), in the order they first
    appear, and for each row of ``x`` its index among them."""
    x = np.ascontiguousarray(x)
    v = x.view(np.dtype((np.void, x.dtype.itemsize * x.shape[1]))).ravel()
    _, first, inv = np.unique(v, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return x[first[order]], rank[np.ravel(inv)]


class DerivedMixin:
    """The derived quantities of :class:`~bayescap.posterior.FitResult` (its ``model``, ``draws``,
    ``scene``, ``mtf``, ``metadata`` and ``seed``), written to ``derived``, ``mtf_info``,
    ``notes`` and ``flags``."""

    def _noise_coefficients(self, p, t_s):
        """Eq. 1's coefficients per draw of the physical parameters ``p`` at exposure ``t_s`` (s)
        and this scene's dark-current factor. The dark variance enters as its square root
        (``dark_noise_e``), squared again: the rounding every fit's numbers are computed with."""
        k = p["conversion_gain_e_per_dn"]
        if self.model.terms.dark_current:
            rd2 = dark_variance_e2(
                p["read_noise_e"], p["dark_current_e_per_s"], t_s, dark_current_factor=self.scene.dark_current_factor
            )
        else:
            rd2 = p["dark_noise_e"] ** 2
        dsnu = p.get("dsnu_e", 0.0)
        prnu = p.get("prnu_percent", 0.0) / 100.0
        return NoiseCoefficients.from_parameters(
            read_noise_e=0.0, dark_noise_e=np.sqrt(rd2), dsnu_e=dsnu, prnu_frac=prnu, conversion_gain_e_per_dn=k
        )

    def signal_max_e(self, p=None):
        """Largest non-saturating signal (e⁻) per draw, and whether it is only a lower bound."""
        p = self.draws if p is None else p
        m = self.model
        k = p["conversion_gain_e_per_dn"]
        t = self.scene.exposure_time_s
        dark_charge = 0.0
        if m.terms.dark_current:
            dark_charge = self.scene.dark_current_factor * p["dark_current_e_per_s"] * t
        if "full_well_e" in p:
            return np.maximum(p["full_well_e"] - dark_charge, 1e-9), False
        return np.maximum((m.max_mean_ok - m.black_dn) * k - dark_charge, 1e-9), True

    def _derive_draws(self, flat, repeats=True):
        """``draws`` (the physical parameters) and ``derived`` of the draws ``flat`` (n, ndim). With
        ``repeats``, each distinct draw is computed once and its values given to its repeats (an
        MCMC walker whose move is rejected repeats its draw: ~80 % of the standard Basler chain;
        the fast path resamples with repeats), where every quantity is a function of its draw
        alone (:func:`derived_per_draw`): the same numbers, bit for bit."""
        if not repeats or flat.shape[0] < 2 or not derived_per_draw(self.mtf):
            self.draws = self.model.physical(flat)
            self._derive()
            return
        rows, where = _distinct_rows(flat)
        self.draws = self.model.physical(rows)
        self._derive()
        n = rows.shape[0]
        if n < flat.shape[0]:
            spread = lambda d: {k: v[where] if np.ndim(v) == 1 and np.size(v) == n else v for k, v in d.items()}
            self.draws, self.derived = spread(self.draws), spread(self.derived)

    def _derive(self, linearity=True):
        """``derived`` (and the notes and flags that go with it) of ``draws``; ``linearity=False``
        leaves out the linearity error (a function of the response shape draws alone, and the
        costliest quantity: its response inverse)."""
        p = self.draws
        coeffs = self._noise_coefficients(p, self.scene.exposure_time_s)
        s_max, lower = self.signal_max_e(p)
        tr = tonal_range(coeffs, s_max)
        bprime = tonal_range_bits(tr)
        ml = mtf_loss_bits(self.mtf, draws=True)
        ds = np.asarray(ml.delta_s_bits, float)
        if ml.has_draws:
            # MTF with its own draws (measured): pair them with posterior samples at random
            rng = np.random.default_rng(np.random.SeedSequence(self.seed).spawn(2)[1])
            ds = ds[rng.integers(0, ds.size, size=bprime.size)]
        else:
            ds = np.full_like(bprime, float(ds))
        self.mtf_info = {"model": self.mtf.describe(), **ml.to_dict()}
        w, h = self.metadata.get("width_px"), self.metadata.get("height_px")
        self.derived = {
            "tonal_range_bits": bprime,
            "dynamic_range_db": dynamic_range_db(coeffs, s_max),
            "snr_max_db": snr_db(coeffs, s_max),
            "mtf_loss_bits": ds,
        }
        if linearity and "response_nonlinearity" in p:
            self.derived["linearity_error_percent"] = self._linearity_error(p["response_nonlinearity"])
        if w and h:
            s = float(w) * float(h)
            self.derived["effective_pixels"] = effective_pixels(s, ds)
            self.derived["capacity_bits"] = information_capacity_bits(s, ds, bits_per_pixel=bprime)
        else:
            self.derived["capacity_bits_per_pixel"] = information_capacity_bits(1.0, ds, bits_per_pixel=bprime)
            self.notes.append(
                "width_px/height_px unknown: capacity is given per pixel "
                "(capacity_bits_per_pixel); add '# width_px:' and '# height_px:'"
            )
        if lower:
            self.flags["capacity_lower_bound"] = True
            self.notes.append(
                "no row reaches saturation: the full well, DR, TR and capacity use "
                "the largest measured signal and are lower bounds"
            )
        if ml.band_cut:
            self.flags["mtf_band_cut"] = True
            self.notes.append(
                f"the MTF reaches zero at {ml.f_end_cy_per_px:.3f} cy/px, below Nyquist "
                f"(0.5): the band is cut there, costing {ml.band_cut_bits:.2f} bits of Δs"
            )
        if float(np.median(ds)) > 0.0:
            # Eq. 8/9 are for a low-pass MTF (Δs ≤ 0, the paper); above 1 over much of the band
            # (sharpening in the pipeline, an MTF not normalised at zero frequency) s' exceeds the
            # pixel count, which no capacity comparison should take at face value
            self.flags["mtf_above_one"] = True
            self.notes.append(
                f"the MTF exceeds 1 over much of the band (Δs = +{float(np.median(ds)):.2f} bits): "
                "Eq. 9 assumes a low-pass MTF (Δs ≤ 0), so the effective pixels exceed the pixel "
                "count; use an MTF measured without sharpening"
            )
        if not self.model.data.has_dark_rows:
            self._note_turnoff()
        if np.any(tr >= 0.999 * N_GREY_LEVELS * (1 - 1e-9)):
            self.notes.append(
                "noise stays below one 8-bit grey level over part of the range: TR is "
                "limited by the 8-bit-equivalent scale (the max(σ, 1) floor of Eq. 7)"
            )

    def _linearity_error(self, a):
        """EMVA 1288's LE (%) of the fitted response, per draw, over 5–95 % of the largest
        unclipped signal (:func:`~bayescap.model.response.linearity_error_shape`)."""
        from bayescap.model.response import linearity_error_shape, shape_draws

        return linearity_error_shape(shape_draws(self.draws), self.model.response_ref_dn)

    def noise_budget(self, fraction_of_range=0.5):
        """Share of each Eq. 1 term in the noise variance at a signal level of the scene
        (default mid-grey, half the largest non-saturating signal): {term: median %}."""
        p = self.draws
        s_max, _ = self.signal_max_e(p)
        S = fraction_of_range * s_max
        if self.model.terms.dark_current:
            dark = {
                "read_noise_e": p["read_noise_e"],
                "dark_current_e_per_s": p["dark_current_e_per_s"],
                "exposure_time_s": self.scene.exposure_time_s,
                "dark_current_factor": self.scene.dark_current_factor,
            }
        else:
            dark = {"dark_noise_e": p["dark_noise_e"]}
        terms = variance_terms(
            S,
            conversion_gain_e_per_dn=p["conversion_gain_e_per_dn"],
            **dark,
            dsnu_e=p.get("dsnu_e"),
            prnu_frac=p["prnu_percent"] / 100.0 if "prnu_percent" in p else None,
        )
        total = sum(terms.values())
        return {
            "signal_e": float(np.median(S)),
            "fraction_of_range": fraction_of_range,
            "shares_percent": {n: float(np.median(100.0 * v / total)) for n, v in terms.items()},
        }

    def derived_summary(self, params: dict | None = None) -> dict:
        """The contract's ``derived`` block; ``params``: the ``parameters`` block when the caller
        has it (the limits the derived quantities follow are read from it)."""
        out = {}
        lower = self.flags.get("capacity_lower_bound", False)
        for name, x in self.summary_derived().items():
            unit = DERIVED_INFO.get(name, ("bits/pixel", ""))[0]
            extra = {}
            if lower and name not in ("mtf_loss_bits",):
                extra["lower_bound"] = True
            out[name] = summarize(x, unit, **extra)
            out[name].pop("constrained")
        if "response_nonlinearity" in self.draws or "brighter_fatter_a00_per_e" in self.draws:
            # K is the small-signal gain here; beside it, the gain a straight-line EMVA 1288 fit reports
            from bayescap.posterior.emva import emva1288_gain_draws

            k_emva = emva1288_gain_draws(self)
            if k_emva is not None:
                out["emva1288_gain_e_per_dn"] = summarize(k_emva, "e-/DN")
                out["emva1288_gain_e_per_dn"].pop("constrained")
        out = apply_derived_limits(self, self.parameter_summary() if params is None else params, out)
        if not self.model.data.has_dark_rows:
            out["ptc_turnoff_dn"] = self.ptc_turnoff_summary()
        return out

    # ------------------------------------------------------------------ PTC turnoff (mean/variance tables)
    def ptc_turnoff_summary(self) -> dict:
        """``derived.ptc_turnoff_dn``: the mean (DN above the offset) above which the temporal
        variance stops rising (:func:`ptc_turnoff`, LSST cp_pipe's PTC turnoff). A rule on the
        measured rows, not a posterior: ``median`` is the last row before the fall, ``ci68`` and
        ``ci95`` bracket the turnoff between that row and the next, ``error_dn`` is half that gap
        (cp_pipe's sampling error). Without a fall in the data, a lower limit (the largest mean)."""
        d = self.model.data
        i, rows_past = ptc_turnoff(d.signal_dn, d.temporal_var_dn2)
        s = np.asarray(d.signal_dn, float)
        order = np.argsort(s, kind="stable")
        definition = (
            "the mean above which the variance stops rising (LSST cp_pipe's PTC turnoff): the last row whose "
            f"variance exceeds that of each of the next {TURNOFF_CONSECUTIVE_DECREASES} rows, searched above a "
            "tenth of the largest variance"
        )
        if i is None:
            top = float(s[order[-1]])
            return {
                "median": None,
                "ci68": [top, None],
                "ci95": [top, None],
                "unit": "DN",
                "lower_bound": top,
                "limit": {"kind": "lower", "value": top, "level": 1.0},
                "definition": definition,
                "rows_past": [],
                "note": "the variance rises up to the largest mean: the turnoff lies above it",
            }
        j = int(np.searchsorted(s[order], s[i], side="right"))
        nxt = float(s[order[j]]) if j < s.size else float(s[i])
        clip = self.model.terms.clip != "none"
        return {
            "median": float(s[i]),
            "ci68": [float(s[i]), nxt],
            "ci95": [float(s[i]), nxt],
            "unit": "DN",
            "error_dn": 0.5 * (nxt - float(s[i])),
            "definition": definition,
            "rows_past": sorted(int(d.row_label(k)) for k in rows_past),
            "rows_past_use": (
                "fitted by the clip model: they inform full_well_e"
                if clip
                else "no clip term describes them (see the notes)"
            ),
        }

    def _note_turnoff(self):
        d = self.model.data
        i, rows_past = ptc_turnoff(d.signal_dn, d.temporal_var_dn2)
        if i is None or not rows_past.size:
            return
        labels = [str(r) for r in sorted(int(d.row_label(k)) for k in rows_past)]
        use = (
            "the clip model fits them, so they inform the full well"
            if self.model.terms.clip != "none"
            else "no clip term describes them: treat the full well and the top of the range with caution"
        )
        self.notes.append(
            f"rows past the PTC turnoff ({float(d.signal_dn[i]):.6g} DN): "
            + ", ".join(labels[:12])
            + (" …" if len(labels) > 12 else "")
            + f"; {use}"
        )


#: cp_pipe's ``consecutivePointsVarDecreases``: the variance must stay below the pivot's this many rows
TURNOFF_CONSECUTIVE_DECREASES = 2
#: the fall is searched above this fraction of the largest variance (cp_pipe: above
#: ``minVarPivotSearch`` = 10 000 ADU², an absolute level for LSST's sensors)
TURNOFF_MIN_VAR_FRACTION = 0.1


def ptc_turnoff(mean_dn, var_dn2, consecutive=TURNOFF_CONSECUTIVE_DECREASES):
    """The PTC turnoff on measured rows, as LSST cp_pipe defines it: the mean above which the
    variance stops rising. With the rows in order of increasing mean, the pivot is the first row
    whose variance exceeds :data:`TURNOFF_MIN_VAR_FRACTION` of the largest and stays above the
    variance of each of the next ``consecutive`` rows (cp_pipe's ``consecutivePointsVarDecreases``;
    all the rows left when fewer remain), so one low row on a rising curve is not a turnoff, while a
    variance that collapses at once (a clip) is. Returns ``(pivot row index or None, indices of the
    rows with a larger mean)``."""
    m = np.asarray(mean_dn, float)
    v = np.asarray(var_dn2, float)
    order = np.argsort(m, kind="stable")
    vs = v[order]
    thr = TURNOFF_MIN_VAR_FRACTION * np.max(vs)
    for p in range(vs.size - 1):
        if vs[p] > thr and np.all(vs[p + 1 : p + 1 + consecutive] < vs[p]):
            return int(order[p]), order[p + 1 :]
    return None, np.zeros(0, int)
