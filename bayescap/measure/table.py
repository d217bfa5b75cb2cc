"""MTF tables (CSV) and edge images read from files.

:func:`read_mtf_table` reads a measured or reference MTF into an :class:`SFRResult`;
:func:`write_mtf_table` writes one; :func:`read_image` reads an edge image for
:func:`bayescap.measure.sfr.measure_sfr`.
"""

from __future__ import annotations

import contextlib
import csv
import math
import re
import warnings
from pathlib import Path

import numpy as np

from bayescap.exceptions import MTFInputError
from bayescap.measure.result import SFRResult, _crossing_cy_per_px, _sampling_efficiency

__all__ = [
    "read_image",
    "read_mtf_table",
    "write_mtf_table",
    "mtf_table_text",
]


_FREQ_COL = "freq_cy_per_px"
#: other names of the frequency column read as it (the lens MTF table's)
_FREQ_ALIASES = ("frequency_cy_per_px",)
_CI_COLS = ("mtf_ci95_low", "mtf_ci95_high")


#: the largest MTF value :func:`read_mtf_table` accepts (sharpening lifts a measured SFR above 1 in
#: the band; a value ten times the zero-frequency one is no SFR)
_MTF_MAX = 10.0


def read_mtf_table(path: str | Path, channel: str | None = None) -> SFRResult:
    """Read an MTF table (CSV) into an :class:`SFRResult` without bootstrap samples.

    Accepted headers: ``freq_cy_per_px,mtf`` (optionally followed by ``mtf_ci95_low,
    mtf_ci95_high`` as written by :func:`write_mtf_table`, which are ignored), the sfrmat
    reference format ``freq_cy_per_px,sfr`` or multi-record ``freq_cy_per_px,sfr_R,sfr_G,
    sfr_B,sfr_Lum``.  Lines starting with ``#`` are comments.  Frequencies must be finite,
    >= 0 and strictly increasing; MTF values finite, >= 0 and at most :data:`_MTF_MAX`, and 1 ± 0.05 at
    0 cy/px where the table has that row.  ``channel`` selects the
    primary record of a multi-record table (default: ``Lum`` if present, else the first).

    Raises
    ------
    MTFInputError
        With file name, row (1-based line number) and column in the message.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise MTFInputError(f"{path}: cannot read MTF table ({exc})") from exc
    rows = [
        (i + 1, r)
        for i, r in enumerate(csv.reader(text.splitlines()))
        if r and not r[0].lstrip().startswith("#") and any(c.strip() for c in r)
    ]
    if not rows:
        raise MTFInputError(f"{path}: empty MTF table")
    hline, header = rows[0]
    header = [h.strip() for h in header]
    expected = (
        "expected header 'freq_cy_per_px,mtf' or 'freq_cy_per_px,sfr' (or 'freq_cy_per_px,sfr_R,sfr_G,sfr_B,sfr_Lum')"
    )
    if header[0] in _FREQ_ALIASES:  # the lens table's name of the column (measure.detector): one convention, both read
        header[0] = _FREQ_COL
    if header[0] != _FREQ_COL:
        raise MTFInputError(f"{path}: row {hline}, column 1: found {header[0]!r}; {expected}")
    data_cols: list[tuple[int, str]] = []
    for j, h in enumerate(header[1:], start=1):
        if h in _CI_COLS:
            continue
        if h in ("mtf", "sfr"):
            data_cols.append((j, h))
        elif h.startswith(("sfr_", "mtf_")) and len(h) > 4:
            data_cols.append((j, h[4:]))
        else:
            raise MTFInputError(f"{path}: row {hline}, column {j + 1}: unexpected column {h!r}; {expected}")
    if not data_cols:
        raise MTFInputError(f"{path}: row {hline}: no MTF column; {expected}")
    if len(rows) < 3:
        raise MTFInputError(f"{path}: need at least 2 data rows, found {len(rows) - 1}")
    values = np.empty((len(rows) - 1, len(header)))
    for i, (lineno, r) in enumerate(rows[1:]):
        if len(r) != len(header):
            raise MTFInputError(f"{path}: row {lineno}: {len(r)} columns, header has {len(header)}")
        for j, cell in enumerate(r):
            try:
                v = float(cell)
            except ValueError:
                raise MTFInputError(
                    f"{path}: row {lineno}, column {j + 1} ({header[j]!r}): cannot parse {cell.strip()!r} as a number"
                ) from None
            if not math.isfinite(v) or v < 0:
                raise MTFInputError(
                    f"{path}: row {lineno}, column {j + 1} ({header[j]!r}): "
                    f"value {cell.strip()!r} must be finite and >= 0"
                )
            values[i, j] = v
    freq = values[:, 0]
    dif = np.diff(freq)
    if np.any(dif <= 0):
        k = int(np.argmax(dif <= 0)) + 1
        raise MTFInputError(
            f"{path}: row {rows[k + 1][0]}, column 1 ({_FREQ_COL!r}): frequencies must be strictly increasing"
        )
    # a system MTF is 1 at zero frequency; sharpening can lift it above 1 in the band, but not tenfold:
    # a table far from that is in other units or not normalised, and its Δs (Eq. 9) would be meaningless
    for j, _name in data_cols:
        v = values[:, j]
        if freq[0] == 0.0 and abs(v[0] - 1.0) > 0.05:
            raise MTFInputError(
                f"{path}: row {rows[1][0]}, column {j + 1} ({header[j]!r}): the MTF at 0 cy/px "
                f"is {v[0]:g}, not 1: normalise the table at zero frequency"
            )
        if np.any(v > _MTF_MAX):
            k = int(np.argmax(v > _MTF_MAX))
            raise MTFInputError(
                f"{path}: row {rows[k + 1][0]}, column {j + 1} ({header[j]!r}): MTF "
                f"{v[k]:g} is above {_MTF_MAX:g}: not an MTF normalised to 1 at zero frequency"
            )
    by = {name: values[:, j].copy() for j, name in data_cols}
    names = list(by)
    if channel is None:
        lowmap = {n.lower(): n for n in names}
        pname = lowmap.get("lum", names[0])
    elif channel in by:
        pname = channel
    else:
        raise MTFInputError(f"{path}: channel {channel!r} not in table columns {names}")
    mtf50 = {k: float(_crossing_cy_per_px(freq, v, 0.5)[0]) for k, v in by.items()}
    se = {k: _sampling_efficiency(freq, v) for k, v in by.items()}
    return SFRResult(
        freq_cy_per_px=freq,
        mtf=by[pname],
        mtf_samples=np.empty((0, freq.size)),
        mtf50_cy_per_px=mtf50[pname],
        mtf50_samples=np.empty(0),
        edge_angle_deg=math.nan,
        sampling_efficiency=se[pname],
        warnings=[],
        channel=pname,
        mtf_by_channel=by,
        mtf50_by_channel_cy_per_px=mtf50,
        sampling_efficiency_by_channel=se,
        orientation="unknown",
        source=str(path),
    )


def mtf_table_text(result: SFRResult) -> str:
    """The CSV text :func:`write_mtf_table` writes."""
    import io

    lo, hi = result.mtf_ci(0.95)
    has_ci = result.mtf_samples.shape[0] > 0
    fh = io.StringIO()
    w = csv.writer(fh, lineterminator="\r\n")
    w.writerow([_FREQ_COL, "mtf"] + (list(_CI_COLS) if has_ci else []))
    for i, f in enumerate(result.freq_cy_per_px):
        row = [f"{f:.6f}", f"{result.mtf[i]:.6f}"]
        if has_ci:
            row += [f"{lo[i]:.6f}", f"{hi[i]:.6f}"]
        w.writerow(row)
    return fh.getvalue()


def write_mtf_table(result: SFRResult, path: str | Path) -> None:
    """Write ``freq_cy_per_px,mtf,mtf_ci95_low,mtf_ci95_high`` (95 % percentile interval
    columns only when bootstrap samples are present).

    The file can be read back with :func:`read_mtf_table`.
    """
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(mtf_table_text(result))


#: terminal escape sequences and control characters (C0, DEL, C1)
_CONTROL = re.compile("\x1b\\[[0-9;?]*[ -/]*[@-~]|[\x00-\x1f\x7f-\x9f]")


def printable(text: str) -> str:
    """``text`` without control characters: what a file holds (a TIFF tag, a library's message
    quoting it) is never echoed raw into a terminal or a CSV."""
    return _CONTROL.sub("", text.replace("\t", " "))


@contextlib.contextmanager
def _pillow_limit():
    """Pillow's own decompression-bomb limit set to bayescap's (``BAYESCAP_MAX_IMAGE_PIXELS``; 0 =
    none), so that the one limit the docs name is the one that holds."""
    from PIL import Image

    from bayescap._limits import image_pixel_limit

    before = Image.MAX_IMAGE_PIXELS
    limit = image_pixel_limit()
    # Pillow warns above its limit and refuses at twice it, when it opens the file: never below
    # bayescap's (an image just above bayescap's limit gets bayescap's message, checked before decoding)
    Image.MAX_IMAGE_PIXELS = None if not limit else max(limit, before or 0)
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = before


def read_image(path: str | Path) -> np.ndarray:
    """Read an edge image (TIFF, PNG, JPEG, ``.npy``) as a float array, (H, W) or (H, W, 3).

    Pillow reads every common container (LZW-compressed TIFF included); 16-bit images keep
    their values. An image declaring more than :data:`bayescap._limits.MAX_IMAGE_PIXELS` values
    is refused before it is decoded. The data must be linear (no gamma); a camera RAW file should be demosaiced
    linearly first or measured per CFA plane. Raises :class:`MTFInputError` naming the file.
    """
    from PIL import Image, UnidentifiedImageError

    from bayescap._limits import image_pixels_problem

    p = Path(path)
    if p.suffix.lower() == ".npy":
        try:
            arr = np.load(p, allow_pickle=False, mmap_mode="r")  # the header first: its shape
        except (OSError, ValueError) as e:
            raise MTFInputError(f"{p}: cannot read the array ({e})") from None
        problem = image_pixels_problem(arr.shape)
        if problem:
            raise MTFInputError(f"{p}: {problem}")
        arr = np.array(arr)
    else:
        try:
            # Pillow warns of what it finds broken ("Corrupt EXIF data") before failing: the
            # error below says it on its one line
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                with _pillow_limit(), Image.open(p) as im:
                    problem = image_pixels_problem((im.size[1], im.size[0]) + ((3,) if im.mode != "L" else ()))
                    if problem:
                        raise MTFInputError(f"{p}: {problem}")
                    im.load()
                    if im.mode in ("P", "PA", "LA", "RGBA"):
                        im = im.convert("RGB")
                    arr = np.asarray(im)
        except FileNotFoundError:
            raise MTFInputError(f"{p}: file not found") from None
        except Image.DecompressionBombError as e:  # Pillow's own limit, checked when it opens
            raise MTFInputError(f"{p}: {printable(str(e))}") from None
        except (UnidentifiedImageError, OSError, ValueError) as e:
            if isinstance(e, MTFInputError):
                raise
            raise MTFInputError(f"{p}: cannot read the image ({printable(str(e))})") from None
    arr = np.asarray(arr, dtype=float)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise MTFInputError(f"{p}: expected a grey or RGB image, got an array of shape {arr.shape}")
    return arr
