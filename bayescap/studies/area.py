"""A fixed imaging area (an optical format or W x H mm) and the crop of a sensor that fills it, for
comparing sensors at the same area (the paper's Section 4)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from bayescap.exceptions import CompareInputError
from bayescap.physics.optics import OPTICAL_FORMATS

#: a sensor within 2 % of the area in both directions counts as filling it (formats are nominal)
AREA_TOLERANCE = 0.02


@dataclass(frozen=True)
class ImagingArea:
    name: str
    width_mm: float
    height_mm: float

    @property
    def diagonal_mm(self) -> float:
        return math.hypot(self.width_mm, self.height_mm)

    def to_dict(self):
        return {
            "name": self.name,
            "width_mm": self.width_mm,
            "height_mm": self.height_mm,
            "diagonal_mm": self.diagonal_mm,
        }


def parse_area(text: str | None) -> ImagingArea | None:
    """``"1/4in"``, ``'1/4"'``, ``"1/4"``, ``"2/3in"``, ``"full-frame"`` or ``"5.0x3.75mm"``;
    ``None``/``"none"`` means no area comparison."""
    if text is None or str(text).strip().lower() in ("", "none", "full"):
        return None
    t = str(text).strip().lower().replace("″", '"').replace("inch", "in")
    m = re.fullmatch(r"([0-9.]+)\s*[x×]\s*([0-9.]+)\s*mm", t)
    if m:
        w, h = float(m.group(1)), float(m.group(2))
        if not (w > 0 and h > 0):
            raise CompareInputError(f"--area {text!r}: width and height must be positive")
        return ImagingArea(f"{w:g}x{h:g}mm", w, h)
    key = re.sub(r'(in|")$', "", t).strip()
    if key in OPTICAL_FORMATS:
        w, h = OPTICAL_FORMATS[key]
        return ImagingArea(f'{key}"' if key[0].isdigit() else key, w, h)
    known = ", ".join(f"{k}in" if k[0].isdigit() else k for k in OPTICAL_FORMATS)
    raise CompareInputError(f"--area {text!r} is not a known optical format ({known}) nor WxHmm (e.g. 3.6x2.7mm)")


@dataclass(frozen=True)
class AreaCrop:
    """The pixels of a sensor that fall inside an imaging area."""

    width_px: int
    height_px: int
    cropped: bool
    smaller_than_area: bool
    covered_fraction: float  # sensor-used area / imaging area

    @property
    def pixels(self) -> int:
        return self.width_px * self.height_px

    def to_dict(self):
        return {
            "width_px": self.width_px,
            "height_px": self.height_px,
            "pixels": self.pixels,
            "cropped": self.cropped,
            "smaller_than_area": self.smaller_than_area,
            "covered_fraction": self.covered_fraction,
        }


def area_crop(width_px: int, height_px: int, pitch_um: float, area: ImagingArea) -> AreaCrop:
    """Pixels of a ``width_px × height_px`` sensor of pitch ``pitch_um`` inside ``area``.

    The area is turned to the sensor's orientation (portrait sensors get a portrait area). Each
    direction keeps ``min(sensor pixels, floor(area_mm·1000/pitch))``.

    >>> c = area_crop(2056, 1544, 2.2, parse_area("1/4in")); (c.width_px, c.height_px, c.cropped)
    (1636, 1227, True)
    """
    if not (pitch_um and pitch_um > 0):
        raise CompareInputError(f"pixel pitch must be positive, got {pitch_um}")
    aw, ah = area.width_mm, area.height_mm
    if (width_px < height_px) != (aw < ah):
        aw, ah = ah, aw
    fit_w = int(math.floor(aw * 1000.0 / pitch_um + 1e-9))
    fit_h = int(math.floor(ah * 1000.0 / pitch_um + 1e-9))
    w, h = min(int(width_px), fit_w), min(int(height_px), fit_h)
    cropped = w < width_px or h < height_px
    smaller = (
        width_px < (1 - AREA_TOLERANCE) * aw * 1000.0 / pitch_um
        or height_px < (1 - AREA_TOLERANCE) * ah * 1000.0 / pitch_um
    )
    covered = (w * pitch_um * 1e-3) * (h * pitch_um * 1e-3) / (aw * ah)
    return AreaCrop(
        width_px=w, height_px=h, cropped=bool(cropped), smaller_than_area=bool(smaller), covered_fraction=float(covered)
    )
