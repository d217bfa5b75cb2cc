"""Checks of the inference against known answers, shared by the test suite and ``benchmarks/``:
simulation-based calibration (:mod:`.sbc`), emcee moves on known targets (:mod:`.moves`), the
paper's integrals by quadrature (:mod:`.integrals`), and the sensor zoo (:mod:`.zoo`): sensors
nobody tuned the model to, simulated frame by frame by :mod:`.framesim`, a simulator written
independently of the likelihood."""

from bayescap.validation import framesim, integrals, moves, sbc, zoo

__all__ = ["sbc", "moves", "integrals", "framesim", "zoo"]
