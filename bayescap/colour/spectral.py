"""Raw responses of a reflectance set, for CS over the colours of real surfaces.

The domain of :func:`bayescap.colour.sensitivity.colour_sensitivity` can be the colours a camera
records from a reflectance set under an illuminant (every exposure of every mixture: the convex cone
of the patches' raw responses) instead of the full raw cube. The responses come from colour-science
(camera sensitivities, ``SDS_COLOURCHECKERS``, ``SDS_ILLUMINANTS``): for patch p and channel c,
``∫ R_p(λ) E(λ) S_c(λ) dλ`` on the sensitivities' wavelengths, without white balance.

The channels' relative scale. colour-science's sensitivities are each normalised to a peak of one,
so the responses are not on the camera's raw axes until each channel is scaled. Either pass
``channel_scale`` (e.g. the fitted per-channel QE ratios), or ``wb_gains``: the white balance in use
for this illuminant, which by definition makes a perfect white's raw response ``∝ 1/wb_gains``; the
channels are then scaled so that it does. Only the directions matter (a cone): the overall scale is
free and the result is normalised to a largest response of one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["reflectance_domain", "load_sensitivities", "SENSITIVITY_NAMES"]

#: colour-science's camera sensitivities (BSD-3), selectable by name
SENSITIVITY_NAMES = ("Nikon 5100 (NPL)", "Sigma SDMerill (NPL)")


def load_sensitivities(spec):
    """Camera spectral sensitivities: a colour-science name (:data:`SENSITIVITY_NAMES`), a CSV file
    of ``wavelength_nm, R, G, B`` rows (a header line allowed, wavelengths increasing, evenly spaced)
    or an ``RGB_CameraSensitivities``. ``ValueError`` naming the input when it is none of those."""
    import colour
    from colour.characterisation import RGB_CameraSensitivities

    if isinstance(spec, RGB_CameraSensitivities):
        return spec
    if str(spec) in colour.MSDS_CAMERA_SENSITIVITIES:
        return colour.MSDS_CAMERA_SENSITIVITIES[str(spec)]
    path = Path(str(spec))
    if not path.is_file():
        raise ValueError(
            f"{spec}: not a file and not one of colour-science's camera sensitivities ({', '.join(SENSITIVITY_NAMES)})"
        )
    rows = []
    for i, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        parts = [p.strip() for p in line.replace(";", ",").split(",") if p.strip()]
        if not parts or line.lstrip().startswith("#"):
            continue
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            if not rows and i == 1:
                continue  # a header line
            raise ValueError(
                f"{path}: row {i}: expected numbers wavelength_nm, R, G, B, got {line.strip()!r}"
            ) from None
        if len(vals) != 4 or not np.all(np.isfinite(vals)) or min(vals[1:]) < 0:
            raise ValueError(f"{path}: row {i}: expected 4 finite numbers wavelength_nm, R, G, B (R, G, B ≥ 0)")
        rows.append(vals)
    a = np.array(rows)
    if a.shape[0] < 3:
        raise ValueError(f"{path}: expected at least 3 rows of wavelength_nm, R, G, B")
    step = np.diff(a[:, 0])
    if np.any(step <= 0) or np.ptp(step) > 1e-6 * step.max():
        raise ValueError(f"{path}: the wavelengths must increase in even steps")
    if np.any(a[:, 1:].max(axis=0) <= 0):
        raise ValueError(f"{path}: a channel's sensitivity is zero at every wavelength")
    return RGB_CameraSensitivities(dict(zip(a[:, 0], a[:, 1:])), labels=("R", "G", "B"), name=path.name)


def reflectance_domain(
    sensitivities="Nikon 5100 (NPL)",
    reflectances: str = "ColorChecker N Ohta",
    illuminant: str = "D65",
    *,
    channel_scale=None,
    wb_gains=None,
) -> np.ndarray:
    """(n, 3) raw R, G, B responses of the reflectance set's patches (relative units; module
    docstring). ``sensitivities``: see :func:`load_sensitivities`; ``reflectances``: an
    ``SDS_COLOURCHECKERS`` name or a dict of spectral distributions; ``illuminant``: an
    ``SDS_ILLUMINANTS`` name. ``channel_scale`` or ``wb_gains`` (not both) put the channels on
    the camera's raw axes."""
    import colour

    sens = load_sensitivities(sensitivities)
    shape = sens.shape
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"unknown illuminant {illuminant!r} (colour-science's SDS_ILLUMINANTS: D65, D50, A, ...)")
    if isinstance(reflectances, str) and reflectances not in colour.SDS_COLOURCHECKERS:
        raise ValueError(
            f"unknown reflectance set {reflectances!r} (colour-science's SDS_COLOURCHECKERS: "
            + ", ".join(colour.SDS_COLOURCHECKERS)
            + ")"
        )
    if channel_scale is not None and wb_gains is not None:
        raise ValueError("give channel_scale or wb_gains, not both")
    ill = colour.SDS_ILLUMINANTS[illuminant].copy().align(shape)
    sds = colour.SDS_COLOURCHECKERS[reflectances] if isinstance(reflectances, str) else reflectances
    refl = np.array([np.asarray(sd.copy().align(shape).values, float) for sd in sds.values()])
    e = np.asarray(ill.values, float)
    s = np.asarray(sens.values, float)
    resp = (refl * e) @ s
    if wb_gains is not None:
        wb = np.asarray(wb_gains, float)
        if wb.shape != (3,) or not np.all(wb > 0):
            raise ValueError(f"wb_gains must be three positive numbers, got {wb_gains!r}")
        channel_scale = (1.0 / wb) / (e @ s)  # a perfect white's response becomes ∝ 1/wb
    if channel_scale is not None:
        scale = np.asarray(channel_scale, float)
        if scale.shape != (3,) or not np.all(scale > 0):
            raise ValueError(f"channel_scale must be three positive numbers, got {channel_scale!r}")
        resp = resp * scale
    return resp / resp.max()
