r"""From flags to dark matter: a posterior on the sub-halo abundance.

The chain, for one or many analysed constellations:

1. :class:`SubhaloPopulation`: pyHalo's sub-halo mass function (its
   ``sigma_sub`` normalisation), concentrations and truncation, CDM or WDM,
   placed in a disc around each image; optionally pyHalo's line-of-sight
   haloes (``los_normalization``), plane by plane.
2. :func:`simulate_anomalies`: the forward model. Every pair's log flux
   anomaly :math:`\ln(f_1/f_2)` in many realisations of the population on a
   grid of abundances, the micro-images solved in the smooth lens's local
   Jacobian (Numba); a halo of another plane acts through that Jacobian's
   two-plane linearisation. :func:`apply_population` applies one realisation to a
   constellation, for mock data.
3. :func:`pair_anomalies` and :func:`abundance_posterior`: the measured
   anomalies and their errors from :func:`~lensdual.check_duality`, the
   Monte-Carlo likelihood (pairs independent given the population, systems
   multiplied) and the posterior on ``sigma_sub`` under a log-uniform prior;
   :func:`half_mode_posterior` the joint posterior with the WDM half-mode
   mass, from simulations of WDM populations on a grid of half-mode masses.
4. :func:`calibrate_posterior`: mock universes of a constellation, made as
   the data, on which :func:`abundance_posterior` recalibrates its intervals
   (the pairs' errors are correlated through shared baselines), and
   :func:`half_mode_posterior` both of its marginals;
   :func:`composite_weight` the older correction, a power of the likelihood.

See the docs page "What the flags say about dark matter" for the model, its
checks and its injection-recovery coverage.
"""

from ._calibration import PosteriorCalibration, calibrate_posterior
from ._forward import MIN_REALISATIONS, AnomalySimulation, apply_population, simulate_anomalies
from ._population import MODELS, SubhaloPopulation
from ._posterior import (
    ANOMALIES,
    INTERVALS,
    abundance_posterior,
    composite_weight,
    half_mode_posterior,
    pair_anomalies,
)

__all__ = [
    "SubhaloPopulation",
    "MODELS",
    "simulate_anomalies",
    "apply_population",
    "AnomalySimulation",
    "MIN_REALISATIONS",
    "pair_anomalies",
    "abundance_posterior",
    "half_mode_posterior",
    "composite_weight",
    "calibrate_posterior",
    "PosteriorCalibration",
    "INTERVALS",
    "ANOMALIES",
]
