"""PSF photometry of point sources on bright lens arcs, and the pairs table.

:class:`ArcPSFPhotometry` (set up once, called on images) and its one-call
form :func:`psf_photometry` fit a PSF to each point source of one image,
starting from given positions, with a local background model that copes
with the bright, curved arc underneath; :func:`measure_pairs` runs it on
every band of two arcs and fills a :ref:`pairs table <pairs-table>` with
positions in one common tangent-plane frame and per-band fluxes.

The subpackage's modules (all private; everything public is imported here):

* ``_psf``: :class:`ArcPSFPhotometry`, :func:`psf_photometry`, the cut-out;
* ``_pairs``: :func:`measure_pairs`;
* ``_flags``: :class:`PhotometryFlag`, :data:`UNUSABLE_FLAGS`, :func:`describe_flags`;
* ``_fitting``: the fits (photutils one by one, astropy for groups, refinement passes);
* ``_profiles``: the PSF profiles; ``_background``: the background strategies and bases;
* ``_models``: the astropy models fitted; ``_filters``: the Gaussian blurs;
* ``_inputs``: images, WCS, PSF settings and positions.
"""

from ._background import BACKGROUND_STRATEGIES
from ._flags import UNUSABLE_FLAGS, PhotometryFlag, describe_flags
from ._pairs import measure_pairs
from ._profiles import _GaussianProfile  # noqa: F401 - used by the tests
from ._psf import ArcPSFPhotometry, psf_photometry

__all__ = [
    "BACKGROUND_STRATEGIES",
    "ArcPSFPhotometry",
    "PhotometryFlag",
    "UNUSABLE_FLAGS",
    "describe_flags",
    "psf_photometry",
    "measure_pairs",
]
