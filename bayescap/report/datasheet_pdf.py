"""The EMVA 1288 datasheet as a one-page PDF (A4 landscape): the HTML datasheet's table (medians
with 95 % intervals, limits alone where the data give only a limit, the standard's recipe), its
photon-transfer and SNR plots, the fit's convergence line and the sensor's metadata. Given the
result of ``bayescap colour`` (``colour=``), a second page holds the colour section
(:mod:`bayescap.report.colour_pdf`), as the HTML datasheet does.

Drawn on a :class:`matplotlib.figure.Figure` and written by matplotlib's PDF backend
(``FigureCanvasPdf``): no pyplot and no backend switch, so an interactive session's display is
left as it was. Written atomically (a temporary file beside the target, then renamed).
"""

from __future__ import annotations

import io
import textwrap
from pathlib import Path

from bayescap._version import __version__
from bayescap.io.atomic import atomic_write_bytes
from bayescap.posterior.emva import emva1288_view
from bayescap.report.datasheet import (
    TABLE_ORDER,
    _convergence_line,
    _fmt,
    _meta_rows,
    emva_limits,
    operating_point,
    ptc_figure,
    snr_figure,
)
from bayescap.report.pdf_table import grid_table

__all__ = ["datasheet_pdf", "write_datasheet_pdf"]

#: A4 landscape, inches
PAGE_IN = (11.69, 8.27)


def _rows(view, limits):
    """The table's rows: (quantity, symbol, unit, value, 95 % interval, recipe) as text."""
    q = view["quantities"]
    out = []
    for key in TABLE_ORDER:
        if key not in q:
            continue
        it = q[key]
        unit = it["unit"] or ""
        if key in limits:  # the limit alone: its value, and what kind of limit it is instead of an interval
            lim = limits[key]
            value = ("< " if lim["kind"] == "upper" else "> ") + _fmt(lim["value"])
            interval = f"({100 * lim['level']:g} % {lim['kind']} limit)"
        else:
            ci = it["ci95"]
            value, interval = _fmt(it["median"]), ("–" if ci is None else f"{_fmt(ci[0])} – {_fmt(ci[1])}")
        out.append([it["name"], it["symbol"], unit, value, interval, _fmt(it["recipe"])])
    return out


def datasheet_pdf(result, *, view=None, title=None, colour=None) -> bytes:
    """The datasheet of ``result`` as PDF bytes: one page, and the colour page with ``colour`` (the
    JSON of ``bayescap colour``)."""
    from matplotlib.backends.backend_pdf import FigureCanvasPdf, PdfPages
    from matplotlib.figure import Figure

    view = emva1288_view(result) if view is None else view
    limits = emva_limits(view)
    meta = dict(result.metadata)
    name = str(title or meta.get("sensor") or Path(str(result.model.data.source)).stem)
    fig = Figure(figsize=PAGE_IN)
    # text is drawn as it is: a '$' in a sensor or file name is not math
    fig.text(0.03, 0.965, name, fontsize=14, weight="bold", va="top", usetex=False, parse_math=False)
    fig.text(
        0.03,
        0.935,
        f"{view['standard']} view of a bayescap {__version__} fit of {result.model.data.source}; medians and "
        "95 % credible intervals over the posterior draws",
        fontsize=8,
        color="0.3",
        va="top",
        parse_math=False,
    )
    ok = (result.diag or {}).get("converged")
    conv = textwrap.fill("Fit: " + _convergence_line(result), 190)
    fig.text(
        0.03, 0.915, conv, fontsize=7.5, va="top", color="0" if ok else "#b00000", weight="normal" if ok else "bold",
        parse_math=False,
    )  # fmt: skip
    rows = _rows(view, limits)
    header = ["Quantity", "Symbol", "Unit", "Median", "95 % interval", "Recipe"]
    grid_table(fig.add_axes((0.03, 0.1, 0.58, 0.78)), rows, header, [0.41, 0.11, 0.07, 0.11, 0.18, 0.12], scale=1.12)
    ptc_figure(result, view, ax=fig.add_axes((0.69, 0.56, 0.29, 0.31)))
    snr_figure(result, view, limits, ax=fig.add_axes((0.69, 0.15, 0.29, 0.31)))
    for ax in fig.axes[1:]:
        for t in (ax.title, ax.xaxis.label, ax.yaxis.label):
            t.set_fontsize(8)
        ax.tick_params(labelsize=7)
        leg = ax.get_legend()
        if leg is not None:
            for t in leg.get_texts():
                t.set_fontsize(5.5)
                t.set_parse_math(False)
    op_txt = "Operating point: " + "; ".join(f"{k}: {v}" for k, v in operating_point(result))
    meta_txt = "Sensor: " + "; ".join(f"{k}: {v}" for k, v in _meta_rows(result))
    fig.text(0.03, 0.07, textwrap.fill(op_txt, 230), fontsize=6, va="top", parse_math=False)
    fig.text(0.03, 0.05, textwrap.fill(meta_txt, 230), fontsize=6, color="0.3", va="top", parse_math=False)
    buf = io.BytesIO()
    if colour is None:
        FigureCanvasPdf(fig).print_pdf(buf)
        return buf.getvalue()
    from bayescap.report.colour_pdf import colour_page

    with PdfPages(buf) as pages:
        for page in (fig, colour_page(colour, name=name, page_in=PAGE_IN)):
            FigureCanvasPdf(page)  # the PDF canvas (a Figure made without pyplot has none)
            pages.savefig(page)
    return buf.getvalue()


def write_datasheet_pdf(result, path, *, title=None, view=None, colour=None) -> Path:
    """Write :func:`datasheet_pdf` of ``result`` to ``path`` (atomically); returns the path."""
    path = Path(path)
    atomic_write_bytes(path, datasheet_pdf(result, view=view, title=title, colour=colour))
    return path
