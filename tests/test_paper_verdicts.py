"""bayescap.studies.paper_verdicts: each verdict follows its stated rule from the numbers."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from bayescap.studies import paper_verdicts as PV
from bayescap.studies import sweep

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "data" / "benchmark"
NAMES = ("M2_2.80um", "M2_2.20um", "M1_2.20um", "M2_1.75um", "M1_1.75um")


def test_rules_on_known_draws():
    rng = np.random.default_rng(0)
    x = rng.normal(1.0, 0.1, 4000)
    assert PV._inside(1.0, x) == "agree" and PV._inside(1.5, x) == "disagree"
    assert PV._ordering([(x + 1, x)])[0] == "agree"
    assert PV._ordering([(x - 1, x)])[0] == "disagree"
    assert PV._ordering([(x, rng.normal(1.0, 0.1, 4000))])[0] == "undecided"


def test_fig4_rows_follow_the_interval_rule():
    s9 = sweep.pixel_size_sweep(n_draws=200, seed=1)
    rows = PV.paper_verdicts(sweep9=s9)
    opt = next(r for r in rows if "optimal pixel pitch" in r["statement"])
    lo, hi = np.quantile(s9.optimal_pitch_draws_um, [0.025, 0.975])
    assert opt["verdict"] == ("agree" if lo <= 1.45 <= hi else "disagree")
    tr = next(r for r in rows if "TR falls" in r["statement"])
    d = s9.table_tr_bits_draws[:, -1] - s9.table_tr_bits_draws[:, 0]
    lo, hi = np.quantile(-d if d.mean() < 0 else d, [0.025, 0.975])
    assert tr["verdict"] == ("agree" if lo <= 1.3 <= hi else "disagree")
    md = PV.verdicts_markdown(rows)
    assert md.startswith("| section | paper statement | paper value | bayescap | verdict")
    assert md.count("\n") == len(rows) + 2


@pytest.fixture(scope="module")
def stand_in_rows():
    from bayescap.studies.compare import compare

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cmp = compare([str(BENCH / f"{n}.csv") for n in NAMES], quality="fast", seed=0)
    return cmp, PV.paper_verdicts(cmp, table1_nominal=sweep.nominal_table1())


def test_section4_rows_for_the_stand_ins(stand_in_rows):
    """The stand-ins share parameters across manufacturers and have no crosstalk (README): the
    statements that rest on manufacturer differences or crosstalk are not claimed as agreement."""
    cmp, rows = stand_in_rows
    by = {r["statement"]: r for r in rows}
    m1m2 = by["capacity difference between M1_1.75 µm and M2_1.75 µm"]
    assert m1m2["verdict"] == "disagree" and "by construction" in m1m2["rule_or_reason"]
    gap = next(r for r in rows if r["section"] == "4, Fig. 6")
    assert gap["verdict"] == "disagree" and "by construction" in gap["rule_or_reason"]
    cpi = next(r for r in rows if r["section"] == "4, Fig. 7 right")
    assert cpi["verdict"] == "disagree"
    # the "almost the same at 1/4\"" rows follow their 0.9-1.1 rule from the draws
    d = {s.name: s for s in cmp.sensors}
    for manu in ("M1", "M2"):
        row = next(r for r in rows if f"the {manu} 2.20 µm sensor" in r["statement"])
        a, b = d[f"{manu}_2.20um"].draws["capacity_area_bits"], d[f"{manu}_1.75um"].draws["capacity_area_bits"]
        n = min(a.size, b.size)
        lo, hi = np.quantile(a[:n] / b[:n], [0.025, 0.975])
        assert row["verdict"] == ("agree" if 0.9 <= lo and hi <= 1.1 else "disagree")
    assert {r["verdict"] for r in rows} <= {"agree", "disagree", "undecided"}


def test_docs_do_not_claim_the_papers_pattern():
    text = (ROOT / "docs" / "compare.md").read_text(encoding="utf-8")
    assert "the pattern the paper describes" not in text
    assert "| paper statement | paper value | bayescap | verdict" in text
