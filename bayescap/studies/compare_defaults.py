"""The comparison's defaults, apart from :mod:`bayescap.studies.compare` so that the command line
can show them in its help without importing the fitting machinery."""

#: the exposure of the comparison's scene (lux·s)
DEFAULT_H0_LUX_S = 0.4

#: the optical format whose area the sensors are compared at
DEFAULT_AREA = "1/4in"

#: the practical difference δ of capacities: A is practically larger than B when C_A > (1+δ)·C_B
DEFAULT_PRACTICAL_DIFFERENCE = 0.01

#: compare fits several sensors: the fast preset by default (Laplace–IS; MCMC with ESS >= 200 per
#: quantity when its k̂ check rejects the draws)
DEFAULT_QUALITY = "fast"

#: mid-grey: the fraction of the top of the signal range at which the scene's mean is placed
DEFAULT_MID_GREY = 0.18
