"""bayescap: Bayesian image-sensor characterization.

Photon-transfer measurements -> posterior of the sensor noise model (Tisse, Guichard & Cao 2008,
Eq. 1) -> image information capacity C = s' * b' (Eq. 6-9) with credible intervals.

>>> import bayescap
>>> result = bayescap.fit(bayescap.load("sensor.csv"), seed=1)   # doctest: +SKIP
>>> result.to_dict()["derived"]["capacity_bits"]["ci95"]         # doctest: +SKIP
"""
__version__ = "0.1.0"

from ._heap import retain_freed_memory as _retain_freed_memory  # noqa: E402

_retain_freed_memory()   # glibc keeps freed temporaries for the next log_prob call (bayescap/_heap.py)

from .api import fit, load, default_scene  # noqa: E402
from .posterior import FitResult, Scene  # noqa: E402
from .ptc import PTCData, PTCInputError, read_ptc_csv, write_ptc_csv  # noqa: E402
from . import simulate  # noqa: E402,F401

__all__ = ["fit", "load", "default_scene", "FitResult", "Scene", "PTCData", "PTCInputError",
           "read_ptc_csv", "write_ptc_csv", "simulate", "__version__"]
