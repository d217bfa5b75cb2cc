"""Input and output: the photon-transfer CSV contract and frames -> photon-transfer CSV."""

from bayescap.io.atomic import atomic_write_text
from bayescap.io.frames import Frame, read_frame
from bayescap.io.ingest import ingest
from bayescap.io.manifest import (
    ExposureLevel,
    FrameEntry,
    FrameSet,
    group_levels,
    load_frame_set,
    read_emva_descriptor,
    read_manifest,
)
from bayescap.io.ptc_csv import PTCData, read_ptc_csv, write_ptc_csv
from bayescap.io.roi import CHANNELS, cfa_positions, parse_roi, split_cfa
from bayescap.io.statistics import SetStatistics, pair_statistics, spatial_variance_dn2

__all__ = [
    "CHANNELS",
    "ExposureLevel",
    "Frame",
    "FrameEntry",
    "FrameSet",
    "PTCData",
    "SetStatistics",
    "atomic_write_text",
    "cfa_positions",
    "group_levels",
    "ingest",
    "load_frame_set",
    "pair_statistics",
    "parse_roi",
    "read_emva_descriptor",
    "read_frame",
    "read_manifest",
    "read_ptc_csv",
    "spatial_variance_dn2",
    "split_cfa",
    "write_ptc_csv",
]
