"""One table of a batch folder: ``DIR/summary.csv`` (and ``DIR/summary.parquet`` where pyarrow is
installed), one row per ``DIR/<name>/result.json``, so that a batch loads in one line::

    import pandas as pd
    df = pd.read_csv("results/summary.csv")

Columns, in this order:

- ``name`` (the sensor's folder), ``input``, ``sensor``, ``method``, ``quality``, ``seed``,
  ``converged`` (``True``/``False``), ``failed_checks``, ``flags``, ``warnings`` (codes joined by
  ``;``, empty for none), ``rhat_max``, ``ess_min``;
- for every parameter and derived quantity (in the report's order): ``<q>_median``,
  ``<q>_ci95_low``, ``<q>_ci95_high``, ``<q>_ci68_low``, ``<q>_ci68_high``, ``<q>_unit``, and where
  a sensor reports it as a limit ``<q>_limit`` (``upper``/``lower``) and ``<q>_limit_value`` (the
  95 % limit): a limited quantity is read from these two columns, not from its median.

Numbers are written with 17 significant digits (``repr``), so the CSV gives back the JSON's
numbers exactly; a missing number is an empty cell (NaN in pandas). The files are written
atomically (:mod:`bayescap.io.atomic`): by the batch when it finishes, and by ``bayescap summary
DIR``, which rebuilds them from the folder.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from bayescap.batch.store import RESULT_FILE
from bayescap.io.atomic import atomic_write_bytes, atomic_write_text
from bayescap.posterior.summary import DERIVED_ORDER, PARAMETER_ORDER

__all__ = ["SUMMARY_CSV", "SUMMARY_PARQUET", "summary_rows", "write_summary"]

SUMMARY_CSV = "summary.csv"
SUMMARY_PARQUET = "summary.parquet"

#: the columns every row has, before the quantities'
_FIXED = (
    "name",
    "input",
    "sensor",
    "method",
    "quality",
    "seed",
    "converged",
    "failed_checks",
    "flags",
    "warnings",
    "rhat_max",
    "ess_min",
)
_PER_QUANTITY = ("median", "ci95_low", "ci95_high", "ci68_low", "ci68_high", "unit")


def _number(v):
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _joined(items) -> str:
    return ";".join(str(x) for x in items)


def _quantity_cells(name, s) -> dict:
    ci95, ci68 = s.get("ci95") or [None, None], s.get("ci68") or [None, None]
    row = {
        f"{name}_median": _number(s.get("median")),
        f"{name}_ci95_low": _number(ci95[0]),
        f"{name}_ci95_high": _number(ci95[1]),
        f"{name}_ci68_low": _number(ci68[0]),
        f"{name}_ci68_high": _number(ci68[1]),
        f"{name}_unit": s.get("unit", ""),
    }
    lim = s.get("limit")
    if lim:
        row[f"{name}_limit"] = lim["kind"]
        row[f"{name}_limit_value"] = _number(lim["value"])
    return row


def _row(name, doc) -> tuple[dict, list]:
    """A result JSON's row and its quantities' names in order."""
    dg = doc.get("diagnostics", {})
    flags = doc.get("flags", {}) or {}
    row = {
        "name": name,
        "input": doc.get("input", ""),
        "sensor": (doc.get("sensor") or {}).get("sensor", ""),
        "method": dg.get("method", ""),
        "quality": dg.get("quality", ""),
        "seed": dg.get("seed"),
        "converged": bool(dg.get("converged")),
        "failed_checks": _joined(dg.get("failed_checks") or []),
        "flags": _joined(sorted(k for k, v in flags.items() if v)),
        "warnings": _joined(w.get("code", "") for w in doc.get("warnings") or []),
        "rhat_max": _number(dg.get("rhat_max")),
        "ess_min": _number(dg.get("ess_min")),
    }
    names = []
    for group in ("parameters", "derived"):
        for q, s in (doc.get(group) or {}).items():
            if isinstance(s, dict):
                row.update(_quantity_cells(q, s))
                names.append(q)
    return row, names


def summary_rows(out) -> tuple[list[str], list[dict]]:
    """(columns, rows) of the folder ``out``: one row per ``<name>/result.json``, by name."""
    out = Path(out)
    rows, quantities = [], []
    for p in sorted(out.glob(f"*/{RESULT_FILE}")):
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:  # a folder in its place, a spoilt file: named, not fatal
            rows.append({"name": p.parent.name, "warnings": f"{RESULT_FILE} unreadable ({type(e).__name__})"})
            continue
        row, names = _row(p.parent.name, doc)
        rows.append(row)
        quantities += [n for n in names if n not in quantities]
    order = {n: i for i, n in enumerate([*PARAMETER_ORDER, *DERIVED_ORDER])}
    quantities.sort(key=lambda n: order.get(n, len(order)))
    columns = list(_FIXED)
    for q in quantities:
        columns += [f"{q}_{c}" for c in _PER_QUANTITY]
        if any(f"{q}_limit" in r for r in rows):
            columns += [f"{q}_limit", f"{q}_limit_value"]
    return columns, rows


def _csv_text(columns, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow(["" if r.get(c) is None else (repr(r[c]) if isinstance(r[c], float) else r[c]) for c in columns])
    return buf.getvalue()


def _parquet_bytes(columns, rows) -> bytes | None:
    """The table as Parquet, or None without pyarrow."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    data = {c: [r.get(c) for r in rows] for c in columns}
    for c in columns:  # one type per column: text, an empty text is missing (as in the CSV)
        if not any(isinstance(v, (int, float)) and not isinstance(v, bool) for v in data[c]):
            if not all(isinstance(v, bool) for v in data[c] if v is not None):
                data[c] = [None if v is None or v == "" else str(v) for v in data[c]]
    buf = io.BytesIO()
    pq.write_table(pa.table(data), buf)
    return buf.getvalue()


def write_summary(out) -> list[Path]:
    """Write ``out/summary.csv`` (and ``out/summary.parquet`` with pyarrow) from the folder's
    result files, atomically; returns the paths written."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    columns, rows = summary_rows(out)
    written = [out / SUMMARY_CSV]
    atomic_write_text(written[0], _csv_text(columns, rows))
    pq = _parquet_bytes(columns, rows)
    if pq is not None:
        written.append(out / SUMMARY_PARQUET)
        atomic_write_bytes(written[1], pq)
    return written
