"""The plain 2-parameter emcee fit a new user would write: the yardstick of ``speed_accuracy``
(sampled in-process, ESS measured) and of ``process_stages`` (run as this script, start to exit).

    python benchmarks/_plain_emcee.py CSV      # prints K and the read noise, 2.5/50/97.5 %

Log K and log read noise; the variances of the rows below 70 % of the largest signal (EMVA 1288's
range) and of the dark rows, Gaussian with σ from the measured value (σ_v = v·√(2/(n−1))); 32
walkers one per call (``vectorize=False``), StretchMove, 500 burn-in + 2 000 steps. Only numpy and
emcee: the script reads the CSV itself and imports nothing of bayescap.
"""

import sys

import numpy as np


def read_columns(path):
    """{column: values} of a contract CSV (``#`` lines and blank lines skipped)."""
    cols, rows = None, []
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        if cols is None:
            cols = line.strip().split(",")
            continue
        rows.append([float(x) if x else float("nan") for x in line.strip().split(",")])
    a = np.array(rows)
    return {n: a[:, i] for i, n in enumerate(cols)}


def problem(mean_dn, dark_mean_dn, var_dn2, n_pixels, dark_var_dn2):
    """(log_prob of (log K, log read noise), its start) for the arrays of a table."""
    s = mean_dn - dark_mean_dn
    keep = s <= 0.7 * s.max()
    S, v, n = s[keep], var_dn2[keep], n_pixels[keep]
    vd, nd = dark_var_dn2, n_pixels
    sv, svd = v * np.sqrt(2 / (n - 1)), vd * np.sqrt(2 / (nd - 1))

    def log_prob(th):
        lk, lr = th
        if not (-7 < lk < 7 and -5 < lr < 8):
            return -np.inf
        K, r = np.exp(lk), np.exp(lr)
        m = S / K + r * r / (K * K) + 1 / 12
        md = r * r / (K * K) + 1 / 12
        return -0.5 * np.sum(((v - m) / sv) ** 2) - 0.5 * np.sum(((vd - md) / svd) ** 2)

    k0 = 1 / np.polyfit(S, v, 1)[0]
    r0 = np.sqrt(max((np.median(vd) - 1 / 12) * k0 * k0, 1.0))
    return log_prob, np.array([np.log(k0), np.log(r0)])


def main(path, seed=1, n_walkers=32, n_burn=500, n_steps=2000):
    import emcee

    c = read_columns(path)
    log_prob, x0 = problem(
        c["mean_dn"], c["dark_mean_dn"], c["temporal_var_dn2"], c["n_pixels"], c["dark_temporal_var_dn2"]
    )
    p0 = x0 + 1e-3 * np.random.default_rng(seed).standard_normal((n_walkers, 2))
    sampler = emcee.EnsembleSampler(n_walkers, 2, log_prob)
    sampler.random_state = np.random.RandomState(seed).get_state()
    sampler.run_mcmc(p0, n_burn + n_steps, progress=False)
    ch = np.exp(sampler.get_chain(discard=n_burn, flat=True))
    print("K", np.percentile(ch[:, 0], [2.5, 50, 97.5]), "read", np.percentile(ch[:, 1], [2.5, 50, 97.5]))


if __name__ == "__main__":
    main(sys.argv[1])
