"""Raw responses of a reflectance set, for CS over the colours of real surfaces.

The domain of :func:`bayescap.colour.sensitivity.colour_sensitivity` can be the colours a camera
records from a reflectance set under an illuminant (every exposure of every mixture: the convex cone
of the patches' raw responses) instead of the full raw cube. The responses come from colour-science
(camera sensitivities, ``SDS_COLOURCHECKERS``, ``SDS_ILLUMINANTS``), without white balance, in the
camera's raw channel scale: colour-science's sensitivities are each normalised to a peak of one, so
pass ``channel_scale`` (e.g. the fitted per-channel QE ratios) to put them on the camera's raw axes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["reflectance_domain"]


def reflectance_domain(
    sensitivities: str = "Nikon 5100 (NPL)",
    reflectances: str = "ColorChecker N Ohta",
    illuminant: str = "D65",
    *,
    channel_scale=None,
) -> np.ndarray:
    """(n, 3) raw R, G, B responses of the reflectance set's patches (relative units)."""
    import colour

    sens = colour.MSDS_CAMERA_SENSITIVITIES[sensitivities] if isinstance(sensitivities, str) else sensitivities
    shape = sens.shape
    ill = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape)
    sds = colour.SDS_COLOURCHECKERS[reflectances] if isinstance(reflectances, str) else reflectances
    refl = np.array([np.asarray(sd.copy().align(shape).values, float) for sd in sds.values()])
    resp = (refl * np.asarray(ill.values, float)) @ np.asarray(sens.values, float)
    if channel_scale is not None:
        scale = np.asarray(channel_scale, float)
        if scale.shape != (3,) or not np.all(scale > 0):
            raise ValueError(f"channel_scale must be three positive numbers, got {channel_scale!r}")
        resp = resp * scale
    return resp / resp.max()
