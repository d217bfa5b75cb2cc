"""The tables of the PDF pages (the EMVA 1288 datasheet and its colour page), drawn alike."""

from __future__ import annotations

__all__ = ["grid_table"]


def grid_table(ax, rows, header, widths, *, fontsize=6.5, scale=1.1):
    """A table of ``rows`` under ``header`` in ``ax`` (its frame hidden): thin rules, a grey header
    row, text left-aligned and never read as mathtext; nothing drawn without rows."""
    ax.axis("off")
    if not rows:
        return None
    t = ax.table(cellText=rows, colLabels=header, loc="upper left", cellLoc="left", colWidths=widths)
    t.auto_set_font_size(False)
    t.set_fontsize(fontsize)
    t.scale(1.0, scale)
    for (r, _), cell in t.get_celld().items():
        cell.set_linewidth(0.3)
        cell.get_text().set_parse_math(False)
        if r == 0:
            cell.set_facecolor("#eeeeee")
    return t
