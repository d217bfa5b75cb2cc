"""Region of interest and colour-filter-array (Bayer) channels of a raw frame."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from bayescap.exceptions import IngestError

__all__ = [
    "CHANNELS",
    "parse_roi",
    "cfa_positions",
    "split_cfa",
]


#: Channel names accepted by :func:`ingest`; ``G`` pools the Gr and Gb pixels, ``all`` writes
#: one CSV for each of R, Gr, Gb and B.
CHANNELS = ("R", "Gr", "Gb", "B", "G", "all")


_SINGLE_CHANNELS = ("R", "Gr", "Gb", "B")


_BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")


def parse_roi(
    roi: str | float | Sequence[int] | None, shape_hw: tuple[int, int], *, cfa: bool = False
) -> tuple[int, int, int, int]:
    """Region of interest ``(x0, y0, x1, y1)`` in pixels (x1, y1 exclusive).

    Parameters
    ----------
    roi : str, float, sequence of 4 ints or None
        ``"x0,y0,x1,y1"`` or a 4-sequence in full-frame pixel coordinates; or a centred
        fraction of each dimension (``0.5`` or ``"0.5"``); ``None`` means the centred 50 %
        (EMVA 1288 leaves the ROI to the user; the centre avoids vignetting and borders).
    shape_hw : (int, int)
        Frame (height, width) in pixels.
    cfa : bool
        For a Bayer frame the corners are moved to even coordinates (x0, y0 down, x1, y1 down)
        so that the ROI starts on the first CFA position and holds whole 2x2 tiles.
    """
    height, width = shape_hw
    if roi is None:
        roi = 0.5
    if isinstance(roi, str):
        parts = [p for p in roi.replace(" ", "").split(",") if p != ""]
        try:
            if len(parts) == 1:
                roi = float(parts[0])
            elif len(parts) == 4:
                roi = [int(p) for p in parts]
            else:
                raise ValueError
        except ValueError:
            raise IngestError(
                f"ROI {roi!r} is neither 'x0,y0,x1,y1' (integers) nor a centred fraction such as 0.5"
            ) from None
    if isinstance(roi, (int, float)) and not isinstance(roi, bool):
        frac = float(roi)
        if not (0.0 < frac <= 1.0):
            raise IngestError(f"ROI fraction {frac:g} must be in (0, 1]")
        w = max(1, int(round(width * frac)))
        h = max(1, int(round(height * frac)))
        x0, y0 = (width - w) // 2, (height - h) // 2
        x1, y1 = x0 + w, y0 + h
    else:
        try:
            x0, y0, x1, y1 = (int(v) for v in roi)
        except (TypeError, ValueError):
            raise IngestError(f"ROI {roi!r} is not four integers x0,y0,x1,y1") from None
        if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
            raise IngestError(
                f"ROI x0={x0},y0={y0},x1={x1},y1={y1} does not lie inside the "
                f"{width}x{height} frame (need 0 <= x0 < x1 <= width, "
                "0 <= y0 < y1 <= height)"
            )
    if cfa:
        x0, y0 = x0 - x0 % 2, y0 - y0 % 2
        x1, y1 = x1 - (x1 - x0) % 2, y1 - (y1 - y0) % 2
        if x1 <= x0 or y1 <= y0:
            raise IngestError("the ROI is smaller than one 2x2 CFA tile")
    if (x1 - x0) * (y1 - y0) < 2:
        raise IngestError("the ROI holds fewer than 2 pixels")
    return x0, y0, x1, y1


def cfa_positions(cfa_pattern: str) -> dict[str, tuple[int, int]]:
    """Position ``(row, column)`` in the 2x2 tile of each Bayer channel R, Gr, Gb, B.

    ``cfa_pattern`` lists the tile row by row (``"GRBG"``: G at (0, 0), R at (0, 1), B at
    (1, 0), G at (1, 1)). Gr is the green pixel in the row of red pixels, Gb the one in the row
    of blue pixels.
    """
    pattern = cfa_pattern.upper()
    if pattern not in _BAYER_PATTERNS:
        raise IngestError(f"CFA pattern {cfa_pattern!r} is not one of {', '.join(_BAYER_PATTERNS)}")
    pos = {c: [(i // 2, i % 2) for i, ch in enumerate(pattern) if ch == c] for c in "RGB"}
    red_row = pos["R"][0][0]
    gr = next(p for p in pos["G"] if p[0] == red_row)
    gb = next(p for p in pos["G"] if p[0] != red_row)
    return {"R": pos["R"][0], "Gr": gr, "Gb": gb, "B": pos["B"][0]}


def split_cfa(pixels: np.ndarray, cfa_pattern: str) -> dict[str, np.ndarray]:
    """Split a Bayer mosaic into its four colour planes R, Gr, Gb and B (views, no copy).

    ``pixels`` must start on the first position of the 2x2 tile described by ``cfa_pattern``.
    Each plane has shape (ceil(rows/2), ceil(columns/2)) or one less where the mosaic is odd.
    """
    return {name: pixels[i::2, j::2] for name, (i, j) in cfa_positions(cfa_pattern).items()}


def _channel_tiles(cfa_pattern: str | None, channel: str) -> list[tuple[int, int]] | None:
    """CFA positions pooled for ``channel`` (None for monochrome: every pixel)."""
    if cfa_pattern is None:
        return None
    pos = cfa_positions(cfa_pattern)
    return [pos["Gr"], pos["Gb"]] if channel == "G" else [pos[channel]]


def _channel_pixels(roi_pixels: np.ndarray, tiles: list[tuple[int, int]] | None) -> np.ndarray:
    """Pixels of one channel inside the (tile-aligned) ROI, as one flat float64 array."""
    if tiles is None:
        return roi_pixels.astype(np.float64).ravel()
    return np.concatenate([roi_pixels[i::2, j::2].astype(np.float64).ravel() for i, j in tiles])
