"""Raw frames: camera RAW/DNG (rawpy), TIFF (tifffile), PNG (Pillow) and ``.npy`` arrays.

:func:`read_frame` picks a reader by the file-name suffix and returns a :class:`Frame`: the
pixels in DN with the black level still in them, and what the file says about black and white
level, colour filter array and exposure time. rawpy, tifffile and Pillow are imported only
where a file of their kind is read.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayescap._limits import image_pixels_problem
from bayescap.exceptions import IngestError, IngestWarning

__all__ = [
    "IngestError",
    "IngestWarning",
    "Frame",
    "read_frame",
]


_PILLOW_SUFFIXES = (".png",)


_TIFF_SUFFIXES = (".tif", ".tiff")


_NPY_SUFFIXES = (".npy",)


_PNG_END = b"IEND\xaeB`\x82"


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


_BYTES_REPR = re.compile(r"b'(?:[^'\\]|\\.)*'" + r'|b"(?:[^"\\]|\\.)*"')


def _reason(exc: BaseException) -> str:
    """A reader's exception in one line for a message: its type and text, without the bytes of
    the file it quotes (a manifest can point at any file: its content is never echoed) and
    without control characters."""
    from bayescap.io.ptc_csv import _clean

    text = _BYTES_REPR.sub("<bytes not shown>", str(exc))
    return _clean(f"{type(exc).__name__}: {text}")


def _tag_text(value: object) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        value = value.decode("latin-1")
    # a control character (NUL, ESC's terminal sequences) never reaches a message or a CSV
    from bayescap.io.ptc_csv import _clean

    text = _clean(str(value)).strip()
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


def _rawpy(path: Path):
    """rawpy (LibRaw), an optional extra: only RAW and DNG files need it."""
    try:
        import rawpy
    except ImportError:
        raise IngestError("reading a RAW or DNG file needs rawpy: pip install 'bayescap[raw]'", path=path) from None
    return rawpy


def _read_rawpy(path: Path) -> Frame:
    """Camera RAW or DNG through LibRaw (rawpy).

    Pixels are ``raw_image_visible`` (the sensor area without masked borders); the black level
    of CFA position (i, j) is ``black_level_per_channel[c]`` with ``c`` the colour index of that
    position in ``raw_colors_visible``; the Bayer letters come from ``color_desc``.
    """
    rawpy = _rawpy(path)

    try:
        with rawpy.imread(str(path)) as raw:  # opening reads the sizes; the pixels come on first use
            problem = image_pixels_problem((raw.sizes.raw_height, raw.sizes.raw_width))
            if problem:
                raise IngestError(problem, path=path)
            pixels = np.array(raw.raw_image_visible, copy=True)
            num_colors = int(raw.num_colors)
            desc = raw.color_desc.decode("ascii", "replace")
            black = [float(b) for b in raw.black_level_per_channel]
            white = float(raw.white_level)
            colors = None
            if num_colors > 1 and pixels.ndim == 2:
                colors = np.array(raw.raw_colors_visible[:2, :2])
            shutter = float(raw.other.shutter_speed)
    except IngestError:
        raise
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise IngestError(
            f"cannot read the frame as camera RAW/DNG ({_reason(exc)}); is the file complete and a supported format?",
            path=path,
        ) from exc
    if pixels.ndim != 2:
        raise IngestError(
            f"the RAW data are {pixels.ndim}-dimensional {pixels.shape}; only "
            "single-plane mosaic or monochrome RAW files can be measured",
            path=path,
        )
    if num_colors == 1:
        cfa, black_dn = None, black[0]
    else:
        letters = "".join(desc[c] if c < len(desc) else "?" for c in colors.ravel())
        if sorted(letters) != sorted("RGGB") or pixels.shape[0] < 2 or pixels.shape[1] < 2:
            raise IngestError(
                f"unsupported colour filter array (colours {desc!r}, 2x2 tile "
                f"{letters!r}); only 2x2 Bayer patterns are supported",
                path=path,
            )
        cfa = letters
        black_dn = np.array([[black[c] for c in row] for row in colors], dtype=float)
    tags = _tiff_tags(path)
    make, model = _tag_text(tags.get(271)), _tag_text(tags.get(272))
    if model is None:
        model = _tag_text(tags.get(50708))  # DNG UniqueCameraModel
    return Frame(
        pixels=pixels,
        black_level_dn=black_dn,
        white_level_dn=white,
        cfa_pattern=cfa,
        exposure_time_s=_round_float32_seconds(shutter) if shutter > 0 else None,
        path=path,
        adc_bits=_bits_for_white_level(white) if white > 0 else None,
        make=make,
        model=model,
    )


def _check_integer_image(pixels: np.ndarray, path: Path) -> int:
    if pixels.ndim != 2:
        raise IngestError(
            f"the image has shape {pixels.shape}; a raw frame must be a single 2-D plane (no RGB or multi-page images)",
            path=path,
        )
    if pixels.dtype.kind not in "ui":
        raise IngestError(f"sample type {pixels.dtype} is not an integer type; raw frames hold integer DN", path=path)
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
        with warnings.catch_warnings():  # the pixel limit below says it on one line
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data))
        with img:
            problem = image_pixels_problem((img.size[1], img.size[0]))
            if problem:
                raise IngestError(problem, path=path)
            img.load()
            mode = img.mode
            pixels = np.array(img)
    except IngestError:
        raise
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, ...
        raise IngestError(f"cannot decode the image ({_reason(exc)})", path=path) from exc
    if mode not in ("L", "I", "I;16", "I;16B", "I;16L"):
        raise IngestError(
            f"image mode {mode!r} is not a single-channel 8/16-bit grey image; save raw frames as greyscale PNG",
            path=path,
        )
    if mode == "I":
        if pixels.size and (pixels.min() < 0 or pixels.max() > 65535):
            raise IngestError("32-bit PNG values outside 0..65535", path=path)
        pixels = pixels.astype(np.uint16)
    bits = _check_integer_image(pixels, path)
    return Frame(
        pixels=pixels,
        black_level_dn=0.0,
        white_level_dn=float(2**bits - 1),
        cfa_pattern=None,
        exposure_time_s=None,
        path=path,
        adc_bits=bits,
    )


def _read_tiff(path: Path) -> Frame:
    """8- or 16-bit single-channel TIFF through tifffile (first page)."""
    import tifffile

    try:
        with _quiet_tifffile(), tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            size = path.stat().st_size
            ends = [int(o) + int(n) for o, n in zip(page.dataoffsets, page.databytecounts)]
            if not ends or max(ends) > size:
                raise IngestError(
                    f"the TIFF file is truncated (image data end at byte "
                    f"{max(ends) if ends else 0}, the file has {size})",
                    path=path,
                )
            problem = image_pixels_problem(page.shape)
            if problem:
                raise IngestError(problem, path=path)
            pixels = page.asarray()
            bits = int(page.bitspersample)
    except IngestError:
        raise
    except Exception as exc:
        raise IngestError(f"cannot read the TIFF image ({_reason(exc)})", path=path) from exc
    _check_integer_image(pixels, path)
    tags = _tiff_tags(path)
    return Frame(
        pixels=pixels,
        black_level_dn=0.0,
        white_level_dn=float(2**bits - 1),
        cfa_pattern=None,
        exposure_time_s=_tag_seconds(tags.get(33434)),
        path=path,
        adc_bits=bits,
        make=_tag_text(tags.get(271)),
        model=_tag_text(tags.get(272)),
    )


def _read_npy(path: Path) -> Frame:
    """A 2-D integer array saved with :func:`numpy.save`."""
    try:
        pixels = np.load(path, allow_pickle=False, mmap_mode="r")  # the header first: its shape
        problem = image_pixels_problem(pixels.shape)
        if problem:
            raise IngestError(problem, path=path)
        pixels = np.array(pixels)
    except IngestError:
        raise
    except Exception as exc:
        raise IngestError(f"cannot read the .npy array ({_reason(exc)})", path=path) from exc
    bits = _check_integer_image(np.asarray(pixels), path)
    return Frame(
        pixels=np.asarray(pixels),
        black_level_dn=0.0,
        white_level_dn=float(2**bits - 1),
        cfa_pattern=None,
        exposure_time_s=None,
        path=path,
        adc_bits=bits,
    )


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
    rawpy = _rawpy(path)

    try:
        with rawpy.imread(str(path)) as raw:  # opening reads the metadata, not the pixels
            shutter = float(raw.other.shutter_speed)
    except IngestError:
        raise
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise IngestError(f"cannot read the frame as camera RAW/DNG ({_reason(exc)})", path=path) from exc
    return _round_float32_seconds(shutter) if shutter > 0 else None
