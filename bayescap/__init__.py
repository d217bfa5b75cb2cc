"""bayescap: Bayesian image-sensor characterization.

Photon-transfer measurements -> posterior of the sensor noise model (Tisse, Guichard & Cao 2008,
Eq. 1) -> image information capacity C = s' * b' (Eq. 6-9) with credible intervals.

>>> import bayescap
>>> result = bayescap.fit(bayescap.load("sensor.csv"), seed=1)   # doctest: +SKIP
>>> result.to_dict()["derived"]["capacity_bits"]["ci95"]         # doctest: +SKIP

Importing bayescap changes nothing global. :func:`retain_freed_memory` is an opt-in speed-up for
long-running processes (the command line calls it).
"""

from bayescap import simulate
from bayescap._heap import retain_freed_memory
from bayescap._version import __version__
from bayescap.api import default_scene, fit, load
from bayescap.batch import fit_many
from bayescap.exceptions import (
    BayescapError,
    BayescapWarning,
    ConvergenceWarning,
    InputError,
    PTCInputError,
)
from bayescap.io.ptc_csv import PTCData, read_ptc_csv, write_ptc_csv
from bayescap.posterior import FitResult, Scene

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
