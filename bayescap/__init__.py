"""bayescap: Bayesian image-sensor characterization.

Photon-transfer measurements -> posterior of the sensor noise model (Tisse, Guichard & Cao 2008,
Eq. 1) -> image information capacity C = s' * b' (Eq. 6-9) with credible intervals.

>>> import bayescap
>>> result = bayescap.fit(bayescap.load("sensor.csv"), seed=1)   # doctest: +SKIP
>>> result.to_dict()["derived"]["capacity_bits"]["ci95"]         # doctest: +SKIP
"""
from bayescap._version import __version__  # noqa: E402

from bayescap._heap import retain_freed_memory as _retain_freed_memory  # noqa: E402

_retain_freed_memory()   # glibc keeps freed temporaries for the next log_prob call (bayescap/_heap.py)

from bayescap.api import fit, load, default_scene  # noqa: E402
from bayescap.posterior import FitResult, Scene  # noqa: E402
from bayescap.io.ptc_csv import PTCData, read_ptc_csv, write_ptc_csv
from bayescap.exceptions import PTCInputError
from bayescap import simulate  # noqa: E402,F401

__all__ = ["fit", "load", "default_scene", "FitResult", "Scene", "PTCData", "PTCInputError",
           "read_ptc_csv", "write_ptc_csv", "simulate", "__version__"]
