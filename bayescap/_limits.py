"""Limits on what an input may declare, checked before it is decoded.

``MAX_IMAGE_PIXELS`` (default 2**28, about 268 million pixels, 2 GB as float64) bounds the pixels
an image or frame may declare: a few-MB compressed file can declare 40 000 x 40 000 pixels and
take tens of GB when decoded. Raise it by setting this attribute, or the environment variable
``BAYESCAP_MAX_IMAGE_PIXELS`` (a whole number; 0 = no limit).
"""

from __future__ import annotations

import os

__all__ = ["MAX_IMAGE_PIXELS", "image_pixels_problem", "image_pixel_limit"]

MAX_IMAGE_PIXELS = 2**28


def image_pixel_limit() -> int:
    """The limit in force (``BAYESCAP_MAX_IMAGE_PIXELS``, else :data:`MAX_IMAGE_PIXELS`); 0 = none."""
    return _limit()


def _limit() -> int:
    env = os.environ.get("BAYESCAP_MAX_IMAGE_PIXELS", "").strip()
    if env:
        try:
            return int(env)
        except ValueError:
            pass
    return MAX_IMAGE_PIXELS


def image_pixels_problem(shape) -> str | None:
    """Why an image of the declared ``shape`` is not decoded, in one line, or None."""
    n = 1
    for s in shape:
        n *= int(s)
    limit = _limit()
    if limit and n > limit:
        dims = " x ".join(str(int(s)) for s in shape)
        return (
            f"the image declares {dims} = {n:,} values, above the limit of {limit:,} "
            "(set BAYESCAP_MAX_IMAGE_PIXELS to raise it)"
        )
    return None
