"""Photon-transfer data: reading and validating the contract CSV, the immutable PTCData object.

The format (see README, "Photon-transfer CSV"): optional ``# key: value`` metadata lines, one
header row, one row per exposure level. Required columns ``exposure_time_s, mean_dn,
temporal_var_dn2, dark_mean_dn, dark_temporal_var_dn2, n_pixels``; optional
``photons_per_pixel, exposure_lux_s, spatial_var_dn2, dark_spatial_var_dn2, n_frames,
frac_saturated``. Spreadsheet exports are read too: ``;``-separated tables (then with a decimal comma
allowed, ``1,5``), tab-separated ones, Excel's first line ``sep=;``, trailing empty columns and
separators padding the metadata lines; control characters (ANSI escapes) are removed from metadata
values. Every refusal raises :class:`PTCInputError` naming file, row and column.

**Mean/variance tables** (the astronomy photon-transfer table of LSST cp_pipe, eotest or a lab
notebook: one row per flat pair, means with the bias already removed, pair-difference variance / 2)
have no dark column: then only ``mean_dn`` and ``temporal_var_dn2`` are required
(:data:`MEAN_VARIANCE_REQUIRED`). ``exposure_time_s`` and ``n_pixels`` are optional there; the
dark columns are filled as "not measured": ``dark_mean_dn`` is the means' offset (``#
black_level_dn:``, else 0), ``dark_temporal_var_dn2`` is NaN on every row
(:attr:`PTCData.has_dark_rows` is False), an absent ``exposure_time_s`` is NaN and an absent
``n_pixels`` is +inf (:attr:`PTCData.n_pixels_known` is False: no sampling error is assumed, the
fit's variance discrepancy carries the whole scatter). cp_pipe's names ``rawMeans``, ``rawVars``
and ``rawExpTimes`` are read as ``mean_dn``, ``temporal_var_dn2`` and ``exposure_time_s``
(:data:`COLUMN_ALIASES`) when the contract's name is not in the header.
"""

from __future__ import annotations

import csv
import io
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bayescap.exceptions import PTCInputError
from bayescap.io.atomic import atomic_write_text
from bayescap.io.table_checks import (
    _check_repeated_key,
    _records,
    check_lit_not_below_dark,
    check_not_all_saturated,
    check_repeated_rows,
    check_some_row_mostly_unclipped,
)

__all__ = [
    "PTCData",
    "PTCInputError",
    "read_ptc_csv",
    "write_ptc_csv",
    "REQUIRED_COLUMNS",
    "OPTIONAL_COLUMNS",
    "MEAN_VARIANCE_REQUIRED",
    "DARK_COLUMNS",
    "COLUMN_ALIASES",
    "METADATA_TYPES",
]

REQUIRED_COLUMNS = (
    "exposure_time_s",
    "mean_dn",
    "temporal_var_dn2",
    "dark_mean_dn",
    "dark_temporal_var_dn2",
    "n_pixels",
)
OPTIONAL_COLUMNS = (
    "photons_per_pixel",
    "exposure_lux_s",
    "spatial_var_dn2",
    "dark_spatial_var_dn2",
    "n_frames",
    "frac_saturated",
)

#: a table without any of these columns is a mean/variance table (module docstring)
DARK_COLUMNS = ("dark_mean_dn", "dark_temporal_var_dn2", "dark_spatial_var_dn2")
#: the only required columns of a mean/variance table
MEAN_VARIANCE_REQUIRED = ("mean_dn", "temporal_var_dn2")
#: other names of contract columns (LSST cp_pipe's PTC dataset), used when the contract's name is absent
COLUMN_ALIASES = {"rawMeans": "mean_dn", "rawVars": "temporal_var_dn2", "rawExpTimes": "exposure_time_s"}

#: optional columns that may be left empty on rows where they were not measured
SPARSE_COLUMNS = ("spatial_var_dn2", "dark_spatial_var_dn2", "n_frames")

#: known metadata keys and their types (unknown keys are kept as strings)
METADATA_TYPES = {
    "sensor": str,
    "manufacturer": str,
    "pixel_pitch_um": float,
    "width_px": int,
    "height_px": int,
    "adc_bits": int,
    "black_level_dn": float,
    "f_number": float,
    "wavelength_nm": float,
    "fill_factor": float,
    "analog_gain": float,
    "channel": str,
    "temperature_c": float,
    "crosstalk_sigma_px": float,
}


def _readonly(a):
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class PTCData:
    """Validated photon-transfer measurements of one sensor/channel/gain (immutable).

    Arrays are read-only, sorted by increasing bright mean. ``metadata`` holds the typed
    ``# key: value`` lines; ``source`` the file name as given.
    """

    exposure_time_s: np.ndarray
    mean_dn: np.ndarray
    temporal_var_dn2: np.ndarray
    dark_mean_dn: np.ndarray
    dark_temporal_var_dn2: np.ndarray
    n_pixels: np.ndarray
    photons_per_pixel: np.ndarray | None = None
    exposure_lux_s: np.ndarray | None = None
    spatial_var_dn2: np.ndarray | None = None
    dark_spatial_var_dn2: np.ndarray | None = None
    n_frames: np.ndarray | None = None
    frac_saturated: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    source: str = "<memory>"
    row_numbers: np.ndarray | None = None  # 1-based data-row numbers in the file (for messages)

    @property
    def n_levels(self) -> int:
        return int(self.mean_dn.size)

    @property
    def adc_max_dn(self) -> float | None:
        bits = self.metadata.get("adc_bits")
        return None if bits is None else float(2 ** int(bits) - 1)

    @property
    def signal_dn(self) -> np.ndarray:
        """Dark-subtracted bright mean (DN)."""
        return self.mean_dn - self.dark_mean_dn

    @property
    def has_spatial(self) -> bool:
        return self.spatial_var_dn2 is not None or self.dark_spatial_var_dn2 is not None

    def with_metadata(self, **overrides) -> "PTCData":
        md = dict(self.metadata)
        md.update(_typed_overrides(overrides, self.source))
        _check_metadata(md, self.source)
        return _replace(self, metadata=md)

    def select(self, mask) -> "PTCData":
        """A new PTCData with only the rows where ``mask`` is true."""
        mask = np.asarray(mask, bool)
        kw = {}
        for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS + ("row_numbers",):
            v = getattr(self, name)
            kw[name] = None if v is None else _readonly(np.asarray(v)[mask])
        return PTCData(**kw, metadata=dict(self.metadata), source=self.source)

    @property
    def has_dark_rows(self) -> bool:
        """False for a mean/variance table (no dark pairs: ``dark_temporal_var_dn2`` is NaN throughout)."""
        return bool(np.any(np.isfinite(self.dark_temporal_var_dn2)))

    @property
    def n_pixels_known(self) -> bool:
        """False when the table gave no ``n_pixels`` (filled with +inf: the variances' scatter is fitted)."""
        return bool(np.all(np.isfinite(self.n_pixels)))

    @property
    def has_exposure_times(self) -> bool:
        return bool(np.all(np.isfinite(self.exposure_time_s)))

    def row_label(self, i) -> int:
        return int(self.row_numbers[i]) if self.row_numbers is not None else int(i) + 1


def _replace(obj, **kw):
    from dataclasses import replace

    return replace(obj, **kw)


#: control characters (C0, DEL, C1): an ANSI escape sequence in a metadata value would reach the
#: terminal when the report is printed
_CONTROL = re.compile("\x1b\\[[0-9;?]*[ -/]*[@-~]|[\x00-\x1f\x7f-\x9f]")
#: Excel's first line naming the separator, ``sep=;``
_SEP_LINE = re.compile(r'^"?sep=(.)"?$', re.IGNORECASE)


def _clean(text: str) -> str:
    """``text`` without control characters (a tab becomes a space)."""
    return _CONTROL.sub("", text.replace("\t", " "))


def _sniff_delimiter(header_line: str) -> str:
    """The separator of the table, from its header line: ``;`` (European spreadsheets, with a
    decimal comma), a tab, or ``,``."""
    counts = {d: header_line.count(d) for d in (",", ";", "\t")}
    if counts[","] == 0 and (counts[";"] or counts["\t"]):
        return ";" if counts[";"] >= counts["\t"] else "\t"
    return ","


def _number(s: str, delimiter: str) -> float:
    """``float(s)``; with a separator other than ``,`` a decimal comma is read too (``1,5``)."""
    if delimiter != "," and "," in s and "." not in s:
        s = s.replace(",", ".", 1)
    return float(s)


def _parse_metadata(lines, path, delimiter=","):
    md, seen = {}, {}
    for lineno, line in lines:
        # a spreadsheet pads every line to the table's width with separators
        body = _clean(line.lstrip("#").strip().rstrip(delimiter + " ").strip())
        if not body:
            continue
        if ":" not in body:
            continue  # a plain comment
        key, value = (s.strip() for s in body.split(":", 1))
        _check_repeated_key(seen, key, value, lineno, path)
        typ = METADATA_TYPES.get(key)
        if typ is None:
            md[key] = value
            continue
        try:
            num = _number(value, delimiter) if typ in (int, float) else None
            v = typ(num) if typ is float else typ(value) if typ is str else int(num)
            if typ is int and num != int(num):
                raise ValueError
        except (ValueError, OverflowError):
            raise PTCInputError(
                f"metadata '{key}' must be {typ.__name__}, got '{value}'", path=path, row=f"metadata line {lineno}"
            ) from None
        if typ is float and not math.isfinite(v):
            raise PTCInputError(
                f"metadata '{key}' must be finite, got '{value}'", path=path, row=f"metadata line {lineno}"
            )
        md[key] = v
    _check_metadata(md, path)
    return md


def _typed_overrides(overrides: dict, path) -> dict:
    """Metadata overrides (keyword arguments, command-line options) with the types of
    :data:`METADATA_TYPES`: a whole number for an int key (``adc_bits=12.5`` is refused), a finite
    number for a float key, text for a str key; None values are left out."""
    out = {}
    for key, v in overrides.items():
        if v is None:
            continue
        typ = METADATA_TYPES.get(key)
        if typ in (int, float):
            ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
            ok = ok and math.isfinite(float(v)) and (typ is float or float(v) == int(v))
            if not ok:
                kind = "a whole number" if typ is int else "a finite number"
                raise PTCInputError(f"metadata override '{key}' must be {kind}, got {v!r}", path=path)
            v = typ(v)
        elif typ is str:
            v = _clean(str(v))
        out[key] = v
    return out


def _check_metadata(md, path):
    positive = ("pixel_pitch_um", "width_px", "height_px", "adc_bits", "f_number", "wavelength_nm")
    for k in positive:
        if k in md and not md[k] > 0:
            raise PTCInputError(f"metadata '{k}' must be positive, got {md[k]}", path=path)
    for k, top in (("width_px", _MAX_SIDE_PX), ("height_px", _MAX_SIDE_PX), ("pixel_pitch_um", _MAX_PITCH_UM)):
        if k in md and md[k] > top:
            raise PTCInputError(f"metadata '{k}' {md[k]:g} is implausible (above {top:g})", path=path)
    if "adc_bits" in md and not 1 <= md["adc_bits"] <= 32:
        raise PTCInputError(f"metadata 'adc_bits' must be between 1 and 32, got {md['adc_bits']}", path=path)
    if "crosstalk_sigma_px" in md and not md["crosstalk_sigma_px"] >= 0:
        raise PTCInputError(f"metadata 'crosstalk_sigma_px' must be >= 0, got {md['crosstalk_sigma_px']}", path=path)
    if "temperature_c" in md and not md["temperature_c"] >= _ABSOLUTE_ZERO_C:
        raise PTCInputError(
            f"metadata 'temperature_c' must be >= {_ABSOLUTE_ZERO_C:g} (absolute zero), got {md['temperature_c']}",
            path=path,
        )
    if "fill_factor" in md and not 0 < md["fill_factor"] <= 1:
        raise PTCInputError(f"metadata 'fill_factor' must be in (0, 1], got {md['fill_factor']}", path=path)


def read_ptc_csv(path, *, overrides: dict | None = None, content: bytes | None = None) -> PTCData:
    """Read and validate a photon-transfer CSV (see module docstring).

    ``overrides`` (e.g. from the command line) replace metadata values. ``content``: the file's
    bytes, already read (standard input), with ``path`` the name errors give. Raises
    :class:`PTCInputError` naming the file, the row (1 = first data row) and the column.
    """
    path_str = str(path)
    try:
        raw = Path(path).read_bytes() if content is None else content
    except FileNotFoundError:
        raise PTCInputError("file not found", path=path_str) from None
    except OSError as e:
        raise PTCInputError(f"cannot read file ({e.strerror})", path=path_str) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise PTCInputError("not a UTF-8 text file", path=path_str) from None
    lines = text.splitlines()
    meta_lines, body_start, delimiter = [], None, None
    for i, line in enumerate(lines):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            meta_lines.append((i + 1, s))
            continue
        m = _SEP_LINE.match(s)
        if m and delimiter is None:  # Excel's "sep=," line
            delimiter = m.group(1)
            continue
        body_start = i
        break
    if body_start is None:
        raise PTCInputError("empty file: expected a header row and at least two data rows", path=path_str)
    delimiter = delimiter or _sniff_delimiter(lines[body_start])
    md = _parse_metadata(meta_lines, path_str, delimiter)
    if overrides:
        md.update(_typed_overrides(overrides, path_str))
        _check_metadata(md, path_str)
    reader = _records(csv.reader(io.StringIO("\n".join(lines[body_start:])), delimiter=delimiter), path_str)
    header = [h.strip() for h in next(reader)]
    while header and header[-1] == "":  # a spreadsheet's trailing empty columns
        header.pop()
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise PTCInputError(f"duplicate column(s) {', '.join(dup)} in the header", path=path_str, row="header")
    header, label = _apply_aliases(header)
    mean_variance = not any(c in header for c in DARK_COLUMNS)
    required = MEAN_VARIANCE_REQUIRED if mean_variance else REQUIRED_COLUMNS
    missing = [c for c in required if c not in header]
    if missing:
        what = (
            f"required: {', '.join(MEAN_VARIANCE_REQUIRED)} for a mean/variance table; a table with dark "
            f"pairs needs {', '.join(REQUIRED_COLUMNS)}"
            if mean_variance
            else f"required: {', '.join(REQUIRED_COLUMNS)}"
        )
        raise PTCInputError(
            f"missing required column(s): {', '.join(missing)} ({what})",
            path=path_str,
            row="header",
            column=missing[0],
        )
    wanted = [c for c in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if c in header]
    cols = {c: [] for c in wanted}
    rownums = []
    rowno = 0
    for rec in reader:
        if not rec or all(not x.strip() for x in rec):
            continue
        if rec[0].lstrip().startswith("#"):
            continue
        rowno += 1
        while len(rec) > len(header) and not rec[-1].strip():  # trailing empty columns
            rec = rec[:-1]
        if len(rec) != len(header):
            raise PTCInputError(f"has {len(rec)} fields, the header has {len(header)}", path=path_str, row=rowno)
        for c in wanted:
            s = rec[header.index(c)].strip()
            if s == "" and c in SPARSE_COLUMNS:
                cols[c].append(math.nan)  # not measured at this level
                continue
            if s == "" and c in OPTIONAL_COLUMNS:
                raise PTCInputError(
                    "empty value in an optional column (leave the column out or give every row a value)",
                    path=path_str,
                    row=rowno,
                    column=label[c],
                )
            try:
                v = _number(s, delimiter)
            except ValueError:
                raise PTCInputError(
                    f"expected a number, got '{s}'" if s else "missing value", path=path_str, row=rowno, column=c
                ) from None
            if not math.isfinite(v):
                raise PTCInputError(f"expected a finite number, got '{s}'", path=path_str, row=rowno, column=label[c])
            _check_value(c, v, path_str, rowno, label[c])
            cols[c].append(v)
        rownums.append(rowno)
    if rowno < 2:
        raise PTCInputError(f"needs at least 2 data rows (exposure levels), found {rowno}", path=path_str)
    if mean_variance:
        _fill_mean_variance(cols, rowno, md)
    order = np.argsort(np.asarray(cols["mean_dn"]) - np.asarray(cols["dark_mean_dn"]), kind="stable")
    kw = {c: _readonly(np.asarray(v)[order]) for c, v in cols.items()}
    check_repeated_rows(cols, rownums, path_str)
    data = PTCData(**kw, metadata=md, source=path_str, row_numbers=_readonly(np.asarray(rownums)[order]))
    _check_consistency(data, path_str)
    check_some_row_mostly_unclipped(data, path_str)
    return data


def _apply_aliases(header):
    """The header with :data:`COLUMN_ALIASES` read as the contract's names (where the contract's
    name is absent), and each contract column's name as the file spells it (for messages)."""
    out = list(header)
    for i, h in enumerate(header):
        c = COLUMN_ALIASES.get(h)
        if c is not None and c not in header:
            out[i] = c
    label = {c: (c if c == h else f"{h} (read as {c})") for c, h in zip(out, header)}
    return out, label


def _fill_mean_variance(cols: dict, n: int, md: dict) -> None:
    """A mean/variance table's columns that were not measured (module docstring), in place: the
    dark mean is the means' offset (``black_level_dn``, else 0 DN: bias already removed), the dark
    variance NaN, an absent exposure time NaN, an absent ``n_pixels`` +inf."""
    cols["dark_mean_dn"] = [float(md.get("black_level_dn", 0.0))] * n
    cols["dark_temporal_var_dn2"] = [math.nan] * n
    cols.setdefault("exposure_time_s", [math.nan] * n)
    cols.setdefault("n_pixels", [math.inf] * n)


#: no column of a photon-transfer table comes near this (a variance of 32-bit DN values is below 2e19);
#: a larger value is a unit or export error, and the model's products of it would overflow
_MAX_ABS_VALUE = 1e30
#: exposure times (s) above 0 and below it are refused: no sensor integrates for less than a picosecond
_MIN_EXPOSURE_S = 1e-12
#: metadata a sensor cannot have: more pixels a side, a larger pixel (µm)
_MAX_SIDE_PX = 1_000_000
_MAX_PITCH_UM = 1000.0
#: temperatures below it (°C) are refused (metadata ``temperature_c``, a scene's temperature)
_ABSOLUTE_ZERO_C = -273.15


def _check_value(col, v, path, row, label=None):
    """Refuse a value no photon-transfer table can hold (``label``: the column as the file names it)."""
    label = label or col
    if v != 0 and abs(v) < sys.float_info.min:
        # a subnormal float is no measured value, and LAPACK fails on it (printing to stdout)
        raise PTCInputError(
            f"{v:g} is a subnormal number (below {sys.float_info.min:g}): not a measured value",
            path=path,
            row=row,
            column=label,
        )
    if col == "exposure_time_s" and 0 < v < _MIN_EXPOSURE_S:
        raise PTCInputError(
            f"exposure time {v:g} s is implausibly short (below {_MIN_EXPOSURE_S:g} s): check the column's units (seconds)",
            path=path,
            row=row,
            column=label,
        )
    if abs(v) > _MAX_ABS_VALUE:
        raise PTCInputError(
            f"{v:g} is implausibly large (above {_MAX_ABS_VALUE:g}): check the column's units",
            path=path,
            row=row,
            column=label,
        )
    nonneg = (
        "exposure_time_s",
        "temporal_var_dn2",
        "dark_temporal_var_dn2",
        "photons_per_pixel",
        "exposure_lux_s",
        "spatial_var_dn2",
        "dark_spatial_var_dn2",
    )
    if col in nonneg and v < 0:
        what = "variance" if "var" in col else "value"
        raise PTCInputError(f"negative {what} {v:g} is physically impossible", path=path, row=row, column=label)
    if col == "n_pixels" and (v < 2 or v != int(v)):
        raise PTCInputError(f"n_pixels must be a whole number >= 2, got {v:g}", path=path, row=row, column=label)
    if col == "n_frames" and (v < 1 or v != int(v)):
        raise PTCInputError(f"n_frames must be a whole number >= 1, got {v:g}", path=path, row=row, column=label)
    if col == "frac_saturated" and not 0 <= v <= 1:
        raise PTCInputError(f"frac_saturated must be in [0, 1], got {v:g}", path=path, row=row, column=label)


def _check_consistency(d: PTCData, path):
    adc = d.adc_max_dn
    if adc is not None:
        for col in ("mean_dn", "dark_mean_dn"):
            bad = np.nonzero(getattr(d, col) > adc + 1e-6)[0]
            if bad.size:
                i = bad[0]
                raise PTCInputError(
                    f"{getattr(d, col)[i]:g} DN exceeds the ADC maximum {adc:g} of adc_bits={d.metadata['adc_bits']}",
                    path=path,
                    row=d.row_label(i),
                    column=col,
                )
        # values within [0, ADC max] have a variance of at most ADC max²/4 (a frame pair's estimate
        # at most ADC max²/2): above ADC max² a variance column is in other units or corrupt
        for col in ("temporal_var_dn2", "dark_temporal_var_dn2", "spatial_var_dn2", "dark_spatial_var_dn2"):
            v = getattr(d, col)
            if v is None:
                continue
            bad = np.nonzero(v > adc * adc)[0]
            if bad.size:
                i = bad[0]
                raise PTCInputError(
                    f"{v[i]:g} DN² exceeds the square of the ADC maximum ({adc:g} DN of "
                    f"adc_bits={d.metadata['adc_bits']}): no variance of values within the "
                    "ADC's range is that large; check the column's units",
                    path=path,
                    row=d.row_label(i),
                    column=col,
                )
    check_lit_not_below_dark(d, path)
    if np.all(d.signal_dn <= 0):
        raise PTCInputError(
            "no row has a bright mean above its dark mean: not a photon-transfer series", path=path, column="mean_dn"
        )
    check_not_all_saturated(d, path)


def check_table(d: PTCData, path=None) -> None:
    """The table-wide checks :func:`read_ptc_csv` makes, for a PTCData built in memory too (the API
    path: :func:`bayescap.model.saturation_flags` calls this before every fit): no row repeated
    exactly, no lit mean far below its dark mean, not every row saturated, some row mostly unclipped."""
    path = d.source if path is None else path
    cols = {c: getattr(d, c) for c in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if getattr(d, c, None) is not None}
    rows = d.row_numbers if d.row_numbers is not None else np.arange(1, d.n_levels + 1)
    check_repeated_rows(cols, [int(r) for r in rows], path)
    check_lit_not_below_dark(d, path)
    check_not_all_saturated(d, path)  # the more specific message first, as read_ptc_csv gives it
    check_some_row_mostly_unclipped(d, path)


def write_ptc_csv(data_or_rows, path, *, metadata: dict | None = None, columns=None):
    """Write a contract CSV atomically (temp file + rename).

    ``data_or_rows`` is a PTCData or a dict of column -> array.
    """
    if isinstance(data_or_rows, PTCData):
        d = data_or_rows
        cols = {c: getattr(d, c) for c in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if getattr(d, c) is not None}
        if not d.has_dark_rows:  # a mean/variance table: what was not measured stays out
            for c in ("dark_mean_dn", "dark_temporal_var_dn2"):
                cols.pop(c)
            if not d.n_pixels_known:
                cols.pop("n_pixels")
            if not d.has_exposure_times:
                cols.pop("exposure_time_s")
        md = dict(d.metadata) if metadata is None else metadata
    else:
        cols = {k: np.asarray(v) for k, v in data_or_rows.items()}
        md = metadata or {}
    if columns is not None:
        cols = {c: cols[c] for c in columns}
    names = list(cols)
    n = len(next(iter(cols.values())))
    buf = io.StringIO()
    for k, v in md.items():
        buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for i in range(n):
        w.writerow([_fmt(cols[c][i], c) for c in names])
    atomic_write_text(path, buf.getvalue())


def _fmt(v, col):
    if col in SPARSE_COLUMNS and not math.isfinite(float(v)):
        return ""
    if col in ("n_pixels", "n_frames"):
        return str(int(round(float(v))))
    return repr(float(v))
