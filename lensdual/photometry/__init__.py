"""PSF photometry of point sources on bright lens arcs, and the pairs table.

:func:`psf_photometry` fits a PSF to each point source of one image,
starting from given positions, with a local background model that copes
with the bright, curved arc underneath; :func:`measure_pairs` runs it on
every band of two arcs and fills a :ref:`pairs table <pairs-table>` with
positions in one common tangent-plane frame and per-band fluxes.
"""

from ._psf import (
    BACKGROUND_STRATEGIES,
    UNUSABLE_FLAGS,
    PhotometryFlag,
    _file_of,
    _GaussianProfile,
    _squeeze_plane,
    describe_flags,
    measure_pairs,
    psf_photometry,
)

__all__ = [
    "BACKGROUND_STRATEGIES",
    "PhotometryFlag",
    "UNUSABLE_FLAGS",
    "describe_flags",
    "psf_photometry",
    "measure_pairs",
]
