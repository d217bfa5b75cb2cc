"""bayescap: Bayesian image-sensor characterization.

Photon-transfer measurements -> posterior of the sensor noise model (Tisse, Guichard & Cao 2008,
Eq. 1) -> image information capacity C = s' * b' (Eq. 6-9) with credible intervals.
"""
__version__ = "0.1.0"
