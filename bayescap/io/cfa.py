"""The four Bayer channels of one sensor as four photon-transfer tables, read in one pass.

Two sources give them:

* a frame set (manifest CSV, EMVA 1288 descriptor or a directory holding one) of RAW/DNG (or
  PNG/TIFF/npy with ``# cfa_pattern:``) flat and dark frames: every frame is read once and its
  R, Gr, Gb and B planes measured as ``bayescap ingest --channel all`` does
  (:func:`bayescap.io.ingest`, run into a temporary folder, so the tables are exactly that
  command's files);
* four photon-transfer CSVs, one per channel (``bayescap ingest --channel all``'s ``*_R.csv``,
  ``*_Gr.csv``, ``*_Gb.csv``, ``*_B.csv``, or any with ``# channel:`` lines).

Either way the four tables must describe one measurement: the same exposure levels and the same
number of pixels per channel. A frame set without a colour filter array, or tables that do not
match, is refused with an :class:`~bayescap.exceptions.IngestError` naming the file.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from bayescap.exceptions import IngestError
from bayescap.io.ptc_csv import PTCData, read_ptc_csv

__all__ = ["CFA_CHANNELS", "CFATables", "ingest_cfa", "read_cfa_tables", "load_cfa"]

CFA_CHANNELS = ("R", "Gr", "Gb", "B")

_SUFFIX = re.compile(r"_(R|Gr|Gb|B)$")


@dataclass(frozen=True)
class CFATables:
    """The four channels' tables of one sensor and where they came from.

    ``tables``: channel -> PTCData; ``source``: what was given; ``first_frame``: the first frame
    file of a frame set (its RAW metadata hold the camera's colour matrix), ``None`` for CSVs;
    ``notices``: the ingest's ``(kind, text)`` notes and plausibility warnings.
    """

    tables: dict
    source: Path
    cfa_pattern: str | None
    first_frame: Path | None = None
    notices: tuple = ()

    @property
    def n_pixels(self) -> int:
        """Pixels per channel (the first row's ``n_pixels``)."""
        return int(self.tables[CFA_CHANNELS[0]].n_pixels[0])


def ingest_cfa(source: os.PathLike | str, *, roi=None, fmt: str = "auto") -> CFATables:
    """Measure R, Gr, Gb and B of a frame set in one pass (module docstring).

    Raises
    ------
    IngestError
        The frames carry no colour filter array (naming the first frame), or any problem
        :func:`bayescap.io.ingest` refuses.
    """
    from bayescap.io.ingest import ingest
    from bayescap.io.manifest import load_frame_set

    source = Path(source)
    frameset = load_frame_set(source, fmt=fmt)
    first = frameset.entries[0].path if frameset.entries else source
    with tempfile.TemporaryDirectory(prefix="bayescap-cfa-") as tmp:
        notices: list = []
        paths = ingest(source, out=Path(tmp) / "ptc.csv", roi=roi, channel="all", fmt=fmt, notices=notices)
        if len(paths) == 1:  # a monochrome frame: ingest wrote one '# channel: mono' table
            raise IngestError(
                "the frame has no colour filter array (a monochrome sensor): colour needs a Bayer RAW/DNG "
                "(or '# cfa_pattern:' in the manifest for PNG/TIFF frames)",
                path=first,
            )
        tables = {c: read_ptc_csv(p) for c, p in zip(CFA_CHANNELS, paths)}
    tables = {c: _named(t, f"{source.name} [{c}]") for c, t in tables.items()}
    pattern = tables["R"].metadata.get("cfa_pattern")
    return CFATables(tables=tables, source=source, cfa_pattern=pattern, first_frame=first, notices=tuple(notices))


def _named(data: PTCData, name: str) -> PTCData:
    from dataclasses import replace

    return replace(data, source=name)


def _channel_of(data: PTCData, path: Path) -> str | None:
    ch = str(data.metadata.get("channel", "")).strip()
    if ch in CFA_CHANNELS:
        return ch
    m = _SUFFIX.search(path.stem)
    return m.group(1) if m else None


def read_cfa_tables(paths: Sequence[os.PathLike | str]) -> CFATables:
    """Four photon-transfer CSVs, one per Bayer channel (module docstring).

    The channel of each file is its ``# channel:`` line, else the ``_R``/``_Gr``/``_Gb``/``_B``
    end of its name.

    Raises
    ------
    IngestError
        Not four files, a channel missing or twice, or channels of different sizes (exposure
        levels or ``n_pixels`` that differ), naming the file.
    """
    paths = [Path(p) for p in paths]
    if len(paths) != 4:
        raise IngestError(
            f"{len(paths)} photon-transfer CSV(s) given; colour needs the four Bayer channels R, Gr, Gb, B "
            "(bayescap ingest --channel all writes them), or one frame set",
            path=paths[0] if paths else None,
        )
    tables: dict[str, PTCData] = {}
    where: dict[str, Path] = {}
    for p in paths:
        data = read_ptc_csv(p)
        ch = _channel_of(data, p)
        if ch is None:
            raise IngestError(
                "which Bayer channel is this? give a '# channel: R|Gr|Gb|B' line or end the name in _R, _Gr, _Gb or _B",
                path=p,
            )
        if ch in tables:
            raise IngestError(f"channel {ch} given twice (also {where[ch].name})", path=p)
        tables[ch], where[ch] = data, p
    ref = tables["R"]
    for ch in CFA_CHANNELS[1:]:
        d, p = tables[ch], where[ch]
        if d.n_levels != ref.n_levels or not np.allclose(
            np.sort(d.exposure_time_s), np.sort(ref.exposure_time_s), rtol=1e-6, atol=0
        ):
            raise IngestError(
                f"channel {ch} has {d.n_levels} exposure levels where R ({where['R'].name}) has {ref.n_levels} "
                "or other exposure times: the four channels must come from the same frames",
                path=p,
            )
        if not np.array_equal(np.sort(d.n_pixels), np.sort(ref.n_pixels)):
            raise IngestError(
                f"channels of different sizes: {ch} has n_pixels {int(np.median(d.n_pixels))} where R "
                f"({where['R'].name}) has {int(np.median(ref.n_pixels))}: the four planes of one ROI have equal sizes",
                path=p,
            )
    pattern = ref.metadata.get("cfa_pattern")
    return CFATables(tables=tables, source=where["R"], cfa_pattern=pattern if pattern != "none" else None)


def load_cfa(inputs: Sequence[os.PathLike | str], *, roi=None, fmt: str = "auto") -> CFATables:
    """A frame set (one manifest/descriptor/directory) or four channel CSVs."""
    inputs = [Path(p) for p in inputs]
    if len(inputs) == 1 and not (inputs[0].suffix.lower() == ".csv" and _is_ptc_csv(inputs[0])):
        return ingest_cfa(inputs[0], roi=roi, fmt=fmt)
    return read_cfa_tables(inputs)


def _is_ptc_csv(path: Path) -> bool:
    """A photon-transfer CSV (its header has ``mean_dn``), not a manifest (``file,kind,...``)."""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for line in fh:
                if line.strip() and not line.lstrip().startswith("#"):
                    return "mean_dn" in line
    except (OSError, UnicodeDecodeError):
        return False
    return False
