"""Many fast paths in lockstep: each sensor's unchanged fast path runs in a greenlet whose model
hands its ``log_prob`` requests to a :class:`Lockstep` evaluator; once every running path waits, all
requests are evaluated in one :class:`~bayescap.model.PTCModelStack` call, and each path resumes
with its own values (bit for bit those of its own model). Used by :func:`bayescap.batch.fit_many` and by
the MCMC's ensembles sharing a call."""

from __future__ import annotations

import copy
import time
import warnings
from collections import defaultdict

import numpy as np


class Lockstep:
    """Evaluate the ``log_prob`` requests of many fits in one stacked call.

    ``run(fns, concurrency)`` runs ``fns[i](log_prob_i)``, where ``log_prob_i(theta)`` stands for
    ``stack.models[i].log_prob(theta)``, each in a greenlet (a coroutine with its own stack: the
    fit's code, scipy's BFGS included, runs unchanged). A request suspends its fit; once every
    running fit has made one (or finished), all requests are evaluated together, in task order and
    in chunks of at most ``max_points`` draws (whole requests), and every fit resumes with its own
    values. A fit that finishes hands its place to the next task, so the stacked calls stay full
    until the queue runs dry (a fast path that is retried makes twice the calls of the others).

    A request of ``solo_points`` draws or more goes to its own model instead: at that size the
    per-call overhead no longer matters, and a stacked call, whose data are (draws, rows) arrays
    instead of broadcast rows, costs more per draw. The values are the same either way (bit for
    bit). Greenlets rather than threads: switching costs ~1 µs instead of ~25 µs per request, and
    the order of evaluation is fixed by the code, not by a scheduler.

    Counts: ``n_calls`` stacked calls, ``n_requests`` requests, ``n_points`` draws (both kinds)."""

    def __init__(self, stack, *, max_points: int = 16384, solo_points: int = 512):
        self.stack = stack
        self.max_points = int(max_points)
        self.solo_points = int(solo_points)
        self.n_calls = self.n_requests = self.n_points = 0
        self._main = None

    def log_prob_for(self, slot: int):
        def log_prob(theta):
            r = self._main.switch((slot, np.atleast_2d(np.asarray(theta, float))))
            if isinstance(r, BaseException):
                raise r
            return r

        return log_prob

    def _evaluate(self, requests):
        """{slot: theta} -> {slot: log p or the exception raised}."""
        res, stacked = {}, []
        for s in sorted(requests):
            th = requests[s]
            self.n_requests += 1
            self.n_points += th.shape[0]
            if th.shape[0] >= self.solo_points:
                try:
                    res[s] = self.stack.models[s].log_prob(th)
                except Exception as e:
                    res[s] = e
            else:
                stacked.append(s)
        chunk, n = [], 0
        for j, s in enumerate(stacked):
            chunk.append(s)
            n += requests[s].shape[0]
            if j == len(stacked) - 1 or n + requests[stacked[j + 1]].shape[0] > self.max_points:
                self._evaluate_stacked(chunk, requests, res)
                chunk, n = [], 0
        return res

    def _evaluate_stacked(self, slots, requests, res):
        th = [requests[s] for s in slots]
        sizes = [t.shape[0] for t in th]
        try:
            lp = self.stack.log_prob(np.vstack(th), np.repeat(np.asarray(slots, int), sizes))
        except Exception:
            # one sensor's failure must not fail the others: each request on its own model, so
            # that only the failing fit sees its error
            for s in slots:
                try:
                    res[s] = self.stack.models[s].log_prob(requests[s])
                except Exception as e:
                    res[s] = e
            return
        self.n_calls += 1
        for s, part in zip(slots, np.split(lp, np.cumsum(sizes)[:-1])):
            res[s] = part

    def run(self, fns, concurrency: int | None = None, ignore_warnings: bool = True):
        """``[fns[i](log_prob_i) for i]``, at most ``concurrency`` at a time (default all), in
        lockstep; an exception is returned in its slot instead of stopping the others.
        ``ignore_warnings``: silence warnings inside (the fast paths' own checks report what
        matters); the caller's filters are restored either way."""
        import greenlet

        out: list = [None] * len(fns)
        todo = iter(range(len(fns)))

        def worker():
            for i in todo:
                try:
                    out[i] = fns[i](self.log_prob_for(i))
                except Exception as e:  # one sensor's failure must not stop the others
                    out[i] = e

        n = len(fns) if concurrency is None else max(1, min(int(concurrency), len(fns)))
        self._main = greenlet.getcurrent()
        running = [(greenlet.greenlet(worker), None) for _ in range(n)]
        # warnings.catch_warnings (scipy's BFGS wrapper, the PSIS fit) saves and restores the
        # process-wide filter list; fits that enter and leave it interleaved would restore each
        # other's lists. One outer block restores the caller's filters whatever the order inside.
        with warnings.catch_warnings():
            if ignore_warnings:
                warnings.simplefilter("ignore")
            while running:
                requests = {}
                waiting = []
                for g, value in running:
                    r = g.switch(value) if value is not None else g.switch()
                    if not g.dead:
                        requests[r[0]] = r[1]
                        waiting.append((g, r[0]))
                res = self._evaluate(requests)
                running = [(g, res[s]) for g, s in waiting]
        return out


def _with_log_prob(model, log_prob):
    """A shallow copy of ``model`` whose ``log_prob`` is ``log_prob`` (the rest is shared)."""
    proxy = copy.copy(model)
    proxy.log_prob = log_prob
    return proxy


def _fast_paths(models, seeds, settings, stack_size: int = 64, derived_fns=None):
    """Fast-path results ``(ChainResult, diagnostics)`` (or an exception) of stackable models, at
    most ``stack_size`` in lockstep. Wall times are the whole run's divided by the number of
    sensors (amortised). ``derived_fns``: each model's ``fast_posterior`` ``derived_fn`` (None: none)."""
    from bayescap.inference.fast import fast_posterior
    from bayescap.model import PTCModelStack

    ls = Lockstep(PTCModelStack(models))
    dfs = derived_fns or [None] * len(models)
    fns = [
        (lambda lp, m=m, s=s, df=df: fast_posterior(_with_log_prob(m, lp), seed=s, settings=settings, derived_fn=df))
        for m, s, df in zip(models, seeds, dfs)
    ]
    t0 = time.perf_counter()
    out = ls.run(fns, concurrency=stack_size)
    wall = (time.perf_counter() - t0) / len(models)
    for r in out:
        if isinstance(r, tuple):
            chains, fd = r
            chains.wall_s = fd["wall_s"] = wall
            fd["stacked"] = chains.extra["stacked"] = {
                "sensors": len(models),
                "stack_size": int(stack_size),
                "stacked_calls": ls.n_calls,
                "note": "fast path run in lockstep with other sensors (bayescap.batch); wall time amortised",
            }
    return out


def stack_groups(models, n_parts: int = 1):
    """Indices of the models that stack together (:meth:`~bayescap.model.PTCModelStack.signature`),
    each group in input order and cut into ``n_parts`` near-equal parts (one per process)."""
    from bayescap.model import PTCModelStack

    groups = defaultdict(list)
    for i, m in enumerate(models):
        if m is not None:
            groups[PTCModelStack.signature(m)].append(i)
    return [[list(p) for p in np.array_split(g, min(n_parts, len(g)))] for g in groups.values()]
