"""bayescap: Bayesian image-sensor characterization.

Photon-transfer measurements -> posterior of the sensor noise model (Tisse, Guichard & Cao 2008,
Eq. 1) -> image information capacity C = s' * b' (Eq. 6-9) with credible intervals.

>>> import bayescap
>>> result = bayescap.fit(bayescap.load("sensor.csv"), seed=1)   # doctest: +SKIP
>>> result.to_dict()["derived"]["capacity_bits"]["ci95"]         # doctest: +SKIP

Importing bayescap changes nothing global. :func:`retain_freed_memory` is an opt-in speed-up for
long-running processes (the command line calls it).
"""

from bayescap._heap import retain_freed_memory
from bayescap._version import __version__
from bayescap.exceptions import (
    BayescapError,
    BayescapWarning,
    ConvergenceWarning,
    InputError,
    PTCInputError,
)

#: the public names that need scipy, emcee or matplotlib, imported on first use (PEP 562): ``import
#: bayescap`` and ``bayescap --version`` stay light
_LAZY = {
    "fit": "bayescap.api",
    "load": "bayescap.api",
    "default_scene": "bayescap.api",
    "fit_many": "bayescap.batch",
    "FitResult": "bayescap.posterior",
    "Scene": "bayescap.posterior",
    "PTCData": "bayescap.io.ptc_csv",
    "read_ptc_csv": "bayescap.io.ptc_csv",
    "write_ptc_csv": "bayescap.io.ptc_csv",
}


def __getattr__(name):
    import importlib

    if name == "simulate":
        return importlib.import_module("bayescap.simulate")
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'bayescap' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY) | {"simulate"})


__all__ = [
    "fit",
    "fit_many",
    "load",
    "default_scene",
    "FitResult",
    "Scene",
    "PTCData",
    "read_ptc_csv",
    "write_ptc_csv",
    "BayescapError",
    "InputError",
    "PTCInputError",
    "BayescapWarning",
    "ConvergenceWarning",
    "retain_freed_memory",
    "simulate",
    "__version__",
]
