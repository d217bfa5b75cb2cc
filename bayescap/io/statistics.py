"""Per-channel statistics of a frame set: pair mean and temporal variance, spatial variance.

Every frame is read once (:class:`_FrameReader` applies the set's metadata overrides and checks
that the frames agree), cut to the ROI and to one CFA channel, and streamed into a
:class:`_SetAccumulator`.

References
----------
EMVA Standard 1288, *Standard for Characterization of Image Sensors and Cameras*, Release 4.0
Linear (European Machine Vision Association, 2021):

* section "Computation of mean and variance of measured gray values": the mean over the ROI of
  a pair of frames, and the temporal variance from the pair difference,
  σ²_y = [mean((A−B)²) − (mean(A) − mean(B))²] / 2;
* sections "Spatial variances" and "Methods for spatial nonuniformity": the spatial variance over
  the ROI of the pixel-wise average of a stack of L frames, which still contains the residual
  temporal variance σ²_y/L (this module does not remove it; the fit does).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from bayescap.exceptions import IngestError, IngestWarning
from bayescap.io.frames import Frame, read_frame
from bayescap.io.manifest import FrameEntry, FrameSet
from bayescap.io.roi import _BAYER_PATTERNS, _channel_pixels, _channel_tiles, parse_roi

__all__ = [
    "SetStatistics",
    "pair_statistics",
    "spatial_variance_dn2",
]


def pair_statistics(a_dn: np.ndarray, b_dn: np.ndarray) -> tuple[float, float]:
    """Mean (DN) and temporal variance (DN²) of a frame pair over the same pixels.

    EMVA 1288 Release 4.0, "Computation of mean and variance of measured gray values":
    μ_y = [mean(A) + mean(B)] / 2 and
    σ²_y = [mean((A − B)²) − (mean(A) − mean(B))²] / 2, computed here as half the (population)
    variance of A − B, which is the same number with less cancellation. The difference removes
    every fixed pattern (DSNU, PRNU, illumination gradients).
    """
    a = np.asarray(a_dn, dtype=np.float64)
    b = np.asarray(b_dn, dtype=np.float64)
    mean_dn = 0.5 * (a.mean() + b.mean())
    temporal_var_dn2 = 0.5 * np.var(a - b)
    return float(mean_dn), float(temporal_var_dn2)


def spatial_variance_dn2(average_dn: np.ndarray) -> float:
    """Spatial variance (DN²) over the ROI of the pixel-wise average of L frames.

    EMVA 1288 Release 4.0, "Spatial variances": s²_y = Σ (⟨y⟩[m,n] − μ_y)² / (MN − 1) with
    ⟨y⟩ the average of the L frames. The residual temporal part σ²_y / L is *not* removed here.
    """
    return float(np.var(np.asarray(average_dn, dtype=np.float64), ddof=1))


@dataclass(frozen=True)
class SetStatistics:
    """Statistics of one set of frames (bright level or dark set) in one channel.

    ``mean_dn`` and ``temporal_var_dn2`` come from the first two frames;
    ``spatial_var_dn2`` from the average of all ``n_frames`` frames;
    ``frac_saturated`` is the fraction of ROI pixel values at or above the white level over all
    frames; ``n_pixels`` counts the ROI pixels of the channel; ``black_level_dn`` is the mean
    black level of the channel's CFA positions.
    """

    mean_dn: float
    temporal_var_dn2: float
    spatial_var_dn2: float
    n_frames: int
    frac_saturated: float
    n_pixels: int
    black_level_dn: float


class _SetAccumulator:
    """Streams the frames of one set: keeps the first pair and a running sum, nothing more."""

    def __init__(self) -> None:
        self.first: np.ndarray | None = None
        self.second: np.ndarray | None = None
        self.total: np.ndarray | None = None
        self.n_frames = 0
        self.n_saturated = 0
        self.n_values = 0
        self.black_dn: list[float] = []

    def add(self, values_dn: np.ndarray, white_level_dn: float, black_dn: float) -> None:
        if self.first is None:
            self.first = values_dn
            self.total = values_dn.copy()
        else:
            if self.second is None:
                self.second = values_dn
            self.total += values_dn
        self.n_frames += 1
        self.n_saturated += int(np.count_nonzero(values_dn >= white_level_dn))
        self.n_values += values_dn.size
        self.black_dn.append(black_dn)

    def result(self) -> SetStatistics:
        mean_dn, temporal_var_dn2 = pair_statistics(self.first, self.second)
        spatial = spatial_variance_dn2(self.total / self.n_frames)
        return SetStatistics(
            mean_dn=mean_dn,
            temporal_var_dn2=temporal_var_dn2,
            spatial_var_dn2=spatial,
            n_frames=self.n_frames,
            frac_saturated=self.n_saturated / self.n_values,
            n_pixels=int(self.first.size),
            black_level_dn=float(np.mean(self.black_dn)),
        )


def _as_override_number(
    metadata: dict[str, str], key: str, source: Path, *, integer: bool = False
) -> float | int | None:
    if key not in metadata or metadata[key] == "":
        return None
    text = metadata[key]
    try:
        value = int(text) if integer else float(text)
    except ValueError:
        raise IngestError(
            f"metadata '# {key}: {text}' is not a " + ("whole number" if integer else "number"), path=source
        ) from None
    if (integer and not 1 <= value <= 32) or (not integer and not (math.isfinite(value) and value >= 0)):
        raise IngestError(f"metadata '# {key}: {text}' is out of range", path=source)
    return value


class _FrameReader:
    """Reads frames of one set description, applies its overrides and checks consistency."""

    def __init__(self, frameset: FrameSet):
        md = frameset.metadata
        src = frameset.source
        self.source = src
        self.adc_bits = _as_override_number(md, "adc_bits", src, integer=True)
        self.black_dn = _as_override_number(md, "black_level_dn", src)
        self.white_dn = _as_override_number(md, "white_level_dn", src)
        cfa = md.get("cfa_pattern")
        if cfa is not None and cfa.strip().lower() in ("", "none", "mono", "monochrome"):
            self.cfa: str | None | bool = None
        elif cfa is not None:
            self.cfa = cfa.strip().upper()
            if self.cfa not in _BAYER_PATTERNS:
                raise IngestError(
                    f"metadata '# cfa_pattern: {cfa}' is not one of {', '.join(_BAYER_PATTERNS)} or mono", path=src
                )
        else:
            self.cfa = False  # no override
        self.shape = frameset.frame_shape_hw
        self.shape_from: str = f"the descriptor's 'n' line ({src.name})"
        self.reference: Frame | None = None

    def read(self, entry: FrameEntry) -> Frame:
        frame = read_frame(entry.path)
        changes = {}
        if self.cfa is not False:
            changes["cfa_pattern"] = self.cfa
        if self.adc_bits is not None:
            changes["adc_bits"] = self.adc_bits
            changes["white_level_dn"] = float(2**self.adc_bits - 1)
        if self.white_dn is not None:
            changes["white_level_dn"] = float(self.white_dn)
        cfa = changes.get("cfa_pattern", frame.cfa_pattern)
        black = self.black_dn if self.black_dn is not None else frame.black_level_dn
        if cfa is None:
            black = float(np.mean(black))
        elif np.ndim(black) == 0:
            black = np.full((2, 2), float(black))
        changes["black_level_dn"] = black
        frame = replace(frame, **changes)
        if self.shape is None:
            self.shape = frame.shape
            self.shape_from = f"the first frame ({entry.path.name})"
        if frame.shape != self.shape:
            raise IngestError(
                f"frame size {frame.shape[1]}x{frame.shape[0]} differs from "
                f"{self.shape[1]}x{self.shape[0]} of {self.shape_from}; all "
                "frames of a measurement must have the same size",
                path=entry.path,
            )
        if self.reference is None:
            self.reference = frame
        elif frame.cfa_pattern != self.reference.cfa_pattern:
            raise IngestError(
                f"CFA pattern {frame.cfa_pattern} differs from "
                f"{self.reference.cfa_pattern} of {self.reference.path.name}",
                path=entry.path,
            )
        elif not np.array_equal(frame.black_level_dn, self.reference.black_level_dn):
            warnings.warn(
                f"{entry.path}: black level {frame.black_level_dn} differs from "
                f"{self.reference.black_level_dn} of {self.reference.path.name}; "
                "the CSV reports the first frame's",
                IngestWarning,
                stacklevel=3,
            )
        return frame


def _set_statistics(
    entries: Iterable[FrameEntry],
    reader: _FrameReader,
    roi: str | float | Sequence[int] | None,
    channels: Sequence[str],
    state: dict,
) -> dict[str, SetStatistics]:
    """Statistics of one frame set for every requested channel (each frame read once)."""
    accumulators = {c: _SetAccumulator() for c in channels}
    for entry in entries:
        frame = reader.read(entry)
        if "roi" not in state:
            state["roi"] = parse_roi(roi, frame.shape, cfa=frame.cfa_pattern is not None)
        x0, y0, x1, y1 = state["roi"]
        roi_pixels = frame.pixels[y0:y1, x0:x1]
        for c in channels:
            tiles = _channel_tiles(frame.cfa_pattern, c)
            black = (
                float(frame.black_level_dn)
                if tiles is None
                else float(np.mean([frame.black_level_dn[i, j] for i, j in tiles]))
            )
            accumulators[c].add(_channel_pixels(roi_pixels, tiles), frame.white_level_dn, black)
    return {c: acc.result() for c, acc in accumulators.items()}
