"""Colour capacities of a CFA sensor, each labelled by its definition (bits per image, per draw).

The paper's capacity is ``C = s′·b′`` (Eq. 6): effective pixels times bits per pixel. A Bayer
sensor of N photosites gives three defensible colour versions, and they differ by more than their
intervals, so each is reported under its own name:

* ``superpixel``: ``CS × N/4``: one colour (CS bits) per RGGB quad, no MTF loss.
* ``per_channel``: ``Σ_c b′_c · s′_c`` over the four CFA channels: each channel's tonal range bits
  (Eq. 7) times its own effective pixels ``s′_c = N/4 · 2^{Δs_c}`` (Eq. 6, Δs_c its MTF loss, Eq. 9).
* ``cs_luminance_mtf``: ``CS · s′`` with ``s′ = N · 2^{Δs_lum}`` from the luminance MTF: as if
  demosaicking delivered a colour at every photosite with the luminance resolution (an optimistic
  reading: chroma is sampled at N/4).
"""

from __future__ import annotations

import numpy as np

from bayescap.physics.capacity import effective_pixels

__all__ = ["CAPACITY_DEFINITIONS", "colour_capacities"]

CAPACITY_DEFINITIONS = {
    "superpixel": "CS × N/4: one colour of CS bits per RGGB super-pixel, no MTF loss",
    "per_channel": "Σ_c b′_c · s′_c over R, Gr, Gb, B: tonal range bits (Eq. 7) × N/4 · 2^Δs_c effective pixels",
    "cs_luminance_mtf": "CS · s′, s′ = N · 2^Δs with Δs the luminance MTF loss (Eq. 9): colour at every photosite",
}


def colour_capacities(cs_bits, n_pixels, channel_bits, *, delta_s_channel_bits=0.0, delta_s_lum_bits=0.0) -> dict:
    """The three colour capacities (bits), each an array over draws, with their definitions.

    Parameters
    ----------
    cs_bits : (n_draws,) colour sensitivity (bits).
    n_pixels : photosites of the mosaic (all four channels together).
    channel_bits : (n_draws, 4) tonal range bits b′ of R, Gr, Gb, B.
    delta_s_channel_bits : MTF loss Δs per channel (bits, ≤ 0): scalar, (4,) or (n_draws, 4).
    delta_s_lum_bits : luminance MTF loss (bits, ≤ 0): scalar or (n_draws,).
    """
    cs = np.asarray(cs_bits, float)
    b = np.asarray(channel_bits, float)
    if b.ndim != 2 or b.shape[1] != 4 or b.shape[0] != cs.shape[0]:
        raise ValueError(f"channel_bits must have shape (n_draws, 4) matching cs_bits, got {b.shape}")
    n = float(n_pixels)
    if not n > 0:
        raise ValueError(f"n_pixels must be positive, got {n_pixels}")
    ds_c = np.broadcast_to(np.asarray(delta_s_channel_bits, float), b.shape)
    s_c = effective_pixels(n / 4.0, ds_c)
    return {
        "superpixel": {"bits": cs * n / 4.0, "definition": CAPACITY_DEFINITIONS["superpixel"]},
        "per_channel": {"bits": np.sum(b * s_c, axis=1), "definition": CAPACITY_DEFINITIONS["per_channel"]},
        "cs_luminance_mtf": {
            "bits": cs * effective_pixels(n, delta_s_lum_bits),
            "definition": CAPACITY_DEFINITIONS["cs_luminance_mtf"],
        },
    }
