"""Frames -> photon-transfer table: RAW/DNG/TIFF/PNG/.npy frames to the contract CSV.

The pipeline of this module reads like the measurement:

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

References
----------
EMVA Standard 1288, *Standard for Characterization of Image Sensors and Cameras*, Release 4.0
Linear (European Machine Vision Association, 2021):

* section "Computation of mean and variance of measured gray values": the mean over the ROI of
  a pair of frames, and the temporal variance from the pair difference,
  σ²_y = [mean((A−B)²) − (mean(A) − mean(B))²] / 2;
* section "Evaluation of the measurements according to the photon transfer method": one bright
  pair per exposure level and a dark pair at the same exposure time;
* sections "Spatial variances" and "Methods for spatial nonuniformity": the spatial variance over
  the ROI of the pixel-wise average of a stack of L frames, which still contains the residual
  temporal variance σ²_y/L (this module does not remove it; the fit does);
* the descriptor file format of the EMVA 1288 reference implementation
  (github.com/EMVA1288/emva1288, ``emva1288.process.parser``): ``n bits width height``,
  ``b texp_ns photons``, ``d texp_ns`` and ``i path`` lines.

The CSV format is the project's interface contract (photon-transfer CSV); ``docs/ingest.md``
describes the inputs, options and formulas for users.
"""
from __future__ import annotations

import contextlib
import csv
import io
import logging
import math
import os
import tempfile
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path, PureWindowsPath
from typing import Iterable, Sequence

import numpy as np

from bayescap.exceptions import IngestError, IngestWarning

__all__ = [
    "IngestError",
    "IngestWarning",
    "Frame",
    "FrameEntry",
    "FrameSet",
    "ExposureLevel",
    "SetStatistics",
    "CHANNELS",
    "read_frame",
    "read_manifest",
    "read_emva_descriptor",
    "load_frame_set",
    "group_levels",
    "parse_roi",
    "split_cfa",
    "cfa_positions",
    "pair_statistics",
    "spatial_variance_dn2",
    "ingest",
]


#: Channel names accepted by :func:`ingest`; ``G`` pools the Gr and Gb pixels, ``all`` writes
#: one CSV for each of R, Gr, Gb and B.
CHANNELS = ("R", "Gr", "Gb", "B", "G", "all")


_SINGLE_CHANNELS = ("R", "Gr", "Gb", "B")


_BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")


_REQUIRED_MANIFEST_COLUMNS = ("file", "kind", "exposure_time_s")


_OPTIONAL_MANIFEST_COLUMNS = ("photons_per_pixel", "exposure_lux_s")


#: Manifest metadata keys that describe the frames themselves (they override the files).
_FRAME_OVERRIDE_KEYS = ("adc_bits", "black_level_dn", "white_level_dn", "cfa_pattern")


_PILLOW_SUFFIXES = (".png",)


_TIFF_SUFFIXES = (".tif", ".tiff")


_NPY_SUFFIXES = (".npy",)


_PNG_END = b"IEND\xaeB`\x82"


# --------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Frame:
    """One raw frame as recorded, in digital numbers (DN).

    Attributes
    ----------
    pixels : numpy.ndarray
        2-D array (rows, columns) of raw values in DN, black level *not* subtracted; for a CFA
        sensor the mosaic as recorded (the visible area for camera RAW files).
    black_level_dn : float or numpy.ndarray
        Black level in DN: a scalar for a monochrome frame, a (2, 2) array for a CFA frame whose
        entry ``[i, j]`` belongs to CFA position ``(i, j)`` of ``cfa_pattern``.
    white_level_dn : float
        The largest value the file can hold for this sensor (ADC maximum or the file's white
        level); pixels at or above it count as saturated.
    cfa_pattern : str or None
        The 2x2 Bayer tile read row by row (``"RGGB"``, ``"GRBG"``, ``"GBRG"``, ``"BGGR"``),
        or ``None`` for a monochrome sensor.
    exposure_time_s : float or None
        Exposure time in seconds from the file's metadata, ``None`` when the file has none.
    path : pathlib.Path
        The file the frame was read from.
    adc_bits : int or None
        Bits of the ADC when the file says so (white level of a RAW file, sample size of a
        PNG/TIFF).
    make, model : str or None
        Camera maker and model from the file's TIFF/EXIF tags, when present.
    """

    pixels: np.ndarray
    black_level_dn: float | np.ndarray
    white_level_dn: float
    cfa_pattern: str | None
    exposure_time_s: float | None
    path: Path
    adc_bits: int | None = None
    make: str | None = None
    model: str | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the frame in pixels."""
        return tuple(int(n) for n in self.pixels.shape)


def _bits_for_white_level(white_level_dn: float) -> int:
    """Smallest number of ADC bits whose range holds ``white_level_dn``."""
    return max(1, int(math.ceil(math.log2(float(white_level_dn) + 1.0))))


def _round_float32_seconds(value: float) -> float:
    """Undo the float32 storage of LibRaw's shutter time: 6 significant digits survive it."""
    return float(f"{float(np.float32(value)):.6g}")


@contextlib.contextmanager
def _quiet_tifffile():
    """tifffile logs what it finds wrong in a file ("invalid offset to first page") to standard error
    before raising; the error bayescap reports says it on its one line, so the log is held back."""
    log = logging.getLogger("tifffile")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


def _tiff_tags(path: Path) -> dict[int, object]:
    """Tags of the first IFD (and of its EXIF IFD) of a TIFF-based file; {} for other files."""
    import tifffile

    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            tags = {tag.code: tag.value for tag in page.tags}
            exif = tags.get(34665)
            if isinstance(exif, dict):
                names = {"ExposureTime": 33434, "Make": 271, "Model": 272}
                for name, code in names.items():
                    tags.setdefault(code, exif.get(name))
            return tags
    except Exception:  # not TIFF-based (CR3, RAF, ...): no tags, which is fine
        return {}


def _tag_text(value: object) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        value = value.decode("latin-1")
    text = str(value).strip().strip("\x00").strip()
    return text or None


def _tag_seconds(value: object) -> float | None:
    """ExposureTime tag (a TIFF RATIONAL, tifffile gives (numerator, denominator))."""
    try:
        if isinstance(value, tuple) and len(value) == 2:
            num, den = value
            seconds = float(num) / float(den) if den else float("nan")
        elif value is None:
            return None
        else:
            seconds = float(value)
    except (TypeError, ValueError):
        return None
    return seconds if math.isfinite(seconds) and seconds > 0 else None


def _read_rawpy(path: Path) -> Frame:
    """Camera RAW or DNG through LibRaw (rawpy).

    Pixels are ``raw_image_visible`` (the sensor area without masked borders); the black level
    of CFA position (i, j) is ``black_level_per_channel[c]`` with ``c`` the colour index of that
    position in ``raw_colors_visible``; the Bayer letters come from ``color_desc``.
    """
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            pixels = np.array(raw.raw_image_visible, copy=True)
            num_colors = int(raw.num_colors)
            desc = raw.color_desc.decode("ascii", "replace")
            black = [float(b) for b in raw.black_level_per_channel]
            white = float(raw.white_level)
            colors = None
            if num_colors > 1 and pixels.ndim == 2:
                colors = np.array(raw.raw_colors_visible[:2, :2])
            shutter = float(raw.other.shutter_speed)
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise IngestError(f"cannot read the frame as camera RAW/DNG ({type(exc).__name__}: "
                          f"{exc}); is the file complete and a supported format?",
                          path=path) from exc
    if pixels.ndim != 2:
        raise IngestError(f"the RAW data are {pixels.ndim}-dimensional {pixels.shape}; only "
                          "single-plane mosaic or monochrome RAW files can be measured",
                          path=path)
    if num_colors == 1:
        cfa, black_dn = None, black[0]
    else:
        letters = "".join(desc[c] if c < len(desc) else "?" for c in colors.ravel())
        if sorted(letters) != sorted("RGGB") or pixels.shape[0] < 2 or pixels.shape[1] < 2:
            raise IngestError(f"unsupported colour filter array (colours {desc!r}, 2x2 tile "
                              f"{letters!r}); only 2x2 Bayer patterns are supported", path=path)
        cfa = letters
        black_dn = np.array([[black[c] for c in row] for row in colors], dtype=float)
    tags = _tiff_tags(path)
    make, model = _tag_text(tags.get(271)), _tag_text(tags.get(272))
    if model is None:
        model = _tag_text(tags.get(50708))  # DNG UniqueCameraModel
    return Frame(pixels=pixels, black_level_dn=black_dn, white_level_dn=white,
                 cfa_pattern=cfa,
                 exposure_time_s=_round_float32_seconds(shutter) if shutter > 0 else None,
                 path=path, adc_bits=_bits_for_white_level(white) if white > 0 else None,
                 make=make, model=model)


def _check_integer_image(pixels: np.ndarray, path: Path) -> int:
    if pixels.ndim != 2:
        raise IngestError(f"the image has shape {pixels.shape}; a raw frame must be a single "
                          "2-D plane (no RGB or multi-page images)", path=path)
    if pixels.dtype.kind not in "ui":
        raise IngestError(f"sample type {pixels.dtype} is not an integer type; raw frames "
                          "hold integer DN", path=path)
    if pixels.dtype.kind == "i" and pixels.size and int(pixels.min()) < 0:
        raise IngestError("the image holds negative values; raw frames hold DN >= 0", path=path)
    return 8 * pixels.dtype.itemsize


def _read_pillow(path: Path) -> Frame:
    """8- or 16-bit single-channel PNG through Pillow."""
    from PIL import Image

    with open(path, "rb") as fh:
        data = fh.read()
    if not data.rstrip(b"\x00").endswith(_PNG_END):
        raise IngestError("the PNG file is truncated (no IEND chunk at its end)", path=path)
    try:
        with Image.open(io.BytesIO(data)) as img:
            img.load()
            mode = img.mode
            pixels = np.array(img)
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, ...
        raise IngestError(f"cannot decode the image ({type(exc).__name__}: {exc})",
                          path=path) from exc
    if mode not in ("L", "I", "I;16", "I;16B", "I;16L"):
        raise IngestError(f"image mode {mode!r} is not a single-channel 8/16-bit grey image; "
                          "save raw frames as greyscale PNG", path=path)
    if mode == "I":
        if pixels.size and (pixels.min() < 0 or pixels.max() > 65535):
            raise IngestError("32-bit PNG values outside 0..65535", path=path)
        pixels = pixels.astype(np.uint16)
    bits = _check_integer_image(pixels, path)
    return Frame(pixels=pixels, black_level_dn=0.0, white_level_dn=float(2 ** bits - 1),
                 cfa_pattern=None, exposure_time_s=None, path=path, adc_bits=bits)


def _read_tiff(path: Path) -> Frame:
    """8- or 16-bit single-channel TIFF through tifffile (first page)."""
    import tifffile

    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            size = path.stat().st_size
            ends = [int(o) + int(n) for o, n in zip(page.dataoffsets, page.databytecounts)]
            if not ends or max(ends) > size:
                raise IngestError(f"the TIFF file is truncated (image data end at byte "
                                  f"{max(ends) if ends else 0}, the file has {size})", path=path)
            pixels = page.asarray()
            bits = int(page.bitspersample)
    except IngestError:
        raise
    except Exception as exc:
        raise IngestError(f"cannot read the TIFF image ({type(exc).__name__}: {exc})",
                          path=path) from exc
    _check_integer_image(pixels, path)
    tags = _tiff_tags(path)
    return Frame(pixels=pixels, black_level_dn=0.0, white_level_dn=float(2 ** bits - 1),
                 cfa_pattern=None, exposure_time_s=_tag_seconds(tags.get(33434)), path=path,
                 adc_bits=bits, make=_tag_text(tags.get(271)), model=_tag_text(tags.get(272)))


def _read_npy(path: Path) -> Frame:
    """A 2-D integer array saved with :func:`numpy.save`."""
    try:
        pixels = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise IngestError(f"cannot read the .npy array ({type(exc).__name__}: {exc})",
                          path=path) from exc
    bits = _check_integer_image(np.asarray(pixels), path)
    return Frame(pixels=np.asarray(pixels), black_level_dn=0.0,
                 white_level_dn=float(2 ** bits - 1), cfa_pattern=None, exposure_time_s=None,
                 path=path, adc_bits=bits)


#: Reader per file-name suffix; every other suffix goes to LibRaw (:func:`_read_rawpy`).
_READERS = {
    **{s: _read_pillow for s in _PILLOW_SUFFIXES},
    **{s: _read_tiff for s in _TIFF_SUFFIXES},
    **{s: _read_npy for s in _NPY_SUFFIXES},
}


def read_frame(path: os.PathLike | str) -> Frame:
    """Read one frame: camera RAW/DNG (rawpy), TIFF (tifffile), PNG (Pillow) or ``.npy``.

    The reader is chosen by the file-name suffix (``.png``, ``.tif``/``.tiff``, ``.npy``);
    anything else is handed to LibRaw, which knows DNG and the camera RAW formats.

    Parameters
    ----------
    path : path-like
        The frame file.

    Returns
    -------
    Frame
        Pixels in DN with the black level still in them, and what the file says about black and
        white level, CFA pattern and exposure time (PNG, TIFF and ``.npy`` carry no black level
        or CFA: 0 and ``None``; their white level is the container's maximum, 2**bits − 1).

    Raises
    ------
    IngestError
        The file is missing, truncated, unreadable or not a single-plane integer image.
    """
    path = Path(path)
    if not path.is_file():
        raise IngestError("no such file", path=path)
    reader = _READERS.get(path.suffix.lower(), _read_rawpy)
    frame = reader(path)
    if frame.pixels.shape[0] < 2 or frame.pixels.shape[1] < 2:
        raise IngestError(f"the frame is only {frame.pixels.shape} pixels", path=path)
    return frame


def _exposure_time_from_file(path: Path) -> float | None:
    """Exposure time stored in a frame file, without decoding the pixels when possible."""
    suffix = path.suffix.lower()
    if suffix in _TIFF_SUFFIXES:
        return _tag_seconds(_tiff_tags(path).get(33434))
    if suffix in _PILLOW_SUFFIXES or suffix in _NPY_SUFFIXES:
        return None
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:  # opening reads the metadata, not the pixels
            shutter = float(raw.other.shutter_speed)
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise IngestError(f"cannot read the frame as camera RAW/DNG ({type(exc).__name__}: "
                          f"{exc})", path=path) from exc
    return _round_float32_seconds(shutter) if shutter > 0 else None


# --------------------------------------------------------------------------------------------
# Frame-set descriptions
# --------------------------------------------------------------------------------------------
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


def _parse_float(text: str, *, path: Path, row: int | None, column: str,
                 allow_empty: bool) -> float | None:
    text = text.strip()
    if not text:
        if allow_empty:
            return None
        raise IngestError("value is missing", path=path, row=row, column=column)
    try:
        value = float(text.replace(",", ".") if text.count(",") == 1 and "." not in text
                      else text)
    except ValueError:
        raise IngestError(f"{text!r} is not a number", path=path, row=row,
                          column=column) from None
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
        raise IngestError(f"cannot read the manifest ({exc.strerror or exc})",
                          path=path) from exc
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
                    raise IngestError(f"the header has no '{name}' column (a manifest needs "
                                      f"{', '.join(_REQUIRED_MANIFEST_COLUMNS)})",
                                      path=path, row=lineno)
            known = _REQUIRED_MANIFEST_COLUMNS + _OPTIONAL_MANIFEST_COLUMNS
            for name in header:
                if name not in known:
                    raise IngestError(f"unknown column (known columns: {', '.join(known)})",
                                      path=path, row=lineno, column=name)
            if len(set(header)) != len(header):
                raise IngestError("a column name appears twice in the header", path=path,
                                  row=lineno)
            continue
        if len(fields) != len(header):
            raise IngestError(f"{len(fields)} fields where the header has {len(header)}",
                              path=path, row=lineno)
        record = dict(zip(header, fields))
        if not record["file"]:
            raise IngestError("the file name is empty", path=path, row=lineno, column="file")
        frame_path = _local_path(record["file"], base)
        if not frame_path.is_file():
            raise IngestError(f"{frame_path} does not exist", path=path, row=lineno,
                              column="file")
        kind = record["kind"].lower()
        if kind not in ("bright", "dark"):
            raise IngestError(f"{record['kind']!r} is neither 'bright' nor 'dark'", path=path,
                              row=lineno, column="kind")
        texp = _parse_float(record["exposure_time_s"], path=path, row=lineno,
                            column="exposure_time_s", allow_empty=True)
        optional = {name: _parse_float(record.get(name, ""), path=path, row=lineno,
                                       column=name, allow_empty=True)
                    for name in _OPTIONAL_MANIFEST_COLUMNS}
        if kind == "dark":
            optional = dict.fromkeys(optional)  # light measures do not describe dark frames
        entries.append(FrameEntry(path=frame_path, kind=kind, exposure_time_s=texp,
                                  source=path, row=lineno, **optional))
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
        raise IngestError(f"cannot read the descriptor ({exc.strerror or exc})",
                          path=path) from exc
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
            raise IngestError(f"the block '{block['line']}' has {len(block['images'])} image; "
                              "every block needs at least two frames (a pair)",
                              path=path, row=block["row"])

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
                raise IngestError(f"'{stripped}' should be 'n bits width height'", path=path,
                                  row=lineno)
            try:
                bits, width, height = (int(a) for a in args)
            except ValueError:
                raise IngestError(f"'{stripped}': bits, width and height must be integers",
                                  path=path, row=lineno) from None
            metadata["adc_bits"] = str(bits)
            shape = (height, width)
        elif command in ("b", "d"):
            close_block()
            want = 2 if command == "b" else 1
            if len(args) != want:
                form = "b exposure_ns photons" if command == "b" else "d exposure_ns"
                raise IngestError(f"'{stripped}' should be '{form}'", path=path, row=lineno)
            names = ("exposure_ns", "photons")
            values = [_parse_float(a, path=path, row=lineno, column=name, allow_empty=False)
                      for a, name in zip(args, names)]
            block = {"kind": "bright" if command == "b" else "dark",
                     "exposure_time_s": values[0] / 1e9,
                     "photons_per_pixel": values[1] if command == "b" else None,
                     "images": [], "line": stripped, "row": lineno}
        elif command == "i":
            if block is None:
                raise IngestError("an 'i' line before any 'b' or 'd' line", path=path,
                                  row=lineno)
            if not rest.strip():
                raise IngestError("'i' without an image path", path=path, row=lineno)
            image = _local_path(rest, base)
            block["images"].append(image)
            entries.append(FrameEntry(path=image, kind=block["kind"],
                                      exposure_time_s=block["exposure_time_s"],
                                      photons_per_pixel=block["photons_per_pixel"],
                                      source=path, row=lineno))
        else:
            warnings.warn(f"{path}: row {lineno}: unknown descriptor command {stripped!r} "
                          "ignored", IngestWarning, stacklevel=2)
    close_block()
    if not entries:
        raise IngestError("the descriptor lists no images", path=path)
    return FrameSet(source=path, entries=entries, metadata=metadata, frame_shape_hw=shape,
                    format="emva")


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
            raise IngestError("the directory holds several EMVA descriptors ("
                              + ", ".join(p.name for p in descriptors)
                              + "); name the one to use", path=source)
        else:
            raise IngestError("the directory holds neither a manifest.csv nor an EMVA 1288 "
                              "descriptor (*.txt)", path=source)
    elif not source.is_file():
        raise IngestError("no such file or directory", path=source)
    if fmt == "auto":
        if source.suffix.lower() == ".csv":
            fmt = "manifest"
        elif source.suffix.lower() == ".txt" or _looks_like_descriptor(source):
            fmt = "emva"
        else:
            fmt = "manifest"
    return read_manifest(source) if fmt == "manifest" else read_emva_descriptor(source)


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
                raise IngestError(f"exposure_time_s is empty and {entry.path.name} records no "
                                  "exposure time; give it in the manifest",
                                  column="exposure_time_s", **_where(entry))
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
            raise IngestError(f"bright frame {members[0].path.name} has no pair partner: no "
                              f"other bright frame with exposure_time_s={texp:g}"
                              + (f", photons_per_pixel={photons:g}" if photons is not None
                                 else "")
                              + (f", exposure_lux_s={lux:g}" if lux is not None else "")
                              + " (each level needs at least two frames)",
                              **_where(members[0]))
        dark = [m for t, m in darks if _same_time(t, texp)]
        if not dark:
            raise IngestError(f"no dark frames at exposure_time_s={texp:g} for bright frame "
                              f"{members[0].path.name}; take a dark pair at every exposure "
                              "time", **_where(members[0]))
        if len(dark[0]) < 2:
            raise IngestError(f"dark frame {dark[0][0].path.name} has no pair partner at "
                              f"exposure_time_s={texp:g} (a dark set needs at least two frames)",
                              **_where(dark[0][0]))
        levels.append(ExposureLevel(texp, photons, lux, tuple(members), tuple(dark[0])))
    for column in _OPTIONAL_MANIFEST_COLUMNS:  # all levels or none: the contract has no gaps
        known = [getattr(lv, column) is not None for lv in levels]
        if any(known) and not all(known):
            lacking = levels[known.index(False)].bright[0]
            raise IngestError(f"{column} is empty for bright frame {lacking.path.name} but given "
                              "for other levels; give it for every bright frame or for none",
                              column=column, **_where(lacking))
    nan_last = lambda v: (v is None, v if v is not None else 0.0)  # noqa: E731
    levels.sort(key=lambda lv: (lv.exposure_time_s, nan_last(lv.photons_per_pixel),
                                nan_last(lv.exposure_lux_s)))
    return levels


# --------------------------------------------------------------------------------------------
# ROI and CFA
# --------------------------------------------------------------------------------------------
def parse_roi(roi: str | float | Sequence[int] | None, shape_hw: tuple[int, int], *,
              cfa: bool = False) -> tuple[int, int, int, int]:
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
            raise IngestError(f"ROI {roi!r} is neither 'x0,y0,x1,y1' (integers) nor a centred "
                              "fraction such as 0.5") from None
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
            raise IngestError(f"ROI x0={x0},y0={y0},x1={x1},y1={y1} does not lie inside the "
                              f"{width}x{height} frame (need 0 <= x0 < x1 <= width, "
                              "0 <= y0 < y1 <= height)")
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
        raise IngestError(f"CFA pattern {cfa_pattern!r} is not one of "
                          f"{', '.join(_BAYER_PATTERNS)}")
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
    return np.concatenate([roi_pixels[i::2, j::2].astype(np.float64).ravel()
                           for i, j in tiles])


# --------------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------------
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
        return SetStatistics(mean_dn=mean_dn, temporal_var_dn2=temporal_var_dn2,
                             spatial_var_dn2=spatial, n_frames=self.n_frames,
                             frac_saturated=self.n_saturated / self.n_values,
                             n_pixels=int(self.first.size),
                             black_level_dn=float(np.mean(self.black_dn)))


def _as_override_number(metadata: dict[str, str], key: str, source: Path, *,
                        integer: bool = False) -> float | int | None:
    if key not in metadata or metadata[key] == "":
        return None
    text = metadata[key]
    try:
        value = int(text) if integer else float(text)
    except ValueError:
        raise IngestError(f"metadata '# {key}: {text}' is not a "
                          + ("whole number" if integer else "number"), path=source) from None
    if (integer and not 1 <= value <= 32) or (not integer and not (math.isfinite(value)
                                                                    and value >= 0)):
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
                raise IngestError(f"metadata '# cfa_pattern: {cfa}' is not one of "
                                  f"{', '.join(_BAYER_PATTERNS)} or mono", path=src)
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
            changes["white_level_dn"] = float(2 ** self.adc_bits - 1)
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
            raise IngestError(f"frame size {frame.shape[1]}x{frame.shape[0]} differs from "
                              f"{self.shape[1]}x{self.shape[0]} of {self.shape_from}; all "
                              "frames of a measurement must have the same size",
                              path=entry.path)
        if self.reference is None:
            self.reference = frame
        elif frame.cfa_pattern != self.reference.cfa_pattern:
            raise IngestError(f"CFA pattern {frame.cfa_pattern} differs from "
                              f"{self.reference.cfa_pattern} of {self.reference.path.name}",
                              path=entry.path)
        elif not np.array_equal(frame.black_level_dn, self.reference.black_level_dn):
            warnings.warn(f"{entry.path}: black level {frame.black_level_dn} differs from "
                          f"{self.reference.black_level_dn} of {self.reference.path.name}; "
                          "the CSV reports the first frame's", IngestWarning, stacklevel=3)
        return frame


def _set_statistics(entries: Iterable[FrameEntry], reader: _FrameReader,
                    roi: str | float | Sequence[int] | None,
                    channels: Sequence[str], state: dict) -> dict[str, SetStatistics]:
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
            black = (float(frame.black_level_dn) if tiles is None
                     else float(np.mean([frame.black_level_dn[i, j] for i, j in tiles])))
            accumulators[c].add(_channel_pixels(roi_pixels, tiles), frame.white_level_dn, black)
    return {c: acc.result() for c, acc in accumulators.items()}


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------
def _fmt(value: float | int | None) -> str:
    if value is None:
        return ""
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)


def _table_text(metadata: dict[str, str], rows: list[dict[str, float | int | None]]) -> str:
    columns = ["exposure_time_s", "mean_dn", "temporal_var_dn2", "dark_mean_dn",
               "dark_temporal_var_dn2", "n_pixels"]
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


def _write_atomically(files: dict[Path, str]) -> None:
    """Write every file to a temporary file in its directory, then os.replace them all."""
    temps: list[tuple[str, Path]] = []
    try:
        for target, text in files.items():
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                                       dir=target.parent)
            temps.append((tmp, target))
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
        for tmp, target in temps:
            os.replace(tmp, target)
    except OSError as exc:
        raise IngestError(f"cannot write the output ({exc.strerror or exc})",
                          path=getattr(exc, "filename", None) or next(iter(files))) from exc
    finally:
        for tmp, _ in temps:
            if os.path.exists(tmp):
                os.unlink(tmp)


def _output_paths(out: Path, source: Path, channels: Sequence[str],
                  suffixed: bool) -> dict[str, Path]:
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


def ingest(source: os.PathLike | str, *, out: os.PathLike | str,
           roi: str | float | Sequence[int] | None = None, channel: str = "G",
           fmt: str = "auto") -> list[Path]:
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
    reader = _FrameReader(frameset)

    # The first frame decides mono vs Bayer, hence which channels are measured.
    first = reader.read(levels[0].bright[0])
    mono = first.cfa_pattern is None
    channels = ["mono"] if mono else (list(_SINGLE_CHANNELS) if channel == "all"
                                      else [channel])
    stat_channels = ["G"] if mono else channels  # any name works for mono: tiles are None

    state: dict = {}
    dark_cache: dict[tuple[Path, ...], dict[str, SetStatistics]] = {}
    rows: dict[str, list[dict]] = {c: [] for c in channels}
    for level in levels:
        bright = _set_statistics(level.bright, reader, roi, stat_channels, state)
        key = tuple(e.path for e in level.dark)
        if key not in dark_cache:
            dark_cache[key] = _set_statistics(level.dark, reader, roi, stat_channels, state)
        dark = dark_cache[key]
        n_bright, n_dark = len(level.bright), len(level.dark)
        if n_bright != n_dark and max(n_bright, n_dark) > 2:
            warnings.warn(f"{frameset.source}: at exposure_time_s={level.exposure_time_s:g} "
                          f"the bright stack has {n_bright} frames and the dark set {n_dark}; "
                          "the CSV gives both (n_frames, dark_n_frames), but a reader that "
                          "knows only n_frames will misjudge the residual temporal part of "
                          "dark_spatial_var_dn2", IngestWarning, stacklevel=2)
        for c, sc in zip(channels, stat_channels):
            b, d = bright[sc], dark[sc]
            rows[c].append({
                "exposure_time_s": level.exposure_time_s,
                "mean_dn": b.mean_dn, "temporal_var_dn2": b.temporal_var_dn2,
                "dark_mean_dn": d.mean_dn, "dark_temporal_var_dn2": d.temporal_var_dn2,
                "n_pixels": b.n_pixels,
                "photons_per_pixel": level.photons_per_pixel,
                "exposure_lux_s": level.exposure_lux_s,
                "spatial_var_dn2": b.spatial_var_dn2,
                "dark_spatial_var_dn2": d.spatial_var_dn2,
                "n_frames": b.n_frames, "dark_n_frames": d.n_frames,
                "frac_saturated": b.frac_saturated,
                "_black": b.black_level_dn,
            })

    ref = reader.reference
    height, width = reader.shape
    x0, y0, x1, y1 = state["roi"]
    adc_bits = ref.adc_bits if ref.adc_bits is not None else _bits_for_white_level(
        ref.white_level_dn)
    paths = _output_paths(out, frameset.source, channels, suffixed=len(channels) > 1)
    inputs = {frameset.source.resolve()} | {e.path.resolve() for e in frameset.entries}
    for p in paths.values():
        if p.resolve() in inputs:
            raise IngestError("the output would overwrite an input file; choose another "
                              "--out", path=p)
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
    _write_atomically(files)
    return list(paths.values())
