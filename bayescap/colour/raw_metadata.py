"""The camera's colour-correction matrix (CCM) and white balance, from a RAW/DNG file or the user.

The CCM here maps white-balanced camera RGB to linear sRGB (D65), rows summing to one, the
matrix ``M`` of Σ_out = M W Σ_raw Wᵀ Mᵀ (``W`` the white-balance gains).

**From the RAW file** (LibRaw through rawpy): LibRaw's ``color_matrix`` is its ``rgb_cam``, exactly
this matrix (3×4, the fourth column zero for RGB sensors). For a DNG it is built from the file's
ColorMatrix1/2 (tag 50721/50722, XYZ → camera) while ``rgb_xyz_matrix`` comes back all zeros
(LibRaw 0.22; LibRaw issues 751, 425). When ``color_matrix`` is zero and ``rgb_xyz_matrix``
(``cam_xyz``, XYZ → camera) is not, the matrix is derived as dcraw's ``cam_xyz_coeff`` does:
``cam_rgb = cam_xyz · xyz_rgb``, each row normalised to sum one, then inverted.
The white balance is LibRaw's ``camera_whitebalance`` (as shot: a DNG's AsShotNeutral,
tag 50728, inverted) and else ``daylight_whitebalance``, both normalised to green = 1.

**From the user** (:func:`parse_ccm`): a RAW/DNG file (its metadata as above), a text/CSV file of
nine numbers (three rows), or nine numbers inline (``"1.4,-0.3,-0.1,..."``, row by row).

A matrix that is not finite or is singular (reciprocal condition number below 1e-12) is refused
with an :class:`~bayescap.exceptions.InputError` naming where it came from.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayescap.exceptions import InputError

__all__ = ["RawColour", "read_raw_colour", "ccm_from_cam_xyz", "parse_ccm", "check_ccm", "XYZ_RGB_D65"]

#: linear sRGB (D65) -> XYZ, the constants of dcraw's ``xyz_rgb`` (the ones LibRaw inverts with)
XYZ_RGB_D65 = np.array([[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169], [0.019334, 0.119193, 0.950227]])

_RCOND_MIN = 1e-12


@dataclass(frozen=True)
class RawColour:
    """What a RAW file says about colour.

    ``ccm`` (3, 3): white-balanced camera RGB -> linear sRGB; ``wb_gains`` (3,): R, G, B gains,
    G = 1 (``None`` when the file has none); ``*_source`` say where each came from.
    """

    ccm: np.ndarray | None
    ccm_source: str
    wb_gains: np.ndarray | None
    wb_source: str
    daylight_wb_gains: np.ndarray | None
    path: Path


def ccm_from_cam_xyz(cam_xyz) -> np.ndarray:
    """dcraw's ``cam_xyz_coeff``: camera -> sRGB from XYZ -> camera (3, 3), rows normalised first."""
    cam_rgb = np.asarray(cam_xyz, float)[:3, :3] @ XYZ_RGB_D65
    cam_rgb = cam_rgb / cam_rgb.sum(axis=1, keepdims=True)
    return np.linalg.inv(cam_rgb)


def _gains(values) -> np.ndarray | None:
    v = np.asarray(values, float)[:3]
    if not np.all(np.isfinite(v)) or v[1] <= 0 or np.any(v <= 0):
        return None
    return v / v[1]


def check_ccm(m, *, where: str) -> np.ndarray:
    """The matrix as a finite, invertible (3, 3) float array; :class:`InputError` otherwise."""
    try:
        m = np.asarray(m, float).reshape(3, 3)
    except ValueError:
        raise InputError(f"{where}: a colour-correction matrix has 9 numbers (3 rows of 3)") from None
    if not np.all(np.isfinite(m)):
        raise InputError(f"{where}: the colour-correction matrix holds a value that is not a finite number")
    s = np.linalg.svd(m, compute_uv=False)
    if s[0] == 0 or s[-1] / s[0] < _RCOND_MIN:
        raise InputError(
            f"{where}: the colour-correction matrix is singular (singular values {', '.join(f'{v:.3g}' for v in s)}): "
            "it maps different camera colours to one output colour and cannot be a CCM"
        )
    return m


def read_raw_colour(path: os.PathLike | str) -> RawColour:
    """The CCM and white balance in a RAW/DNG file's metadata (module docstring)."""
    from bayescap.exceptions import IngestError
    from bayescap.io.frames import _rawpy

    path = Path(path)
    if not path.is_file():
        raise IngestError("no such file", path=path)
    rawpy = _rawpy(path)
    try:
        with rawpy.imread(str(path)) as raw:
            n_colors = int(raw.num_colors)
            color_matrix = np.array(raw.color_matrix, float)
            cam_xyz = np.array(raw.rgb_xyz_matrix, float)
            cam_wb = np.array(raw.camera_whitebalance, float)
            day_wb = np.array(raw.daylight_whitebalance, float)
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise IngestError(
            f"cannot read the RAW/DNG metadata ({type(exc).__name__}: {exc}); is it a camera RAW or DNG file?",
            path=path,
        ) from exc
    if n_colors < 3:
        raise IngestError("the RAW file has no colour filter array (a monochrome sensor): no colour matrix", path=path)
    if np.any(color_matrix[:3, :3] != 0):
        ccm, source = color_matrix[:3, :3], f"{path.name}: LibRaw color_matrix (camera RGB -> sRGB)"
    elif np.any(cam_xyz[:3] != 0):
        ccm, source = (
            ccm_from_cam_xyz(cam_xyz),
            f"{path.name}: LibRaw rgb_xyz_matrix (XYZ -> camera), inverted as dcraw",
        )
    else:
        ccm, source = None, f"{path.name}: no colour matrix in the metadata"
    if ccm is not None:
        ccm = check_ccm(ccm, where=str(path))
    wb, wb_source = _gains(cam_wb), f"{path.name}: as shot (camera_whitebalance)"
    day = _gains(day_wb)
    if wb is None and day is not None:
        wb, wb_source = day, f"{path.name}: daylight (daylight_whitebalance)"
    if wb is None:
        wb_source = f"{path.name}: no white balance in the metadata"
    return RawColour(ccm=ccm, ccm_source=source, wb_gains=wb, wb_source=wb_source, daylight_wb_gains=day, path=path)


_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _numbers(text: str) -> list[float]:
    body = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    tokens = [t for t in re.split(r"[,;\s]+", body.strip()) if t]
    out = []
    for t in tokens:
        if not _NUMBER.fullmatch(t):
            raise ValueError(t)
        out.append(float(t))
    return out


def parse_ccm(spec: str) -> tuple[np.ndarray, str, "RawColour | None"]:
    """A CCM from ``--ccm``: a RAW/DNG file, a text file of 9 numbers, or 9 numbers inline.

    Returns (matrix (3, 3), where it came from, the RawColour when a RAW file was given).
    """
    p = Path(spec)
    if p.is_file():
        if p.suffix.lower() in (".csv", ".txt", ".tsv", ".ccm", ""):
            try:
                nums = _numbers(p.read_text(encoding="utf-8-sig"))
            except ValueError as e:
                raise InputError(f"{p}: {str(e)!r} is not a number (a CCM file holds 3 rows of 3 numbers)") from None
            except (OSError, UnicodeDecodeError) as e:
                raise InputError(f"{p}: cannot read the CCM file ({e})") from None
            if len(nums) != 9:
                raise InputError(f"{p}: {len(nums)} numbers where a CCM has 9 (3 rows of 3)")
            return check_ccm(nums, where=str(p)), f"user matrix ({p.name})", None
        rc = read_raw_colour(p)
        if rc.ccm is None:
            raise InputError(f"{p}: the RAW file's metadata hold no colour matrix; give the CCM as 9 numbers")
        return rc.ccm, rc.ccm_source, rc
    try:
        nums = _numbers(spec)
    except ValueError as e:
        raise InputError(f"--ccm {spec!r}: neither a file nor 9 numbers ({str(e)!r} is not a number)") from None
    if len(nums) != 9:
        raise InputError(f"--ccm {spec!r}: {len(nums)} numbers where a CCM has 9 (3 rows of 3) or a file")
    return check_ccm(nums, where="--ccm"), "user matrix (inline)", None
