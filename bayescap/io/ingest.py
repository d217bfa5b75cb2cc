"""Frames -> photon-transfer table: RAW/DNG/TIFF/PNG/.npy frames to the contract CSV.

The pipeline reads like the measurement:

1. a *frame-set description* lists the frames: a manifest CSV (:func:`read_manifest`) or an
   EMVA 1288 descriptor file (:func:`read_emva_descriptor`);
2. bright frames are grouped into *exposure levels*, each with the dark set taken at the same
   exposure time (:func:`group_levels`);
3. every frame is read once (:func:`read_frame`), cut to the region of interest (ROI) and to one
   colour plane of the colour filter array (CFA) (:func:`parse_roi`, :func:`split_cfa`);
4. per level, the mean and the temporal variance of a frame pair and, for stacks of more than two
   frames, the spatial variance of the averaged frame are computed (:func:`pair_statistics`,
   :func:`spatial_variance_dn2`), as in EMVA 1288 Release 4.0;
5. one photon-transfer CSV per channel is written atomically (:func:`ingest`).

The steps live in :mod:`bayescap.io.manifest` (1, 2), :mod:`bayescap.io.frames` (3),
:mod:`bayescap.io.roi` (3) and :mod:`bayescap.io.statistics` (4); this module runs them.

The formulas follow EMVA Standard 1288, Release 4.0 Linear; the sections are cited in
:mod:`bayescap.io.statistics` and :mod:`bayescap.io.manifest`.

The CSV format is the project's interface contract (photon-transfer CSV); ``docs/ingest.md``
describes the inputs, options and formulas for users.
"""

from __future__ import annotations

import csv
import io
import os
import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from bayescap._progress import bar
from bayescap.exceptions import IngestError, IngestWarning
from bayescap.io.atomic import output_problem, write_files_atomically
from bayescap.io.frames import _bits_for_white_level
from bayescap.io.manifest import group_levels, load_frame_set
from bayescap.io.roi import _SINGLE_CHANNELS, CHANNELS
from bayescap.io.statistics import SetStatistics, _FrameReader, _set_statistics

__all__ = [
    "ingest",
]


#: Manifest metadata keys that describe the frames themselves (they override the files).
_FRAME_OVERRIDE_KEYS = ("adc_bits", "black_level_dn", "white_level_dn", "cfa_pattern")


def _fmt(value: float | int | None) -> str:
    if value is None:
        return ""
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)


def _table_text(metadata: dict[str, str], rows: list[dict[str, float | int | None]]) -> str:
    columns = ["exposure_time_s", "mean_dn", "temporal_var_dn2", "dark_mean_dn", "dark_temporal_var_dn2", "n_pixels"]
    for optional in ("photons_per_pixel", "exposure_lux_s"):
        if any(r.get(optional) is not None for r in rows):
            columns.append(optional)
    if any(r["n_frames"] > 2 or r["dark_n_frames"] > 2 for r in rows):
        # one stack makes the spatial columns appear, and then every row carries them (the
        # contract refuses empty cells; a pair gives the spatial variance of its average)
        columns += ["spatial_var_dn2", "dark_spatial_var_dn2", "n_frames", "dark_n_frames"]
    columns.append("frac_saturated")
    buf = io.StringIO()
    for key, value in metadata.items():
        buf.write(f"# {key}: {' '.join(str(value).split())}\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for r in rows:
        writer.writerow([_fmt(r.get(c)) for c in columns])
    return buf.getvalue()


def _output_paths(out: Path, source: Path, channels: Sequence[str], suffixed: bool) -> dict[str, Path]:
    if out.is_dir():
        stem = source.parent.name if source.name == "manifest.csv" else source.stem
        out = out / f"{stem or 'ptc'}.csv"
    if not suffixed:
        return {channels[0]: out}
    suffix = out.suffix or ".csv"
    return {c: out.with_name(f"{out.stem}_{c}{suffix}") for c in channels}


def _sensor_name(make: str | None, model: str | None) -> str | None:
    if make and model and not model.lower().startswith(make.lower()):
        return f"{make} {model}"
    return model or make


def _refuse_reused_frames(frameset, levels) -> None:
    """Refuse a level whose pair is one file twice, or whose bright frames are also its dark: the
    pair variance would be 0 (or the signal 0), data that cannot be right."""
    for level in levels:
        bright = [e.path.resolve() for e in level.bright]
        dark = [e.path.resolve() for e in level.dark]
        at = f"at exposure_time_s={level.exposure_time_s:g}"
        for kind, paths in (("bright", bright), ("dark", dark)):
            if len(set(paths[:2])) < 2:
                raise IngestError(
                    f"{at} the {kind} pair is {paths[0].name} twice: a pair needs two exposures "
                    "(their difference is the temporal noise)",
                    path=frameset.source,
                )
        both = sorted(p.name for p in set(bright) & set(dark))
        if both:
            raise IngestError(
                f"{at} {', '.join(both)} is listed both as a bright frame and as the dark frame: "
                "the dark must be taken with the light off",
                path=frameset.source,
            )


def _refuse_identical_pair(frameset, level, b: SetStatistics, d: SetStatistics) -> None:
    """Refuse a pair whose two frames are identical (variance exactly 0 below saturation): the same
    exposure saved twice."""
    for kind, st, entries in (("bright", b, level.bright), ("dark", d, level.dark)):
        if st.temporal_var_dn2 == 0 and st.frac_saturated < 1:
            names = " and ".join(e.path.name for e in entries[:2])
            raise IngestError(
                f"at exposure_time_s={level.exposure_time_s:g} the {kind} frames {names} are identical "
                "(pair variance exactly 0 below saturation): the same exposure saved twice?",
                path=frameset.source,
            )


def _add_notices(notices, frameset, rows, channels, adc_bits) -> None:
    """What the ingest assumed and the plausibility warnings of the table it wrote."""
    from bayescap.io.plausibility import plausibility_warnings
    from bayescap.io.ptc_csv import PTCData

    t = [r["exposure_time_s"] for r in rows[channels[0]]]
    if frameset.format == "emva":
        notices.append(
            (
                "note",
                f"{frameset.source.name}: exposure times read in ns (the EMVA 1288 descriptor's unit, as the "
                f"emva1288 reference implementation reads them): {min(t) * 1e9:g}–{max(t) * 1e9:g} ns = "
                f"{min(t):.3g}–{max(t):.3g} s",
            )
        )
    for c in channels:
        r = rows[c]
        col = lambda k, r=r: np.array([x[k] if x.get(k) is not None else np.nan for x in r], float)
        mu_p = col("photons_per_pixel")
        data = PTCData(
            exposure_time_s=col("exposure_time_s"),
            mean_dn=col("mean_dn"),
            temporal_var_dn2=col("temporal_var_dn2"),
            dark_mean_dn=col("dark_mean_dn"),
            dark_temporal_var_dn2=col("dark_temporal_var_dn2"),
            n_pixels=col("n_pixels"),
            photons_per_pixel=mu_p if np.all(np.isfinite(mu_p)) else None,
            frac_saturated=col("frac_saturated"),
            metadata={"adc_bits": adc_bits},
        )
        for w in plausibility_warnings(data):
            notices.append(("warning", (f"channel {c}: " if len(channels) > 1 else "") + w["message"]))


def ingest(
    source: os.PathLike | str,
    *,
    out: os.PathLike | str,
    roi: str | float | Sequence[int] | None = None,
    channel: str = "G",
    fmt: str = "auto",
    progress: bool = False,
    notices: list | None = None,
) -> list[Path]:
    """Turn a set of frames into photon-transfer CSV file(s) (the project's input contract).

    Parameters
    ----------
    source : path-like
        A manifest CSV, an EMVA 1288 descriptor, or a directory holding ``manifest.csv`` or one
        descriptor ``*.txt`` (see :func:`load_frame_set`).
    out : path-like
        The CSV to write. With ``channel="all"`` on a Bayer sensor, four files are written with
        ``_R``, ``_Gr``, ``_Gb`` and ``_B`` before the suffix (``ptc.csv`` -> ``ptc_R.csv`` ...).
        An existing directory receives ``<source name>.csv``.
    roi : str, float, sequence or None
        ``"x0,y0,x1,y1"`` in full-frame pixels (x1, y1 exclusive), or a centred fraction of each
        dimension; default the centred 50 % (see :func:`parse_roi`).
    channel : {"R", "Gr", "Gb", "B", "G", "all"}
        Bayer channel; ``G`` pools the Gr and Gb pixels into one set (means, variances and
        ``n_pixels`` over both). Ignored for monochrome frames (one file, ``# channel: mono``).
    progress : a bar of the exposure levels read, on stderr.
    notices : a list that receives ``(kind, text)`` pairs: ``"note"`` for what was assumed (the
        EMVA descriptor's time unit) and ``"warning"`` for the plausibility warnings of the table
        (:func:`bayescap.io.plausibility.plausibility_warnings`).
    fmt : {"auto", "manifest", "emva"}
        How to read ``source``.

    Returns
    -------
    list of pathlib.Path
        The files written.

    Raises
    ------
    IngestError
        Any problem with the description or the frames; nothing is written then.

    Notes
    -----
    Per exposure level (EMVA 1288 Release 4.0, photon-transfer method): ``mean_dn`` and
    ``temporal_var_dn2`` from the first two bright frames (:func:`pair_statistics`), the same
    for the first two dark frames at that exposure time; with L > 2 frames also
    ``spatial_var_dn2`` (:func:`spatial_variance_dn2`) and ``n_frames = L`` (``dark_*`` for the
    dark set); ``frac_saturated`` over all bright frames of the level.
    """
    if channel not in CHANNELS:
        raise IngestError(f"unknown channel {channel!r} (use one of {', '.join(CHANNELS)})")
    source = Path(source)
    out = Path(out)
    frameset = load_frame_set(source, fmt=fmt)
    levels = group_levels(frameset)
    _refuse_reused_frames(frameset, levels)
    reader = _FrameReader(frameset)

    # The first frame decides mono vs Bayer, hence which channels are measured.
    first = reader.read(levels[0].bright[0])
    mono = first.cfa_pattern is None
    channels = ["mono"] if mono else (list(_SINGLE_CHANNELS) if channel == "all" else [channel])
    stat_channels = ["G"] if mono else channels  # any name works for mono: tiles are None
    # before the frames are read: an output over an input, or one that cannot be written
    paths = _output_paths(out, frameset.source, channels, suffixed=len(channels) > 1)
    inputs = [frameset.source] + [e.path for e in frameset.entries]
    for p in paths.values():
        problem = output_problem(p, inputs, option="--out")
        if problem:
            raise IngestError(problem)

    state: dict = {}
    dark_cache: dict[tuple[Path, ...], dict[str, SetStatistics]] = {}
    rows: dict[str, list[dict]] = {c: [] for c in channels}
    level_bar = bar(progress, total=len(levels), desc="ingest: exposure levels", unit="level")
    for level in levels:
        bright = _set_statistics(level.bright, reader, roi, stat_channels, state)
        key = tuple(e.path for e in level.dark)
        if key not in dark_cache:
            dark_cache[key] = _set_statistics(level.dark, reader, roi, stat_channels, state)
        dark = dark_cache[key]
        n_bright, n_dark = len(level.bright), len(level.dark)
        if n_bright != n_dark and max(n_bright, n_dark) > 2:
            warnings.warn(
                f"{frameset.source}: at exposure_time_s={level.exposure_time_s:g} "
                f"the bright stack has {n_bright} frames and the dark set {n_dark}; "
                "the CSV gives both (n_frames, dark_n_frames), but a reader that "
                "knows only n_frames will misjudge the residual temporal part of "
                "dark_spatial_var_dn2",
                IngestWarning,
                stacklevel=2,
            )
        for c, sc in zip(channels, stat_channels):
            b, d = bright[sc], dark[sc]
            _refuse_identical_pair(frameset, level, b, d)
            rows[c].append(
                {
                    "exposure_time_s": level.exposure_time_s,
                    "mean_dn": b.mean_dn,
                    "temporal_var_dn2": b.temporal_var_dn2,
                    "dark_mean_dn": d.mean_dn,
                    "dark_temporal_var_dn2": d.temporal_var_dn2,
                    "n_pixels": b.n_pixels,
                    "photons_per_pixel": level.photons_per_pixel,
                    "exposure_lux_s": level.exposure_lux_s,
                    "spatial_var_dn2": b.spatial_var_dn2,
                    "dark_spatial_var_dn2": d.spatial_var_dn2,
                    "n_frames": b.n_frames,
                    "dark_n_frames": d.n_frames,
                    "frac_saturated": b.frac_saturated,
                    "_black": b.black_level_dn,
                }
            )
        level_bar.update(1)

    level_bar.close()
    ref = reader.reference
    height, width = reader.shape
    x0, y0, x1, y1 = state["roi"]
    adc_bits = ref.adc_bits if ref.adc_bits is not None else _bits_for_white_level(ref.white_level_dn)
    files = {}
    for c in channels:
        md: dict[str, str] = {}
        sensor = frameset.metadata.get("sensor") or _sensor_name(ref.make, ref.model)
        if sensor:
            md["sensor"] = sensor
        if ref.make and "manufacturer" not in frameset.metadata:
            md["manufacturer"] = ref.make
        md["width_px"] = str(width)
        md["height_px"] = str(height)
        md["adc_bits"] = str(adc_bits)
        md["black_level_dn"] = _fmt(rows[c][0]["_black"])
        md["white_level_dn"] = _fmt(ref.white_level_dn)
        md["channel"] = c
        md["cfa_pattern"] = ref.cfa_pattern or "none"
        md["roi_px"] = f"x0={x0} y0={y0} x1={x1} y1={y1}"
        md["source"] = frameset.source.name
        for key, value in frameset.metadata.items():
            if key not in md and key not in _FRAME_OVERRIDE_KEYS:
                md[key] = value
        files[paths[c]] = _table_text(md, rows[c])
    if notices is not None:
        _add_notices(notices, frameset, rows, channels, adc_bits)
    try:
        write_files_atomically(files)
    except OSError as exc:
        raise IngestError(
            f"cannot write the output ({exc.strerror or exc})", path=getattr(exc, "filename", None) or next(iter(files))
        ) from exc
    return list(paths.values())
