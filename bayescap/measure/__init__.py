"""Slanted-edge MTF measurement (ISO 12233 e-SFR), MTF tables and synthetic edges."""

from bayescap.measure.result import SFRResult
from bayescap.measure.sfr import LUMINANCE_WEIGHTS, measure_sfr
from bayescap.measure.synthetic import synthetic_edge, synthetic_edge_mtf
from bayescap.measure.table import read_image, read_mtf_table, write_mtf_table

__all__ = [
    "LUMINANCE_WEIGHTS",
    "SFRResult",
    "measure_sfr",
    "read_image",
    "read_mtf_table",
    "synthetic_edge",
    "synthetic_edge_mtf",
    "write_mtf_table",
]
