"""Checks of the inference against known answers, shared by the test suite and ``benchmarks/``:
simulation-based calibration (:mod:`.sbc`), emcee moves on known targets (:mod:`.moves`) and the
paper's integrals by quadrature (:mod:`.integrals`)."""

from bayescap.validation import integrals, moves, sbc

__all__ = ["sbc", "moves", "integrals"]
