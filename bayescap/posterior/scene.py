"""Where a fit's derived quantities are evaluated: :class:`Scene` (exposure time, temperature)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from bayescap.io.ptc_csv import _ABSOLUTE_ZERO_C, _MAX_ABS_VALUE

__all__ = ["Scene"]


@dataclass(frozen=True)
class Scene:
    """Where TR and capacity are evaluated: exposure time (dark-current charge and shot noise).

    ``temperature_c`` with ``reference_temperature_c`` scales the dark current by 2^(ΔT/6 °C)
    (paper, Section 2.2)."""

    exposure_time_s: float
    source: str = "given"
    temperature_c: float | None = None
    reference_temperature_c: float | None = None

    def __post_init__(self):
        # bounded so that the dark signal and the noise budget stay finite
        if not 0.0 <= self.exposure_time_s <= _MAX_ABS_VALUE:
            raise ValueError(
                f"scene exposure time must be a number in [0, {_MAX_ABS_VALUE:g}] s, got {self.exposure_time_s}"
            )
        for t in (self.temperature_c, self.reference_temperature_c):
            if t is not None and not _ABSOLUTE_ZERO_C <= t < math.inf:
                raise ValueError(f"scene temperature must be a finite number >= {_ABSOLUTE_ZERO_C:g} °C, got {t}")

    @property
    def dark_current_factor(self) -> float:
        if self.temperature_c is None or self.reference_temperature_c is None:
            return 1.0
        return 2.0 ** ((self.temperature_c - self.reference_temperature_c) / 6.0)

    def to_dict(self):
        d = {"exposure_time_s": self.exposure_time_s, "source": self.source}
        if self.temperature_c is not None:
            d["temperature_c"] = self.temperature_c
            d["reference_temperature_c"] = self.reference_temperature_c
            d["dark_current_factor"] = self.dark_current_factor
        return d
