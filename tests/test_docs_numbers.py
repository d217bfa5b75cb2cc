"""Numbers quoted in docs/*.md come from the program: each lies in a generated block

    <!-- docs-numbers: NAME -->
    ...
    <!-- /docs-numbers -->

whose text :data:`BLOCKS` ``[NAME]`` makes from a fresh fit (the Basler reference set, ``standard``,
seed 1, the documented call) or from a benchmark's results file. The test regenerates every block and
compares it with the docs, so a change to the model that moves a quoted number fails here until the
docs are regenerated:

    python tests/test_docs_numbers.py --regenerate

(as the golden files: in its own commit, saying why the numbers moved). A block NAME in the docs that
no generator knows, or a generator whose block is in no doc, fails too.
"""

from __future__ import annotations

import json
import re
import sys
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BASLER = ROOT / "data" / "emva1288_basler_ccd12.csv"
REF = ROOT / "data" / "emva1288_refset001" / "reference_results_emva1288_v1.0.2.json"
BENCH_GAIN = ROOT / "benchmarks" / "results" / "basler_vs_emva1288.md"

_BLOCK = re.compile(r"(<!-- docs-numbers: ([\w-]+) -->\n)(.*?)(<!-- /docs-numbers -->)", re.S)


def basler_fit():
    """The fit the docs quote: ``bayescap.fit("data/emva1288_basler_ccd12.csv", seed=1)``."""
    import bayescap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bayescap.fit(str(BASLER), seed=1)


def _g(x, d=4):
    """``d`` significant digits; thousands with a thin space as the docs write them."""
    if abs(x) >= 10000:
        return f"{x:,.0f}".replace(",", " ")
    return f"{x:.{d}g}" if abs(x) >= 1 else f"{x:.{d}g}"


def _iv(med, ci, d=4):
    return f"{_g(med, d)} [{_g(ci[0], d)}, {_g(ci[1], d)}]"


def _results_repr(r, view, ref):
    path = str(BASLER.relative_to(ROOT))
    return f"```\n{repr(r).replace(str(BASLER), path)}\n```\n"


#: the docs' Basler table: (label, view key, scale, digits)
_TABLE = (
    ("K (DN/e⁻), the standard's straight line", "K", 1.0, 4),
    ("1/K (e⁻/DN)", "inverse_K", 1.0, 4),
    ("η (%)", "QE", 1.0, 4),
    ("R (DN/p)", "R", 1.0, 4),
    ("σ_d (e⁻)", "sigma_d", 1.0, 4),
    ("σ_y.dark (DN)", "sigma_y_dark", 1.0, 4),
    ("μe.sat (e⁻)", "u_e_sat", 1.0, 5),
    ("μp.min (p)", "u_p_min", 1.0, 4),
    ("DR (dB)", "DR_dB", 1.0, 4),
    ("SNR_max (dB)", "SNR_max_dB", 1.0, 4),
    ("LE (%)", "LE", 1.0, 3),
    ("DSNU1288 (e⁻)", "DSNU1288", 1.0, 3),
    ("PRNU1288 (%)", "PRNU1288", 1.0, 3),
    ("μ_I.mean (e⁻/s)", "u_I_mean", 1.0, 3),
    ("μ_I.var (e⁻/s)", "u_I_var", 1.0, 3),
)
_REF_KEY = {"LE": None, "inverse_K": None}


def _cell(it, d):
    lim = it.get("limit")
    if lim:
        return f"{'<' if lim['kind'] == 'upper' else '>'} {_g(lim['value'], d)} ({100 * lim['level']:g} % {lim['kind']} limit)"
    if it.get("ci95") is None:
        return f"{_g(it['median'], d)} (data only)"
    return _iv(it["median"], it["ci95"], d)


def _emva_table(r, view, ref):
    q = view["quantities"]
    lines = [
        "| quantity | bayescap median [95 %] | standard's recipe on the CSV | emva1288 1.0.2 |",
        "|---|---|---|---|",
    ]
    for label, key, _, d in _TABLE:
        it = q[key]
        rec = "—" if it.get("recipe") is None else _g(it["recipe"], d + 1)
        rk = _REF_KEY.get(key, key)
        em = "—" if rk is None or rk not in ref else _g(ref[rk], d + 1)
        lines.append(f"| {label} | {_cell(it, d)} | {rec} | {em} |")
    p = r.to_dict()
    k0, fw = p["parameters"]["conversion_gain_e_per_dn"], p["parameters"]["full_well_e"]
    lines.append(f"| small-signal gain `conversion_gain_e_per_dn` (e⁻/DN) | {_iv(k0['median'], k0['ci95'])} | — | — |")
    a = p["parameters"].get("response_nonlinearity")
    if a:
        lines.append(
            f"| response deviation from linear at the top of the unclipped rows (`response_nonlinearity`) | {_iv(a['median'], a['ci95'], 3)} | — | — |"
        )
    if "u_e_sat_model" in q:
        lines.append(f"| μe.sat at the model's variance peak (e⁻) | {_cell(q['u_e_sat_model'], 5)} | — | — |")
    lines.append(f"| `full_well_e`, the charge at the clip (e⁻) | {_iv(fw['median'], fw['ci95'], 5)} | — | — |")
    return "\n".join(lines) + "\n"


def _bench_rows():
    """{row label: K} of benchmarks/results/basler_vs_emva1288.md's table."""
    out = {}
    for line in BENCH_GAIN.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 2:
            out[cells[0]] = cells[1]
    return out


def _gain_sentence(r, view, ref):
    """The gains of the two-gains paragraph, from the fit and from the benchmark's results file."""
    p = r.to_dict()
    k0 = p["parameters"]["conversion_gain_e_per_dn"]
    a = p["parameters"].get("response_nonlinearity")
    ke = p["derived"].get("emva1288_gain_e_per_dn")
    b = _bench_rows()
    lin = next(v for k, v in b.items() if k.startswith("bayescap with a linear response forced"))
    w = next(v for k, v in b.items() if k.startswith("1/sd²-weighted"))
    return (
        f"On the Basler set (response deviation at the top {_g(a['median'], 2) if a else '0'}): small-signal gain "
        f"{_iv(k0['median'], k0['ci95'])} e⁻/DN, the standard's gain from the same fit "
        f"{_iv(ke['median'], ke['ci95']) if ke else '—'} e⁻/DN, emva1288 {_g(1 / ref['K'], 5)} e⁻/DN. With the "
        f"response held linear the fit gives {lin} e⁻/DN; the standard's own rows weighted by 1/σ² give {w} "
        f"(`python benchmarks/run.py basler_vs_emva1288`).\n"
    )


#: block name -> function(fit, EMVA view, emva1288's results) -> the block's text
BLOCKS = {
    "results-repr": _results_repr,
    "emva-basler-table": _emva_table,
    "emva-basler-gains": _gain_sentence,
}


def _generated(r):
    from bayescap.posterior.emva import emva1288_view

    view = emva1288_view(r)
    ref = {k: v["value"] for k, v in json.loads(REF.read_text()).items()}
    return {name: fn(r, view, ref) for name, fn in BLOCKS.items()}


def _doc_blocks():
    """[(doc path, name, text)] of every generated block in docs/*.md."""
    out = []
    for p in sorted(DOCS.glob("*.md")):
        for m in _BLOCK.finditer(p.read_text(encoding="utf-8")):
            out.append((p, m.group(2), m.group(3)))
    return out


def regenerate() -> list[Path]:
    new = _generated(basler_fit())
    changed = []
    for p in sorted(DOCS.glob("*.md")):
        text = p.read_text(encoding="utf-8")
        out = _BLOCK.sub(lambda m: m.group(1) + new[m.group(2)] + m.group(4), text)
        if out != text:
            p.write_text(out, encoding="utf-8")
            changed.append(p)
    return changed


@pytest.fixture(scope="module")
def generated(basler_standard_fit):
    return _generated(basler_standard_fit)  # basler_fit()'s fit, shared with other tests (conftest)


def test_every_block_has_a_generator_and_every_generator_a_block():
    names = [n for _, n, _ in _doc_blocks()]
    assert set(names) == set(BLOCKS), (sorted(names), sorted(BLOCKS))


@pytest.mark.parametrize("doc, name", [(p.name, n) for p, n, _ in _doc_blocks()])
def test_docs_numbers_are_the_programs(doc, name, generated):
    text = next(t for p, n, t in _doc_blocks() if p.name == doc and n == name)
    assert text == generated[name], (
        f"docs/{doc}, block {name}: the numbers moved; regenerate with "
        f"'python tests/test_docs_numbers.py --regenerate' (and say why in the commit)\n--- docs\n{text}\n--- now\n"
        f"{generated[name]}"
    )


def test_no_stale_basler_numbers_outside_blocks():
    """The numbers the docs once quoted by hand for the Basler fit are gone from the prose."""
    for p in DOCS.glob("*.md"):
        prose = _BLOCK.sub("", p.read_text(encoding="utf-8"))
        for stale in ("K=3.55 [", "10.86 [10.81", "44.99 [44.79"):
            assert stale not in prose, (p.name, stale)


if __name__ == "__main__":
    if sys.argv[1:] == ["--regenerate"]:
        print("regenerated:", *[str(p.relative_to(ROOT)) for p in regenerate()] or ["nothing changed"])
    else:
        sys.exit("usage: python tests/test_docs_numbers.py --regenerate")
