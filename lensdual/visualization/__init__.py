"""Figures in the style of the paper (matplotlib), and DS9 regions.

Every function draws on a given ``ax`` or ``fig`` (or a new one) and returns
it, so that figures can be composed, restyled and saved by the caller.

The figures of the other subpackages are drawn here too and re-exported
where they belong: :func:`plot_parametric_comparison` and
:func:`plot_size_vs_model` by `lensdual.parametric`,
:func:`plot_flux_excess_violin` and :func:`plot_detection_snr_map` by
`lensdual.sensitivity`.
"""

# Modules: _estimators (Figs. 6, 10, 11), _duality (Figs. 3 and 4, the flux field),
# _images (the pairs on the arcs' images), _regions (DS9), _abundance (the
# sub-halo abundance posterior), _parametric, _sensitivity (Figs. 8 and 9), _run
# (the figures the commands write), _common (pyplot).
from ._abundance import plot_abundance_posterior, plot_half_mode_posterior
from ._duality import plot_duality, plot_flux_field, plot_pairing_map
from ._estimators import plot_error_histograms, plot_estimator_grid, plot_true_vs_inferred
from ._images import plot_arc_images
from ._parametric import plot_parametric_comparison, plot_size_vs_model
from ._regions import ds9_regions
from ._sensitivity import plot_detection_snr_map, plot_flux_excess_violin

__all__ = [
    "plot_true_vs_inferred",
    "plot_estimator_grid",
    "plot_error_histograms",
    "plot_pairing_map",
    "plot_duality",
    "plot_flux_field",
    "ds9_regions",
    "plot_arc_images",
    "plot_abundance_posterior",
    "plot_half_mode_posterior",
    "plot_parametric_comparison",
    "plot_size_vs_model",
    "plot_flux_excess_violin",
    "plot_detection_snr_map",
]
