"""From flags to dark matter: a posterior on the sub-halo abundance."""

from ._forward import MIN_REALISATIONS, AnomalySimulation, apply_population, simulate_anomalies
from ._population import MODELS, SubhaloPopulation
from ._posterior import INTERVALS, abundance_posterior, pair_anomalies

__all__ = [
    "SubhaloPopulation",
    "MODELS",
    "simulate_anomalies",
    "apply_population",
    "AnomalySimulation",
    "MIN_REALISATIONS",
    "pair_anomalies",
    "abundance_posterior",
    "INTERVALS",
]
