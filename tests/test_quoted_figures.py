"""Benchmark figures the README and docs quote in prose stand in the results file a rerun overwrites.

Each row pairs a phrase of a page with the text the benchmark's results file writes for the same
figure: a rerun that moves the figure changes the file, and this test fails until the page says the
new figure (rerun the benchmark named in the row, then edit the page). Figures generated into
docs/ from a fit are tests/test_docs_numbers.py's.
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"

#: (page, phrase on the page, results file, the same figure as the results file writes it)
QUOTED = [
    # python benchmarks/run.py zoo_nonlinear
    ("README.md", "142 of 147 checks hold the truth (97 %)", "zoo_nonlinear.md", "**142/147 (97 %)**"),
    ("README.md", "median 3.16 s of sampling", "zoo_nonlinear.md", "| 3.16 (193.04) |"),
    ("README.md", "(up to 193 s;", "zoo_nonlinear.md", "| 3.16 (193.04) |"),
    ("README.md", "overlap on 42/42", "zoo_nonlinear.md", "**142/147 (97 %)** | 42/42 (100 %) |"),
    ("README.md", "K itself holds\non 41/42", "zoo_nonlinear.md", "| all | 41/42 (98 %) |"),
    ("README.md", "No smooth sensor has a row named an outlier", "zoo_nonlinear.md", "| 0 | 0/42 (0 %) |"),
    # python benchmarks/run.py zoo_nonlinear_seeds
    (
        "README.md",
        "700 of 735 checks hold\n(95.2 %, 95 % interval 93–97 %)",
        "zoo_nonlinear_seeds.md",
        "**700/735 (95.2 %)** [93, 97]",
    ),
    ("README.md", "has an\nRMS of 0.98", "zoo_nonlinear_seeds.md", "| +0.08 ± 0.07 | 0.98 |"),
    (
        "README.md",
        "holds 42/45 (z-scores +0.02 ± 0.27, RMS 1.01",
        "zoo_nonlinear_seeds.md",
        "| two_slope, no photons | 15 | **42/45 (93.3 %)** [82, 98] | 14/15 | 13/15 | 15/15 | 0 | +0.02 ± 0.27 | 1.01 |",
    ),
    ("README.md", "the soft knee holds 97/105", "zoo_nonlinear_seeds.md", "| soft_knee | 30 | **97/105 (92.4 %)**"),
    (
        "README.md",
        "(57/60 with photon counts, 40/45 without",
        "zoo_nonlinear_seeds.md",
        "| soft_knee, photons | 15 | **57/60",
    ),
    ("README.md", "quadratic lowest, 97/105 each", "zoo_nonlinear_seeds.md", "| quadratic | 30 | **97/105 (92.4 %)**"),
    ("docs/real_sensors.md", "There 700 of 735 checks hold (95.2 %)", "zoo_nonlinear_seeds.md", "**700/735 (95.2 %)**"),
    (
        "docs/real_sensors.md",
        "holds 42 of 45 and K's z-scores centre on +0.02 ± 0.27 with an RMS of 1.01",
        "zoo_nonlinear_seeds.md",
        "| two_slope, no photons | 15 | **42/45 (93.3 %)** [82, 98] | 14/15 | 13/15 | 15/15 | 0 | +0.02 ± 0.27 | 1.01 |",
    ),
    (
        "docs/real_sensors.md",
        "the soft knee holds 97 of 105 checks (92.4 %, interval 86–96 %",
        "zoo_nonlinear_seeds.md",
        "| soft_knee | 30 | **97/105 (92.4 %)** [86, 96]",
    ),
    (
        "docs/real_sensors.md",
        "with photon counts 57 of 60, without 40 of 45",
        "zoo_nonlinear_seeds.md",
        "| soft_knee, photons | 15 | **57/60",
    ),
    ("docs/real_sensors.md", "without 40 of 45", "zoo_nonlinear_seeds.md", "| soft_knee, no photons | 15 | **40/45"),
    (
        "docs/real_sensors.md",
        "The two-slope ADC with photons holds 59 of 60",
        "zoo_nonlinear_seeds.md",
        "| two_slope, photons | 15 | **59/60",
    ),
    (
        "docs/real_sensors.md",
        "z(K) +1.6, +1.7, +1.4, +0.5, −2.2",
        "zoo_nonlinear_seeds.md",
        "| nl_soft_knee_16bit_ph | +1.6 +1.7 +1.4 +0.5 -2.2 |",
    ),
    # python benchmarks/run.py process_stages
    (
        "README.md",
        "(the Basler set 2.4 s and 3.4 s)",
        "process_stages.md",
        "| basler_ccd12 (real) | fast | laplace-is | 2.43 |",
    ),
    (
        "README.md",
        "(the Basler set 2.4 s and 3.4 s)",
        "process_stages.md",
        "| basler_ccd12 (real) | standard | emcee | 3.36 |",
    ),
    ("README.md", "`bayescap --version` 0.06 s", "process_stages.md", "`bayescap --version`: **0.06 s**"),
    # python benchmarks/run.py colour_cfa_speed
    (
        "README.md",
        "2.61× one channel's monochrome fit at `standard`",
        "colour_cfa_speed.md",
        "colour (standard) / monochrome (standard): median 2.61x",
    ),
    ("README.md", "2.76× at `fast`", "colour_cfa_speed.md", "colour (fast) / monochrome (fast): median 2.76x"),
    ("README.md", "command costs 1.50×", "colour_cfa_speed.md", "bayescap colour / bayescap fit (fast): median 1.50x"),
    (
        "docs/colour_cli.md",
        "cost 2.76× the monochrome fit's CPU time",
        "colour_cfa_speed.md",
        "colour (fast) / monochrome (fast): median 2.76x (range 2.27-2.98x), total 2.61x",
    ),
    (
        "docs/colour_cli.md",
        "at `standard` 2.61× (range 2.38-3.43×, total 2.66×)",
        "colour_cfa_speed.md",
        "colour (standard) / monochrome (standard): median 2.61x (range 2.38-3.43x), total 2.66x",
    ),
    (
        "docs/colour_cli.md",
        "cost 1.50× the whole",
        "colour_cfa_speed.md",
        "bayescap colour / bayescap fit (fast): median 1.50x",
    ),
    (
        "docs/colour.md",
        "the map used in 227 of 256 evaluations",
        "colour_coverage.md",
        "the map used in 227 of 256 evaluations",
    ),
    # python benchmarks/run.py colour_coverage
    (
        "README.md",
        "K and QE held the truth in 489/512 and 487/512",
        "colour_coverage.md",
        "- K (each channel's own fit): 489/512",
    ),
    ("README.md", "K and QE held the truth in 489/512 and 487/512", "colour_coverage.md", "- QE per channel: 487/512"),
    (
        "README.md",
        "CS in 125/128 (raw cube) and 127/128",
        "colour_coverage.md",
        "- CS (cube, 8-bit floor, spectral CCM taken as exact): 125/128",
    ),
    (
        "README.md",
        "CS in 125/128 (raw cube) and 127/128",
        "colour_coverage.md",
        "- CS clipped after M (CCM exact): 127/128",
    ),
    ("README.md", "held the shared K in\n125/128", "colour_coverage.md", "- K (shared): 125/128"),
    ("README.md", "QE in 499/512", "colour_coverage.md", "- QE per channel: 499/512"),
    (
        "README.md",
        "CS in 124/128 clipped after the CCM and 121/128 over the raw cube (94.5 %,\n95 % interval 89.1–97.8 %",
        "colour_coverage.md",
        "- CS (cube, 8-bit floor, CCM exact): 121/128 = 94.5% (95 % CI 89.1%-97.8%",
    ),
    (
        "README.md",
        "CS in 124/128 clipped after the CCM",
        "colour_coverage.md",
        "- CS clipped after M (CCM exact): 124/128",
    ),
]


@pytest.mark.parametrize("page, phrase, results, figure", QUOTED, ids=[f"{q[0]}: {q[1][:40]}" for q in QUOTED])
def test_quoted_figure_is_the_results_files(page, phrase, results, figure):
    text = " ".join((ROOT / page).read_text(encoding="utf-8").split())
    assert " ".join(phrase.split()) in text, f"{page} no longer says {phrase!r}"
    assert figure in (RESULTS / results).read_text(encoding="utf-8"), (
        f"benchmarks/results/{results} no longer holds {figure!r}: {page}'s {phrase!r} is stale"
    )
