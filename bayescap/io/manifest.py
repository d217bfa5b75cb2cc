"""Frame-set descriptions: manifest CSVs, EMVA 1288 descriptor files and exposure levels.

A frame set lists the frames of one photon-transfer measurement (:func:`read_manifest`,
:func:`read_emva_descriptor`, :func:`load_frame_set`); :func:`group_levels` groups its bright
frames into exposure levels, each with the dark set taken at the same exposure time.

References
----------
EMVA Standard 1288, Release 4.0 Linear, section "Evaluation of the measurements according to
the photon transfer method": one bright pair per exposure level and a dark pair at the same
exposure time. The descriptor file format is that of the EMVA 1288 reference implementation
(github.com/EMVA1288/emva1288, ``emva1288.process.parser``): ``n bits width height``,
``b texp_ns photons``, ``d texp_ns`` and ``i path`` lines.
"""

from __future__ import annotations

import csv
import math
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path, PureWindowsPath

from bayescap.exceptions import IngestError, IngestWarning
from bayescap.io.frames import _exposure_time_from_file

__all__ = [
    "FrameEntry",
    "FrameSet",
    "ExposureLevel",
    "read_manifest",
    "read_emva_descriptor",
    "load_frame_set",
    "group_levels",
]


_REQUIRED_MANIFEST_COLUMNS = ("file", "kind", "exposure_time_s")


_OPTIONAL_MANIFEST_COLUMNS = ("photons_per_pixel", "exposure_lux_s")


@dataclass(frozen=True)
class FrameEntry:
    """One frame of a frame set: its file, its kind and the exposure it was taken with.

    ``exposure_time_s`` in s; ``photons_per_pixel`` (EMVA 1288 μ_p, photons) and
    ``exposure_lux_s`` (lux·s) only for bright frames, when known. ``source`` and ``row`` locate
    the entry in its description (file and line number) for error messages.
    """

    path: Path
    kind: str
    exposure_time_s: float | None
    photons_per_pixel: float | None = None
    exposure_lux_s: float | None = None
    source: Path | None = None
    row: int | None = None


@dataclass
class FrameSet:
    """The frames of one measurement and what their description says about them.

    ``metadata`` holds ``# key: value`` lines of a manifest (or what an EMVA descriptor says);
    the keys ``adc_bits``, ``black_level_dn``, ``white_level_dn`` and ``cfa_pattern`` override
    what the frame files say, the others pass through to the CSV. ``frame_shape_hw`` is the
    (height, width) every frame must have when the description states it.
    """

    source: Path
    entries: list[FrameEntry]
    metadata: dict[str, str] = field(default_factory=dict)
    frame_shape_hw: tuple[int, int] | None = None
    format: str = "manifest"


def _local_path(text: str, base: Path) -> Path:
    """A path from a description, relative to ``base``; Windows backslashes are accepted."""
    text = text.strip()
    if "\\" in text and os.sep != "\\":
        win = PureWindowsPath(text)
        path = Path(*win.parts) if not win.drive else Path(text)
    else:
        path = Path(text)
    return path if path.is_absolute() else base / path


def _parse_float(text: str, *, path: Path, row: int | None, column: str, allow_empty: bool) -> float | None:
    text = text.strip()
    if not text:
        if allow_empty:
            return None
        raise IngestError("value is missing", path=path, row=row, column=column)
    try:
        value = float(text.replace(",", ".") if text.count(",") == 1 and "." not in text else text)
    except ValueError:
        raise IngestError(f"{text!r} is not a number", path=path, row=row, column=column) from None
    if not math.isfinite(value):
        raise IngestError(f"{text!r} is not a finite number", path=path, row=row, column=column)
    if value < 0:
        raise IngestError(f"{text!r} is negative", path=path, row=row, column=column)
    return value


def _parse_metadata_line(line: str) -> tuple[str, str] | None:
    """``# key: value`` -> (key, value); other comment lines -> None."""
    body = line.lstrip()[1:].strip()
    if ":" not in body:
        return None
    key, value = body.split(":", 1)
    key = key.strip()
    if not key or " " in key:
        return None
    return key, value.strip()


def read_manifest(path: os.PathLike | str) -> FrameSet:
    """Read a manifest CSV that lists the frames of a photon-transfer measurement.

    Format (UTF-8, comma separated, one header row)::

        # adc_bits: 12            <- optional metadata lines, see below
        file,kind,exposure_time_s,photons_per_pixel,exposure_lux_s
        img/b_000_a.dng,bright,0.00004,120,
        img/b_000_b.dng,bright,0.00004,120,
        img/d_000_a.dng,dark,0.00004,,
        img/d_000_b.dng,dark,0.00004,,

    ``file`` is relative to the manifest; ``kind`` is ``bright`` or ``dark``;
    ``exposure_time_s`` (s) may be left empty for files that record their exposure time (RAW,
    DNG, TIFF with an ExposureTime tag). ``photons_per_pixel`` (EMVA 1288 μ_p) and
    ``exposure_lux_s`` (lux·s) are optional. Lines starting with ``#`` are comments;
    ``# key: value`` lines are metadata: ``adc_bits``, ``black_level_dn``, ``white_level_dn``
    and ``cfa_pattern`` override what the files say (useful for PNG/TIFF frames, which carry
    none of these), all other keys (``sensor``, ``pixel_pitch_um``, ...) pass through to the
    photon-transfer CSV.

    Raises
    ------
    IngestError
        Naming the manifest, the row (line number in the file) and the column of a bad entry,
        or a listed file that does not exist.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise IngestError(f"cannot read the manifest ({exc.strerror or exc})", path=path) from exc
    except UnicodeDecodeError as exc:
        raise IngestError(f"the manifest is not UTF-8 text ({exc.reason})", path=path) from exc
    base = path.parent
    metadata: dict[str, str] = {}
    header: list[str] | None = None
    entries: list[FrameEntry] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if line.lstrip().startswith("#"):
            item = _parse_metadata_line(line)
            if item is not None:
                metadata[item[0]] = item[1]
            continue
        fields = [f.strip() for f in next(csv.reader([line]))]
        if header is None:
            header = fields
            for name in _REQUIRED_MANIFEST_COLUMNS:
                if name not in header:
                    raise IngestError(
                        f"the header has no '{name}' column (a manifest needs {', '.join(_REQUIRED_MANIFEST_COLUMNS)})",
                        path=path,
                        row=lineno,
                    )
            known = _REQUIRED_MANIFEST_COLUMNS + _OPTIONAL_MANIFEST_COLUMNS
            for name in header:
                if name not in known:
                    raise IngestError(
                        f"unknown column (known columns: {', '.join(known)})", path=path, row=lineno, column=name
                    )
            if len(set(header)) != len(header):
                raise IngestError("a column name appears twice in the header", path=path, row=lineno)
            continue
        if len(fields) != len(header):
            raise IngestError(f"{len(fields)} fields where the header has {len(header)}", path=path, row=lineno)
        record = dict(zip(header, fields))
        if not record["file"]:
            raise IngestError("the file name is empty", path=path, row=lineno, column="file")
        frame_path = _local_path(record["file"], base)
        if not frame_path.is_file():
            raise IngestError(f"{frame_path} does not exist", path=path, row=lineno, column="file")
        kind = record["kind"].lower()
        if kind not in ("bright", "dark"):
            raise IngestError(
                f"{record['kind']!r} is neither 'bright' nor 'dark'", path=path, row=lineno, column="kind"
            )
        texp = _parse_float(
            record["exposure_time_s"], path=path, row=lineno, column="exposure_time_s", allow_empty=True
        )
        optional = {
            name: _parse_float(record.get(name, ""), path=path, row=lineno, column=name, allow_empty=True)
            for name in _OPTIONAL_MANIFEST_COLUMNS
        }
        if kind == "dark":
            optional = dict.fromkeys(optional)  # light measures do not describe dark frames
        entries.append(
            FrameEntry(path=frame_path, kind=kind, exposure_time_s=texp, source=path, row=lineno, **optional)
        )
    if header is None:
        raise IngestError("the manifest has no header row", path=path)
    if not entries:
        raise IngestError("the manifest lists no frames", path=path)
    return FrameSet(source=path, entries=entries, metadata=metadata, format="manifest")


def read_emva_descriptor(path: os.PathLike | str) -> FrameSet:
    """Read an EMVA 1288 descriptor file, as used by the EMVA 1288 reference data sets.

    Lines (``#`` starts a comment)::

        v 3.0                      descriptor version
        n 12 640 480               ADC bits, frame width, frame height
        b 40000.0 120.0            bright block: exposure time in ns, photons per pixel (μ_p)
        i images\\b_000_snap_001.png   the block's images (at least two), relative to the file
        d 40000.0                  dark block: exposure time in ns

    Blocks of two images are the photon-transfer pairs; longer blocks are the stacks for the
    spatial non-uniformity (EMVA 1288 "Methods for spatial nonuniformity"). Blocks with the same
    exposure (and photon count) are merged into one level. Decimal commas are accepted, as in
    the reference implementation; ``n`` sets the ADC bits (white level 2**bits − 1) and the
    frame size every image must have.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise IngestError(f"cannot read the descriptor ({exc.strerror or exc})", path=path) from exc
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    base = path.parent
    metadata: dict[str, str] = {}
    shape: tuple[int, int] | None = None
    entries: list[FrameEntry] = []
    block: dict | None = None

    def close_block() -> None:
        if block is not None and len(block["images"]) < 2:
            raise IngestError(
                f"the block '{block['line']}' has {len(block['images'])} image; "
                "every block needs at least two frames (a pair)",
                path=path,
                row=block["row"],
            )

    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        command, _, rest = stripped.partition(" ")
        args = rest.split()
        if command == "v":
            metadata["emva1288_descriptor_version"] = rest.strip()
        elif command == "n":
            if len(args) != 3:
                raise IngestError(f"'{stripped}' should be 'n bits width height'", path=path, row=lineno)
            try:
                bits, width, height = (int(a) for a in args)
            except ValueError:
                raise IngestError(
                    f"'{stripped}': bits, width and height must be integers", path=path, row=lineno
                ) from None
            metadata["adc_bits"] = str(bits)
            shape = (height, width)
        elif command in ("b", "d"):
            close_block()
            want = 2 if command == "b" else 1
            if len(args) != want:
                form = "b exposure_ns photons" if command == "b" else "d exposure_ns"
                raise IngestError(f"'{stripped}' should be '{form}'", path=path, row=lineno)
            names = ("exposure_ns", "photons")
            values = [
                _parse_float(a, path=path, row=lineno, column=name, allow_empty=False) for a, name in zip(args, names)
            ]
            block = {
                "kind": "bright" if command == "b" else "dark",
                "exposure_time_s": values[0] / 1e9,
                "photons_per_pixel": values[1] if command == "b" else None,
                "images": [],
                "line": stripped,
                "row": lineno,
            }
        elif command == "i":
            if block is None:
                raise IngestError("an 'i' line before any 'b' or 'd' line", path=path, row=lineno)
            if not rest.strip():
                raise IngestError("'i' without an image path", path=path, row=lineno)
            image = _local_path(rest, base)
            block["images"].append(image)
            entries.append(
                FrameEntry(
                    path=image,
                    kind=block["kind"],
                    exposure_time_s=block["exposure_time_s"],
                    photons_per_pixel=block["photons_per_pixel"],
                    source=path,
                    row=lineno,
                )
            )
        else:
            warnings.warn(
                f"{path}: row {lineno}: unknown descriptor command {stripped!r} ignored", IngestWarning, stacklevel=2
            )
    close_block()
    if not entries:
        raise IngestError("the descriptor lists no images", path=path)
    return FrameSet(source=path, entries=entries, metadata=metadata, frame_shape_hw=shape, format="emva")


def _looks_like_descriptor(path: Path) -> bool:
    try:
        with open(path, "r", encoding="latin-1") as fh:
            for line in fh:
                s = line.strip()
                if s and not s.startswith("#"):
                    return s.split()[0] in ("v", "n", "b", "d")
    except OSError:
        return False
    return False


def load_frame_set(source: os.PathLike | str, *, fmt: str = "auto") -> FrameSet:
    """Read a frame-set description: manifest CSV, EMVA 1288 descriptor or a directory.

    ``fmt`` is ``"auto"``, ``"manifest"`` or ``"emva"``. With ``auto``, a ``.csv`` file is a
    manifest and a ``.txt`` file (or any file whose first command line starts with ``v``, ``n``,
    ``b`` or ``d``) an EMVA descriptor; a directory must hold a ``manifest.csv`` or exactly one
    ``*.txt`` descriptor.
    """
    source = Path(source)
    if fmt not in ("auto", "manifest", "emva"):
        raise IngestError(f"unknown format {fmt!r} (use auto, manifest or emva)", path=source)
    if source.is_dir():
        manifest = source / "manifest.csv"
        descriptors = sorted(p for p in source.glob("*.txt") if _looks_like_descriptor(p))
        if fmt in ("auto", "manifest") and manifest.is_file():
            source = manifest
        elif fmt in ("auto", "emva") and len(descriptors) == 1:
            source = descriptors[0]
        elif len(descriptors) > 1:
            raise IngestError(
                "the directory holds several EMVA descriptors ("
                + ", ".join(p.name for p in descriptors)
                + "); name the one to use",
                path=source,
            )
        else:
            raise IngestError(
                "the directory holds neither a manifest.csv nor an EMVA 1288 descriptor (*.txt)", path=source
            )
    elif not source.is_file():
        raise IngestError("no such file or directory", path=source)
    if fmt == "auto":
        if source.suffix.lower() == ".csv":
            fmt = "manifest"
        elif source.suffix.lower() == ".txt" or _looks_like_descriptor(source):
            fmt = "emva"
        elif _looks_like_frame(source):
            raise IngestError(
                "this is one frame (an image or camera RAW file), not a measurement: a photon-transfer "
                "table needs pairs of bright frames at each exposure level and a dark pair at each exposure "
                "time, listed in a manifest CSV or an EMVA 1288 descriptor (docs/ingest.md)",
                path=source,
            )
        else:
            fmt = "manifest"
    return read_manifest(source) if fmt == "manifest" else read_emva_descriptor(source)


#: file-name suffixes of single frames: images and the common camera RAW formats
FRAME_SUFFIXES = frozenset(
    ".png .tif .tiff .npy .dng .cr2 .cr3 .crw .nef .nrw .arw .srf .sr2 .raf .orf .rw2 .pef .srw .raw .rwl .3fr "
    ".iiq .x3f .erf .mef .mos .kdc .dcr .jpg .jpeg".split()
)


def _looks_like_frame(path: Path) -> bool:
    """A single frame rather than a frame list: an image/RAW suffix, or binary content (a NUL byte
    in the first 4 kB, which no manifest or descriptor has)."""
    if path.suffix.lower() in FRAME_SUFFIXES:
        return True
    try:
        with open(path, "rb") as fh:
            return b"\x00" in fh.read(4096)
    except OSError:
        return False


@dataclass(frozen=True)
class ExposureLevel:
    """Bright frames of one exposure (≥ 2) and the dark frames at the same exposure time (≥ 2).

    ``exposure_time_s`` in s, ``photons_per_pixel`` in photons, ``exposure_lux_s`` in lux·s
    (``None`` when unknown).
    """

    exposure_time_s: float
    photons_per_pixel: float | None
    exposure_lux_s: float | None
    bright: tuple[FrameEntry, ...]
    dark: tuple[FrameEntry, ...]


def _where(entry: FrameEntry) -> dict:
    return {"path": entry.source or entry.path, "row": entry.row}


def _resolve_exposure_times(frameset: FrameSet) -> list[FrameEntry]:
    """Fill empty exposure times from the files' metadata (manifest rows left empty)."""
    resolved = []
    for entry in frameset.entries:
        if entry.exposure_time_s is None:
            texp = _exposure_time_from_file(entry.path)
            if texp is None:
                raise IngestError(
                    f"exposure_time_s is empty and {entry.path.name} records no exposure time; give it in the manifest",
                    column="exposure_time_s",
                    **_where(entry),
                )
            entry = replace(entry, exposure_time_s=texp)
        resolved.append(entry)
    return resolved


def _same_time(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)


def group_levels(frameset: FrameSet) -> list[ExposureLevel]:
    """Group the bright frames into exposure levels and attach the matching dark set.

    Bright frames with identical ``exposure_time_s``, ``photons_per_pixel`` and
    ``exposure_lux_s`` form one level (EMVA 1288 photon-transfer method: one pair per
    irradiation step; more frames make a stack). The dark set of a level is every dark frame
    with the same exposure time (relative tolerance 1e-6). Levels are sorted by exposure time,
    then by photons and lux·s. Empty manifest exposure times are read from the files.

    Raises
    ------
    IngestError
        A level with one bright frame (missing pair partner), a dark set with one frame, or a
        level without dark frames at its exposure time; the message names the frame file and
        where it is listed.
    """
    entries = _resolve_exposure_times(frameset)
    bright: dict[tuple, list[FrameEntry]] = {}
    darks: list[tuple[float, list[FrameEntry]]] = []
    for entry in entries:
        if entry.kind == "bright":
            key = (entry.exposure_time_s, entry.photons_per_pixel, entry.exposure_lux_s)
            bright.setdefault(key, []).append(entry)
        else:
            for texp, members in darks:
                if _same_time(texp, entry.exposure_time_s):
                    members.append(entry)
                    break
            else:
                darks.append((entry.exposure_time_s, [entry]))
    if not bright:
        raise IngestError("no bright frames are listed", path=frameset.source)
    levels = []
    for (texp, photons, lux), members in bright.items():
        if len(members) < 2:
            raise IngestError(
                f"bright frame {members[0].path.name} has no pair partner: no "
                f"other bright frame with exposure_time_s={texp:g}"
                + (f", photons_per_pixel={photons:g}" if photons is not None else "")
                + (f", exposure_lux_s={lux:g}" if lux is not None else "")
                + " (each level needs at least two frames)",
                **_where(members[0]),
            )
        dark = [m for t, m in darks if _same_time(t, texp)]
        if not dark:
            raise IngestError(
                f"no dark frames at exposure_time_s={texp:g} for bright frame "
                f"{members[0].path.name}; take a dark pair at every exposure "
                "time",
                **_where(members[0]),
            )
        if len(dark[0]) < 2:
            raise IngestError(
                f"dark frame {dark[0][0].path.name} has no pair partner at "
                f"exposure_time_s={texp:g} (a dark set needs at least two frames)",
                **_where(dark[0][0]),
            )
        levels.append(ExposureLevel(texp, photons, lux, tuple(members), tuple(dark[0])))
    for column in _OPTIONAL_MANIFEST_COLUMNS:  # all levels or none: the contract has no gaps
        known = [getattr(lv, column) is not None for lv in levels]
        if any(known) and not all(known):
            lacking = levels[known.index(False)].bright[0]
            raise IngestError(
                f"{column} is empty for bright frame {lacking.path.name} but given "
                "for other levels; give it for every bright frame or for none",
                column=column,
                **_where(lacking),
            )
    nan_last = lambda v: (v is None, v if v is not None else 0.0)
    levels.sort(key=lambda lv: (lv.exposure_time_s, nan_last(lv.photons_per_pixel), nan_last(lv.exposure_lux_s)))
    return levels
